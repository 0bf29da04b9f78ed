"""Volume rendering of bricks/regions/BVH with the OpenCL integrator (paper §4).

`Renderer` uploads one dataset once and renders many frames (cameras,
transfer functions, settings); `render` is the one-frame convenience. The
kernels (kernels/integrator.cl) march every ray front to back through the
Active Brick Regions in lattice space with t in world distance, sample each
region at `sampling_rate` samples per finest cell width of that region with
the interval-midpoint scheme of paper §4.3 (Fig. 5), reconstruct with the basis
method from the region's brick list (eq. 1-2), and composite emission and
absorption. Conventions the design leaves open, chosen here:

* dt of a region with finest level l is ``2**l * min(spacing_world) /
  sampling_rate`` (world units; min over axes for anisotropic spacing).
* Interleaved sampling: the per-ray offset rho is a seeded hash of (pixel,
  sample index, seed); with ``jitter=False`` rho = 0.5 (delimiters halfway
  between the points k * dt).
* ``spp = 1``: the ray goes through the pixel centre. ``spp > 1``: each of the
  spp rays goes through a sub-pixel position drawn uniformly from the seeded
  hash (jitter on or off) and the frame is their average.
* ``unit_distance`` default: the finest cell width of the dataset in world
  units, ``2**min(level) * min(spacing_world)``.
* ``shading="headlight"``: emitted rgb *= 0.3 + 0.7 |n . v| with n the
  normalised analytic gradient (paper §5.1.2) and v the ray direction; a zero
  gradient is unshaded. ``"none"``: pure emission-absorption.
* depth: world distance along the ray at which the accumulated opacity first
  reaches 0.5 (smallest over the pixel's samples); +inf where it never does.
* ``traversal="ordered"`` (default) walks the regions with one BVH traversal
  per ray and a private min-heap (re-tracing if the heap fills up);
  ``"retrace"`` re-traces from the root for every region as the paper does
  (§4). Same regions, same image; ordered is 1.1-1.5x faster on PoCL
  (docs/benchmarks.md, "render (PoCL)").
* ``Renderer(..., reconstruction="cell-location")`` (Python API only) is the
  comparison of paper §6.4.2 (Table 3): the regions still decide where to
  sample, but each sample finds its bricks by descending a tree over the brick
  supports from the root (kernels/cell_location.cl, built in memory when the
  Renderer is made, or shared by `Renderer.with_reconstruction`) instead of
  reading the region's brick list. Same samples, and the same bricks summed in
  the same order, so the same frame; only the speed differs. ``"regions"``
  (default) is the paper's method.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field as dataclass_field

import numpy as np

from .. import interrupt, opencl, schema
from ..constants import MAX_SAMPLES_PER_RAY
from ..errors import ExabricksError
from .scene import DeviceScene, _float4

SHADING_MODES = ("headlight", "none")

# Region walks (kernels/traversal.cl): "ordered" keeps a private min-heap of
# BVH nodes and regions per ray (one traversal per ray); "retrace" is the
# paper's §4 closest-hit traversal from the root for every region.
TRAVERSALS = ("ordered", "retrace")

# Where a sample finds the bricks it reconstructs from: the region's list (paper
# §3.2) or a per-sample descent of a tree over the brick supports (§6.4.2).
RECONSTRUCTIONS = ("regions", "cell-location")

# Pixels per work-group side: 8 x 8 tiles keep neighbouring rays (which walk the
# same regions and bricks) together on one core.
TILE = 8


@dataclass(frozen=True)
class RenderResult:
    """One frame.

    rgba:  float32 (H, W, 4), premultiplied colour and opacity, row 0 at the top.
    depth: float32 (H, W) world distance where opacity reached 0.5 (inf: never), or None.
    stats: samples (reconstructions), ms (kernel wall time per frame),
           samples_per_second, visible_regions, and the settings used
           (reconstruction included).
    """

    rgba: np.ndarray
    depth: np.ndarray | None
    stats: dict = dataclass_field(default_factory=dict)


def _check_settings(width, height, sampling_rate, spp, max_opacity, unit_distance, shading,
                    traversal="ordered"):
    if int(width) < 1 or int(height) < 1:
        raise ExabricksError(f"image size must be positive, got {width}x{height}")
    if not (math.isfinite(sampling_rate) and sampling_rate > 0):
        raise ExabricksError(f"sampling rate must be positive, got {sampling_rate:g}")
    if int(spp) < 1:
        raise ExabricksError(f"samples per pixel must be at least 1, got {spp}")
    if not (0.0 < max_opacity <= 1.0):
        raise ExabricksError(f"max opacity must be in (0, 1], got {max_opacity:g}")
    if unit_distance is not None and not (math.isfinite(unit_distance) and unit_distance > 0):
        raise ExabricksError(f"unit distance must be positive, got {unit_distance:g}")
    if shading not in SHADING_MODES:
        raise ExabricksError(f"unknown shading {shading!r} (one of {', '.join(SHADING_MODES)})")
    if traversal not in TRAVERSALS:
        raise ExabricksError(f"unknown traversal {traversal!r} (one of {', '.join(TRAVERSALS)})")


def _check_reconstruction(reconstruction):
    if reconstruction not in RECONSTRUCTIONS:
        raise ExabricksError(f"unknown reconstruction {reconstruction!r} "
                             f"(one of {', '.join(RECONSTRUCTIONS)})")


class Renderer:
    """A dataset on an OpenCL device, ready to render frames of one field."""

    def __init__(self, bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh,
                 *, field: str | None = None, device=None, reconstruction: str = "regions"):
        _check_reconstruction(reconstruction)
        self.scene = DeviceScene(bricks, regions, bvh, field=field, device=device)
        self._use(reconstruction)

    def _use(self, reconstruction: str) -> None:
        _check_reconstruction(reconstruction)
        self.reconstruction = reconstruction
        program = self.scene.program
        self.location_args = []
        if reconstruction == "cell-location":
            program = opencl.program_for(self.scene.context, ("EB_CELL_LOCATION",))
            self.location_args = self.scene.location_args()
        self.kernel = opencl.kernel(program, "eb_render")

    def with_reconstruction(self, reconstruction: str) -> "Renderer":
        """A Renderer of the same uploaded scene (no second upload) with another
        reconstruction (RECONSTRUCTIONS)."""
        other = copy.copy(self)
        other._use(reconstruction)
        return other

    @property
    def field(self) -> str:
        return self.scene.field

    @property
    def device_name(self) -> str:
        return self.scene.device.name.strip()

    def render(self, *, camera, transfer_function, width: int = 512, height: int = 512,
               sampling_rate: float = 2.0, spp: int = 1, seed: int = 0, jitter: bool = True,
               max_opacity: float = 0.98, unit_distance: float | None = None,
               shading: str = "headlight", depth: bool = False,
               traversal: str = "ordered") -> RenderResult:
        """Render one frame; see the module docstring for the conventions.

        `traversal` picks the region walk (TRAVERSALS); both give the same
        image up to float rounding, only the speed differs."""
        _check_settings(width, height, sampling_rate, spp, max_opacity, unit_distance, shading,
                        traversal)
        width, height, spp = int(width), int(height), int(spp)
        s = self.scene
        unit = s.finest_width_world if unit_distance is None else float(unit_distance)
        origin, forward, du, dv = camera.frame(width, height)
        node_vis, region_vis = s.visibility(transfer_function)
        xs, rgba_knots = transfer_function.merged_knots()
        stats = {
            "field": self.field, "width": width, "height": height, "spp": spp,
            "sampling_rate": float(sampling_rate), "seed": int(seed), "jitter": bool(jitter),
            "max_opacity": float(max_opacity), "unit_distance": unit, "shading": shading,
            "traversal": traversal, "reconstruction": self.reconstruction,
            "device": self.device_name,
            "visible_regions": int(region_vis.sum()), "regions": s.regions.n_regions,
        }
        if s.empty or not node_vis[0]:
            stats.update(samples=0, ms=0.0, samples_per_second=0.0)
            rgba = np.zeros((height, width, 4), np.float32)
            d = np.full((height, width), np.inf, np.float32) if depth else None
            return RenderResult(rgba, d, stats)
        self._check_samples_per_ray(sampling_rate)
        rgba = _host_image(width, height, 4, "the image")
        d = _host_image(width, height, 1, "the depth image")[..., 0] if depth else None

        q = s.queue
        up = opencl.to_device
        band_rows = _band_rows(s.device, width, height)
        band_pixels = width * band_rows
        rgba_buf = opencl.empty_buffer(q, band_pixels * 16)
        depth_buf = opencl.empty_buffer(q, band_pixels * 4)
        samples_buf = opencl.empty_buffer(q, band_pixels * 4)
        samples = np.empty(band_pixels, np.uint32)
        scene_args = s.scene_args(up(q, node_vis), up(q, region_vis))
        tf_args = [up(q, xs, np.float32), up(q, rgba_knots, np.float32), np.int32(xs.shape[0])]
        fixed = [
            np.uint32(int(seed) & 0xFFFFFFFF), np.int32(bool(jitter)),
            _float4(origin), _float4(forward), _float4(du), _float4(dv),
            s.origin_world4, s.inv_spacing4, s.gradient_scale4,
            np.float32(s.min_spacing_world / sampling_rate), np.float32(1.0 / unit),
            np.float32(max_opacity), np.int32(shading != "none"), np.int32(traversal == "ordered"),
            *scene_args, *self.location_args, *tf_args, rgba_buf, depth_buf, samples_buf,
        ]
        q.finish()
        start = time.perf_counter()
        total = 0
        row0, rows = 0, TILE
        while row0 < height:
            rows = min(rows, band_rows, height - row0)
            band_start = time.perf_counter()
            global_size = (-(-width // TILE) * TILE, -(-rows // TILE) * TILE)
            for sample in range(spp):
                self.kernel(q, global_size, (TILE, TILE),
                            np.int32(width), np.int32(height), np.int32(row0), np.int32(rows),
                            np.int32(sample), np.int32(spp), *fixed)
            n = width * rows
            opencl.read_back(q, rgba_buf, rgba[row0:row0 + rows].reshape(n, 4))
            opencl.read_back(q, samples_buf, samples[:n])
            if depth:
                opencl.read_back(q, depth_buf, d[row0:row0 + rows].reshape(n))
            total += int(samples[:n].sum(dtype=np.int64))
            row0 += rows
            rows = _next_band(rows, time.perf_counter() - band_start)
            interrupt.raise_pending()
        seconds = time.perf_counter() - start
        stats.update(samples=total, ms=1e3 * seconds / spp,
                     samples_per_second=total / seconds if seconds > 0 else 0.0)
        return RenderResult(rgba, d, stats)

    def _check_samples_per_ray(self, sampling_rate: float) -> None:
        """Refuse a sampling rate that would take more than MAX_SAMPLES_PER_RAY samples
        on a ray through the whole dataset (its bounding box's world diagonal at the
        finest step)."""
        s = self.scene
        extent = (s.bvh.upper_lattice[0].astype(np.float64) - s.bvh.lower_lattice[0])
        diagonal = float(np.linalg.norm(extent * s.bricks.spacing_world))
        finest = int(s.regions.finest_level.min())
        step = s.min_spacing_world * 2.0 ** finest / sampling_rate
        bound = diagonal / step
        if not bound <= MAX_SAMPLES_PER_RAY:
            raise ExabricksError(
                f"a sampling rate of {sampling_rate:g} takes up to {bound:,.0f} samples on a ray "
                f"through the data, more than the {MAX_SAMPLES_PER_RAY:,} allowed: lower it")


# A frame is rendered in bands of whole rows, each enqueue sized to take about
# BAND_SECONDS (measured band after band), so that SIGINT/SIGTERM end a run
# within a second and the device buffers stay small; bands never exceed
# BAND_BYTES of device output buffers.
BAND_SECONDS = 0.1
BAND_BYTES = 64 << 20


def _band_rows(device, width: int, height: int) -> int:
    """Most rows of one band (a multiple of TILE), from the buffer limits."""
    largest = min(int(device.max_mem_alloc_size), BAND_BYTES)
    rows = max(TILE, largest // (16 * width) // TILE * TILE)
    return min(rows, -(-height // TILE) * TILE)


def _next_band(rows: int, seconds: float) -> int:
    """Rows of the next band: scaled towards BAND_SECONDS, at most 4x larger."""
    scale = 4.0 if seconds <= 0 else min(4.0, BAND_SECONDS / seconds)
    return max(TILE, int(rows * scale) // TILE * TILE)


def _host_image(width: int, height: int, channels: int, what: str) -> np.ndarray:
    """A float32 (height, width, channels) array, or one clear error if it cannot fit."""
    nbytes = width * height * channels * 4
    limit = schema.memory_limit()
    if limit is not None and nbytes > limit:
        raise ExabricksError(f"{what} of {width}x{height} needs {nbytes / 2**30:.1f} GiB, more "
                             f"than the {limit / 2**30:.1f} GiB of memory available")
    return np.empty((height, width, channels), np.float32)


def render(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh, *, camera,
           transfer_function, field: str | None = None, width: int = 512, height: int = 512,
           sampling_rate: float = 2.0, spp: int = 1, seed: int = 0, jitter: bool = True,
           max_opacity: float = 0.98, unit_distance: float | None = None,
           shading: str = "headlight", depth: bool = False, device=None,
           traversal: str = "ordered", reconstruction: str = "regions") -> RenderResult:
    """Render one frame of `field` (default: the first); see `Renderer.render`."""
    return Renderer(bricks, regions, bvh, field=field, device=device,
                    reconstruction=reconstruction).render(
        camera=camera, transfer_function=transfer_function, width=width, height=height,
        sampling_rate=sampling_rate, spp=spp, seed=seed, jitter=jitter,
        max_opacity=max_opacity, unit_distance=unit_distance, shading=shading, depth=depth,
        traversal=traversal)
