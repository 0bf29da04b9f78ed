"""A slab of constant value (tests/engine/test_render.py, test_shadows.py): 32 x 32 x 4
level-0 cells whose support is 33 x 33 x 5 cells, a constant transfer function, and a
camera that looks down through its top and its bottom."""

from __future__ import annotations

import functools

import numpy as np

from exabricks import schema
from exabricks.picture.camera import Camera
from exabricks.picture.transfer_function import TransferFunction

from . import Built, build

SLAB_TOLERANCE = 1e-5
SLAB_VALUE = 2.0
SLAB_RGB = (0.2, 0.6, 0.9)
SLAB_ORIGIN = np.array([-1.0, 2.0, 3.0])
SLAB_SPACING = 0.5
SLAB_CELLS = (32, 32, 4)   # level-0 cells; the support is 33 x 33 x 5 cells


@functools.lru_cache(maxsize=1)
def slab() -> Built:
    nx, ny, nz = SLAB_CELLS
    z, y, x = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    lower = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1).astype(np.int32)
    cells = schema.Cells(fields=("density",), origin_world=SLAB_ORIGIN,
                         spacing_world=np.full(3, SLAB_SPACING), lower_lattice=lower,
                         level=np.zeros(len(lower), np.int8),
                         values=np.full((1, len(lower)), SLAB_VALUE, np.float32))
    built = build(cells)
    assert built.bricks.n_bricks == 1
    return built


def constant_tf(alpha: float) -> TransferFunction:
    return TransferFunction(np.array([[SLAB_VALUE, *SLAB_RGB]]),
                            np.array([[SLAB_VALUE, alpha]]), "constant")


def slab_camera() -> Camera:
    """Head-on: 3 world units above the top of the support, looking down -z at its centre."""
    nx, ny, nz = SLAB_CELLS
    centre = SLAB_ORIGIN + SLAB_SPACING * np.array([nx / 2, ny / 2, nz / 2])
    top = SLAB_ORIGIN[2] + SLAB_SPACING * (nz + 0.5)
    return Camera((centre[0], centre[1], top + 3.0), tuple(centre), (0.0, 1.0, 0.0), 60.0)


def slab_alpha(directions, a0: float, unit: float) -> np.ndarray:
    """1 - (1 - a0)^(L / unit), L = support thickness / |d_z| (rays through top and bottom)."""
    thickness = SLAB_SPACING * (SLAB_CELLS[2] + 1)
    return 1.0 - (1.0 - a0) ** (thickness / np.abs(directions[..., 2]) / unit)
