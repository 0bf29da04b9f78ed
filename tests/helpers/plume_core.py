"""The Gerris plume's hot core lit from the side, the real-data scene of the shadow
and path integrators' tests (tests/engine/test_shadows.py, test_path.py): the
plume built in memory, a camera on the core's lattice box (49, 17, 49)-(79, 56, 79),
a colour ramp over T in [0.01, 0.5] whose opacity stops short of 1, an opacity per
4 finest cells, and the light's direction."""

from __future__ import annotations

import functools
from types import SimpleNamespace

import numpy as np

from exabricks.picture.transfer_function import TransferFunction

from . import GERRIS, build

CORE = ((49, 17, 49), (79, 56, 79))  # lattice corners
LIGHT = (1.0, 0.4, -0.3)


@functools.lru_cache(maxsize=1)
def plume_core() -> SimpleNamespace:
    from exabricks.picture.camera import default_camera
    from exabricks.readers import read

    built = build(read(GERRIS))
    world = [built.cells.origin_world + built.cells.spacing_world * np.array(c, np.float64) for c in CORE]
    mid = 0.5 * (0.01 + 0.5)
    tf = TransferFunction(np.array([[0.01, 0.1, 0.2, 0.9], [mid, 0.9, 0.9, 0.2], [0.5, 0.9, 0.1, 0.1]]),
                          np.array([[0.01, 0.0], [mid, 0.3], [0.5, 0.6]]), "ramp")
    return SimpleNamespace(built=built, camera=default_camera(*world), tf=tf,
                           unit=4.0 * built.finest_width_world, light=LIGHT)
