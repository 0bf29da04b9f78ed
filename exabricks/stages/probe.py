"""Field values at world points with the renderer's reconstructions (paper eq. 1-2,
nearest, vertex).

Each point finds its Active Brick Region through the BVH (regions are
disjoint: the first containing box) and is reconstructed from that region's
bricks by the same kernels/reconstruction.cl code the integrator uses.
"""

from __future__ import annotations

import numpy as np

from .. import interrupt, opencl, schema
from ..errors import ExabricksError
from .device_data import DeviceScene


def probe_fields(scene: DeviceScene, points_world, *, reconstruction: str = "basis") -> np.ndarray:
    """Values of every field of `scene` at `points_world` (N, 3) world units ->
    (F, N) float32, F = len(scene.fields), with `reconstruction`.

    NaN where no region contains the point or no cell has support there (no
    containing cell, for nearest and vertex). Points travel as float32.
    """
    points = np.asarray(points_world)
    if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.number):
        raise ExabricksError(f"points must be a numeric (N, 3) array, got shape {points.shape} "
                             f"and dtype {points.dtype}")
    n = points.shape[0]
    n_fields = max(1, len(scene.fields))
    out = np.full((n_fields, n), np.nan, np.float32)
    if n == 0 or scene.empty:
        return out
    q = scene.queue
    local = 64
    kernel = opencl.kernel(scene.program_for(reconstruction=reconstruction), "eb_probe")
    args = scene.scene_args(reconstruction=reconstruction)
    # In chunks, so that a signal can stop a large probe between enqueues.
    chunk = min(n, PROBE_CHUNK)
    values_buf = opencl.empty_buffer(q, 4 * chunk * n_fields)
    values = np.empty(chunk * n_fields, np.float32)
    points = np.ascontiguousarray(points, np.float32)
    for start in range(0, n, chunk):
        m = min(chunk, n - start)
        kernel(q, (-(-m // local) * local,), (local,),
               np.int32(m), opencl.to_device(q, points[start:start + m]),
               scene.origin_world4, scene.inv_spacing4, *args, values_buf)
        opencl.read_back(q, values_buf, values[:m * n_fields])
        out[:, start:start + m] = values[:m * n_fields].reshape(n_fields, m)
        interrupt.raise_pending()
    return out


def probe_scene(scene: DeviceScene, points_world, *, reconstruction: str = "basis") -> np.ndarray:
    """Values of `scene`'s first field at `points_world` (N, 3) -> (N,) float32
    (see `probe_fields`)."""
    return probe_fields(scene, points_world, reconstruction=reconstruction)[0]


# Points per enqueue: a fraction of a second on a CPU device.
PROBE_CHUNK = 1 << 18


def probe(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh, points_world,
          *, field: str | None = None, device=None, reconstruction: str = "basis") -> np.ndarray:
    """`field` (default: the first) at world points (N, 3) -> (N,) float32, with
    `reconstruction` (basis, nearest or vertex)."""
    points = np.asarray(points_world)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ExabricksError(f"points must be an (N, 3) array, got shape {points.shape}")
    if points.shape[0] >= 2**31:
        raise ExabricksError(f"too many points ({points.shape[0]}); probe at most 2**31 - 1 at once")
    return probe_scene(DeviceScene(bricks, regions, bvh, field=field, device=device), points,
                       reconstruction=reconstruction)
