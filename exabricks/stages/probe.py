"""Field values at world points with the renderer's reconstructions (paper eq. 1-2,
nearest, vertex).

Each point finds its Active Brick Region through the BVH (regions are
disjoint: the first containing box) and is reconstructed from that region's
bricks by the same kernels/reconstruction.cl code the integrator uses.
"""

from __future__ import annotations

import numpy as np

from .. import schema
from ..errors import ExabricksError
from ..engine.device_data import DeviceDataset


def probe(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh, points_world,
          *, field: str | None = None, device=None, reconstruction: str = "basis") -> np.ndarray:
    """`field` (default: the first) at world points (N, 3) -> (N,) float32, with
    `reconstruction` (basis, nearest or vertex)."""
    points = np.asarray(points_world)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ExabricksError(f"points must be an (N, 3) array, got shape {points.shape}")
    if points.shape[0] >= 2**31:
        raise ExabricksError(f"too many points ({points.shape[0]}); probe at most 2**31 - 1 at once")
    scene = DeviceDataset(bricks, regions, bvh, field=field, device=device)
    return scene.probe_fields(points, reconstruction=reconstruction)[0]
