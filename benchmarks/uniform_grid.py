"""The uniform-grid ceiling: a dataset resampled onto its finest grid and marched trilinearly.

`finest_grid` gives the box of the dataset's finest lattice, `resample` fills it
with the renderer's own basis reconstruction (paper eq. 1-2, through
`DeviceDataset.probe_fields`) at every finest-cell centre, and
`UniformGridRenderer` renders that volume with kernels/uniform_grid.cl: the
renderer's camera, transfer function, sample placement (interval midpoints,
paper §4.3), opacity correction, compositing and early termination, but one
trilinear lookup per sample and no traversal (no BVH, no regions, no space
skipping, one constant step of finest cell width / sampling rate). It is the
bound benchmarks/bench_peers.py measures the renderer against; on one region of
a single-level dataset both take the same samples and give the same frame.
"""

from __future__ import annotations

import time

import numpy as np

from exabricks.device import opencl
from exabricks.engine import variants
from exabricks.util.errors import ExabricksError

# Points per probe call while resampling (float32 (N, 3) points: 24 MiB).
PROBE_CHUNK = 1 << 21

# Pixels per work-group side, as the renderer's 8 x 8 tiles.
TILE = 8

# The kernel source: a program of its own (it is not one of render.cl's entry points).
SOURCE = "uniform_grid.cl"


def finest_grid(data) -> tuple[np.ndarray, np.ndarray]:
    """The box of the finest lattice covering `data` (schema.Cells or schema.Bricks).

    Returns (lower_lattice int64 (3,), dims int64 (3,)): one voxel per lattice
    unit (finest cell), voxel (i, j, k) the cell whose lower corner is
    lower_lattice + (i, j, k).
    """
    width = np.left_shift(1, data.level.astype(np.int64))[:, None]
    extent = width * (data.dims if hasattr(data, "dims") else 1)
    lower = data.lower_lattice.astype(np.int64)
    lo = lower.min(axis=0)
    hi = (lower + extent).max(axis=0)
    return lo, hi - lo


def resample(scene, lower_lattice, dims, *, chunk: int = PROBE_CHUNK) -> np.ndarray:
    """The basis reconstruction of `scene` at every finest-cell centre of a box.

    scene: an exabricks.engine.device_data.DeviceDataset; lower_lattice (3,) and dims (3,)
    integers, the box as `finest_grid` gives it; chunk: points per probe call.
    Returns float32 (Z, Y, X) = (dims[2], dims[1], dims[0]), x fastest, in the
    field's units; NaN where no cell has support.
    """
    nx, ny, nz = (int(d) for d in dims)
    volume = np.empty((nz, ny, nx), np.float32)
    origin = np.asarray(scene.bricks.origin_world, np.float64)
    spacing = np.asarray(scene.bricks.spacing_world, np.float64)
    xs = origin[0] + spacing[0] * (lower_lattice[0] + np.arange(nx) + 0.5)
    ys = origin[1] + spacing[1] * (lower_lattice[1] + np.arange(ny) + 0.5)
    slabs = max(1, chunk // (nx * ny))
    for z0 in range(0, nz, slabs):
        z1 = min(nz, z0 + slabs)
        zs = origin[2] + spacing[2] * (lower_lattice[2] + np.arange(z0, z1) + 0.5)
        Z, Y, X = np.meshgrid(zs, ys, xs, indexing="ij")
        points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
        volume[z0:z1] = scene.probe_fields(points)[0].reshape(z1 - z0, ny, nx)
    return volume


def _int4(xyz):
    import pyopencl.cltypes as cltypes

    x, y, z = (int(v) for v in xyz)
    return cltypes.make_int4(x, y, z, 0)


class UniformGridRenderer:
    """One volume on an OpenCL device (uploaded once), rendered by kernels/uniform_grid.cl.

    volume: float (Z, Y, X), x fastest, voxel (i, j, k) the value at the centre of
    the finest cell whose lower corner is lower_lattice + (i, j, k) (as `resample`
    makes it; NaN voxels are transparent); lower_lattice (3,) lattice units;
    origin_world, spacing_world (3,) world units, the dataset's lattice frame.
    device: a pyopencl Device, a spec string or None (opencl.choose_device).
    """

    def __init__(self, volume, lower_lattice, origin_world, spacing_world, *, device=None):
        volume = np.ascontiguousarray(volume, np.float32)
        if volume.ndim != 3 or volume.size == 0:
            raise ExabricksError(f"the uniform grid must be a non-empty 3D array, "
                                 f"got shape {volume.shape}")
        self.device = device if device is not None and not isinstance(device, str) \
            else opencl.choose_device(device)
        self.context, self.queue = opencl.context_for(self.device)
        self.kernel = opencl.kernel(opencl.program_for(self.context, variants.variant().defines,
                                                       source_name=SOURCE),
                                    "eb_uniform_render")
        nz, ny, nx = volume.shape
        self.dims4 = _int4((nx, ny, nz))
        self.volume_buf = opencl.to_device(self.queue, volume)
        self.lower_lattice4 = opencl.float4(lower_lattice)
        self.origin_world4 = opencl.float4(origin_world)
        self.inv_spacing4 = opencl.float4(1.0 / np.asarray(spacing_world, np.float64))
        self.finest_width_world = float(np.min(spacing_world))

    def render(self, *, camera, transfer_function, width: int, height: int,
               sampling_rate: float = 2.0, max_opacity: float = 0.98,
               unit_distance: float | None = None, jitter: bool = True, seed: int = 0):
        """One frame; the settings mean what they mean in `Renderer.render` (shading none).

        unit_distance: world units, default the finest cell width. Returns
        (rgba float32 (H, W, 4) premultiplied, row 0 at the top; samples: the
        trilinear lookups of the frame, int; kernel wall seconds, float).
        """
        q = self.queue
        unit = self.finest_width_world if unit_distance is None else float(unit_distance)
        origin, forward, du, dv = camera.frame(width, height)
        xs, knots = transfer_function.merged_knots()
        n = width * height
        rgba_buf = opencl.empty_buffer(q, 16 * n)
        samples_buf = opencl.empty_buffer(q, 4 * n)
        global_size = (-(-width // TILE) * TILE, -(-height // TILE) * TILE)
        args = (np.int32(width), np.int32(height), np.uint32(seed), np.int32(bool(jitter)),
                opencl.float4(origin), opencl.float4(forward), opencl.float4(du), opencl.float4(dv),
                self.origin_world4, self.inv_spacing4, self.lower_lattice4, self.volume_buf,
                self.dims4, np.float32(self.finest_width_world / sampling_rate),
                np.float32(1.0 / unit), np.float32(max_opacity),
                opencl.to_device(q, xs, np.float32), opencl.to_device(q, knots, np.float32),
                np.int32(xs.shape[0]), rgba_buf, samples_buf)
        q.finish()
        start = time.perf_counter()
        self.kernel(q, global_size, (TILE, TILE), *args)
        q.finish()
        seconds = time.perf_counter() - start
        rgba = opencl.read_back(q, rgba_buf, np.empty((height, width, 4), np.float32))
        samples = opencl.read_back(q, samples_buf, np.empty(n, np.uint32))
        return rgba, int(samples.sum(dtype=np.int64)), seconds
