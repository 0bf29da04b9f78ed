"""Field values at world points with the renderer's reconstructions (paper eq. 1-2,
nearest, vertex).

Each point finds its Active Brick Region through the BVH (regions are
disjoint: the first containing box) and is reconstructed from that region's
bricks by the same kernels/reconstruction.cl code the integrator uses.
"""

from __future__ import annotations

import os

import numpy as np

from .. import schema
from ..util.errors import ExabricksError
from ..engine.device_data import DeviceDataset


def probe(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh, points_world,
          *, field: str | None = None, device=None, reconstruction: str = "basis") -> np.ndarray:
    """`field` (default: the first) at world points (N, 3) -> (N,) float32, with
    `reconstruction` (basis, nearest or vertex)."""
    points = world_points(points_world)
    scene = DeviceDataset(bricks, regions, bvh, field=field, device=device)
    return scene.probe_fields(points, reconstruction=reconstruction)[0]


def world_points(points) -> np.ndarray:
    """`points` as an (N, 3) array of real numbers (integers or floats, as given);
    ExabricksError naming what was given otherwise: a string (a file name, where
    the points themselves are wanted), a ragged or non-numeric list, complex
    numbers (never cut to their real part)."""
    if isinstance(points, (str, bytes, os.PathLike)):
        raise ExabricksError(f"points: expected an (N, 3) array of world coordinates, got "
                             f"{points!r} (a file of points: read it with numpy.load first)")
    try:
        array = np.asarray(points)
    except (TypeError, ValueError):  # numpy refuses a ragged list
        raise ExabricksError(f"points: expected an (N, 3) array of world coordinates, got a "
                             f"{type(points).__name__} whose rows differ in length") from None
    if array.dtype.kind == "c":
        raise ExabricksError(f"points: complex numbers ({array.dtype}) are no world coordinates: "
                             "give real (N, 3) points")
    if array.dtype.kind not in "iuf" or array.ndim != 2 or array.shape[1] != 3:
        raise ExabricksError(f"points: expected an (N, 3) array of world coordinates, got shape "
                             f"{array.shape} and dtype {array.dtype}")
    if array.shape[0] >= 2**31:
        raise ExabricksError(f"too many points ({array.shape[0]}); probe at most 2**31 - 1 at once")
    return array
