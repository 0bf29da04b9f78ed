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
* ``traversal="ordered"`` walks the regions with one BVH traversal per ray and
  a private min-heap (re-tracing if the heap fills up); ``"retrace"`` re-traces
  from the root for every region as the paper does (§4), without a stack.
  Same regions, same image. The default follows the device: ordered with
  sample packets (CPUs: faster on PoCL, docs/benchmarks-render.md "render
  (PoCL)"), re-trace one sample at a time (GPUs: no heap in memory).
* ``Renderer(..., lookup="cell-location")`` (Python API only) is the
  comparison of paper §6.4.2 (Table 3): the regions still decide where to
  sample, but each sample finds its bricks by descending a tree over the brick
  supports from the root (kernels/cell_location.cl, built in memory when the
  Renderer is made, or shared by `Renderer.with_lookup`) instead of
  reading the region's brick list. Same samples, and the same bricks summed in
  the same order, so the same frame; only the speed differs. ``"regions"``
  (default) is the paper's method.
* Sample packets: on CPU devices a ray reconstructs its next PACKET_WIDTH samples at
  once in vector registers (kernels/packet.cl; in a volume frame from up to three
  consecutive region visits), the transfer function and opacity of one volume layer
  too; compositing stays in order, so the image equals the one-sample path's up to
  float rounding. ``Renderer(..., packets=False)`` (or `with_packets`) forces the
  one-sample path, the one GPUs take.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field as dataclass_field, replace as dataclass_replace

import numpy as np

from ..device import kernel_abi, opencl
from .. import schema
from ..util.constants import MAX_SAMPLES_PER_RAY
from ..device.kernel_abi import LOD_LEVELS, PACKET_WIDTH
from ..util.errors import ExabricksError
from ..film import denoise
from ..film.film import develop
from ..mesh import mesh_set
from ..picture.light import light_params
from ..scene import Lighting, Scene, Settings, VolumeLayer
from . import instances, light_volume
from .device_data import DatasetScale, DeviceDataset
from .host_images import frame_window, host_image
from .look import frame_arrays
from .majorants import frame_majorants
from . import pacing
from .pacing import Pace
from .variants import (LOOKUPS, TRAVERSALS, check_choice, frame, program_variant,
                       run_time_params, uses_packets)

# Pixels per work-group side: 8 x 8 tiles keep neighbouring rays (which walk the
# same regions and bricks) together on one core.
TILE = 8


@dataclass(frozen=True)
class RenderResult:
    """One frame.

    rgba:  float32 (H, W, 4), premultiplied colour and opacity, row 0 at the top.
    depth: float32 (H, W) world distance where opacity reached 0.5 (inf: never), or None.
    stats: samples (reconstructions), ms (kernel wall time of the frame, every
           sample per pixel), ms_per_sample (of one sample per pixel),
           samples_per_second, visible_regions, and the settings used
           (reconstruction included).
    """

    rgba: np.ndarray
    depth: np.ndarray | None
    stats: dict = dataclass_field(default_factory=dict)


@dataclass
class _Frame:
    """What one `Renderer.integrate` call draws: the frame's size and samples, the
    window (col0, tile_row0, cols, n_rows) and spans of rows, the host images,
    the stats, whether anything is in view, and the visible nodes and regions."""

    width: int
    height: int
    spp: int
    col0: int
    tile_row0: int
    cols: int
    n_rows: int
    spans: list
    rgba: np.ndarray
    depth: np.ndarray | None
    stats: dict
    nothing: bool
    node_vis: np.ndarray
    region_vis: np.ndarray


@dataclass
class _Launch:
    """The kernel of a frame with its eb_params, fixed arguments and band buffers."""

    kernel: object
    params: object
    fixed: list
    band_rows: int
    rgba_buf: object
    front_buf: object
    counts_buf: object  # per pixel of a band its samples, then its depth (kernels/render.cl)
    counts: np.ndarray
    lod: bool
    level_buf: object
    level_samples: np.ndarray


def _check_settings(settings: Settings, traversal: str) -> None:
    w, h = settings.width, settings.height
    if int(w) < 1 or int(h) < 1:
        raise ExabricksError(f"image size must be positive, got {w}x{h}")
    rate = settings.sampling_rate
    if not (math.isfinite(rate) and rate > 0):
        raise ExabricksError(f"sampling rate must be positive, got {rate:g}")
    if int(settings.spp) < 1:
        raise ExabricksError(f"samples per pixel must be at least 1, got {settings.spp}")
    if not (0.0 < settings.max_opacity <= 1.0):
        raise ExabricksError(f"max opacity must be in (0, 1], got {settings.max_opacity:g}")
    unit = settings.unit_distance
    if unit is not None and not (math.isfinite(unit) and unit > 0):
        raise ExabricksError(f"unit distance must be positive, got {unit:g}")
    check_choice("traversal", traversal, TRAVERSALS)


class Renderer:
    """A dataset on an OpenCL device, ready to render frames of the uploaded fields
    (`fields`, default: `field`, else the first field of the bricks)."""

    def __init__(self, bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh,
                 *, field: str | None = None, fields=None, device=None,
                 lookup: str = "regions", packets: bool | None = None,
                 domain=None, scale: DatasetScale | None = None, light=None):
        """`domain`: (lower, upper) lattice bounds of the half-open box of a domain of
        a k-d partition (exabricks.engine.partition) that these structures are
        the share of, `scale` the whole dataset's; frames then hold exactly the
        samples inside the box (docs/design-scale.md, "Data-parallel rendering and MPI").
        `light`: the light_volume.Cache that the domains of one dataset share."""
        check_choice("brick lookup", lookup, LOOKUPS)
        self.dataset = DeviceDataset(bricks, regions, bvh, field=field, fields=fields, device=device,
                                 scale=scale)
        self.domain = None if domain is None else kernel_abi.float4_box(domain)
        self._use(lookup)
        # Sample packets: on CPU devices unless asked otherwise (both give the same image).
        self.packets = opencl.is_cpu(self.dataset.device) if packets is None else bool(packets)
        self._mesh_upload = None  # (mesh files, device buffers, their eb_params)
        self._mesh_set = None
        self._whole = None  # _everywhere's
        self.light_cache = light or light_volume.Cache()  # the shadow integrator's, toward the light
        self.copies = None  # overlapping instances (_mixture): float32 (n, rows, 4)
        self._macrocells = {}  # the path integrator's grid and value ranges (majorants.frame_majorants)

    def _use(self, lookup: str) -> None:
        check_choice("brick lookup", lookup, LOOKUPS)
        self.lookup = lookup
        if lookup == "cell-location":
            self.dataset.location_args()  # built now: its time is not a frame's

    def _point(self, scene: Scene, traversal: str):
        """`scene`'s frame here: a point of the feature table (variants.AXES)."""
        lighting, cfg = scene.lighting, scene.settings
        return frame(kind="cpu" if self.packets else "gpu", n_fields=len(self.dataset.fields) or 1,
                     integrator=lighting.integrator,
                     surfaces=bool(scene.isosurfaces or scene.slices or scene.meshes),
                     reconstruction=cfg.reconstruction, lod=cfg.lod > 0, gradient=lighting.gradient,
                     lookup=self.lookup, domain=self.domain is not None,
                     mixture=self.copies is not None, occlusion=lighting.ao_samples > 0,
                     traversal=traversal)

    def _kernel(self, point, extra=()):
        """eb_render of frame `point` (exabricks.engine.variants), `extra` defines added."""
        return opencl.kernel(self.dataset.program_for(program_variant(point), extra), "eb_render")

    def _packet_width(self, reconstruction: str, integrator: str = "headlight") -> int:
        """Samples reconstructed at once: PACKET_WIDTH for the basis reconstruction from
        the regions' lists on a renderer with packets, else 1 (and under the path
        integrator, built one sample at a time)."""
        use = uses_packets(frame(kind="cpu" if self.packets else "gpu", lookup=self.lookup,
                                 reconstruction=reconstruction, integrator=integrator))
        return PACKET_WIDTH if use else 1

    def with_lookup(self, lookup: str) -> "Renderer":
        """A Renderer of the same uploaded dataset (no second upload) whose samples
        find their bricks another way (LOOKUPS)."""
        other = copy.copy(self)
        other._use(lookup)
        return other

    def with_packets(self, packets: bool) -> "Renderer":
        """A Renderer of the same uploaded dataset that reconstructs samples by packets
        (kernels/packet.cl) or one at a time; the image is the same."""
        other = copy.copy(self)
        other.packets = bool(packets)
        return other

    @property
    def traversal(self) -> str:
        """The default region walk: the ordered one beside sample packets (CPUs), the
        stackless re-trace one where rays take one sample at a time (GPUs)."""
        return "ordered" if self.packets else "retrace"

    @property
    def field(self) -> str:
        return self.dataset.field

    @property
    def device_name(self) -> str:
        return self.dataset.device.name.strip()

    def render(self, *, camera, transfer_function, width: int = 512, height: int = 512,
               sampling_rate: float = 2.0, spp: int = 1, seed: int = 0, jitter: bool = True,
               max_opacity: float = 0.98, unit_distance: float | None = None,
               shading: str = "headlight", depth: bool = False,
               traversal: str | None = None, reconstruction: str = "basis") -> RenderResult:
        """One frame of one volume layer (the first uploaded field); see the module
        docstring for the conventions and `render_scene` for everything else."""
        scene = Scene(
            camera=camera, volumes=(VolumeLayer(self.field, transfer_function),),
            lighting=Lighting(shading=shading),
            settings=Settings(width=int(width), height=int(height), spp=int(spp),
                              sampling_rate=float(sampling_rate), max_opacity=float(max_opacity),
                              seed=int(seed), jitter=bool(jitter), unit_distance=unit_distance,
                              depth=bool(depth), reconstruction=reconstruction))
        return self.render_scene(scene, traversal=traversal)

    def render_scene(self, scene: Scene, **options) -> RenderResult:
        """The frame of `scene` as it is seen: `integrate`'s radiance developed by
        the film (exabricks.film.film: exposure, background).  A whole frame's
        renderer only: domains, samples and tiles that others composite call
        `integrate`, and the film follows their compositing."""
        if scene.settings.denoise:
            denoise.check()  # before the frame, not after
        result = self.integrate(scene, **options)
        develop(result.rgba, scene, result.stats)
        return result

    def integrate(self, scene: Scene, *, traversal: str | None = None, rows=None,
                  window=None, sample: int | None = None, front: np.ndarray | None = None,
                  deadline: float | None = None) -> RenderResult:
        """The premultiplied radiance of `scene` (exabricks.scene.Scene; its fields
        must be uploaded), before the film: no exposure, no background.

        `traversal` picks the region walk (TRAVERSALS; default: `self.traversal`);
        both give the same image up to float rounding, only the speed differs. `rows`: the spans
        (first row, count) to render (default: all rows; the others stay 0).
        `window`: (first column, first row, columns, rows) of a tile of the
        frame: the result (and `front`, `rows`) is that tile alone, the very
        pixels the whole frame has there.
        `sample`: only sample `sample` of the frame's spp rays per pixel,
        unaveraged (data-parallel frames composite each sample on its own).
        `front` (a domain's renderer only): float32 (H, W, 4), the premultiplied
        image of this sample in front of the domain; the rays continue from it
        (early ray termination included) and the result is the composite.
        `deadline` (time.perf_counter() seconds): stop after the band that
        passes it; stats["rows"] then says how many rows from the top were
        drawn (the rest are `front`, else empty)."""
        scene.check()
        traversal = traversal or self.traversal
        _check_settings(scene.settings, traversal)
        if scene.instances:
            if self.domain is not None:
                raise ExabricksError("instances need the whole dataset: a domain's frame holds none")
            return RenderResult(*instances.render(
                self._everywhere(), scene, self._object_box(scene), traversal=traversal, rows=rows,
                window=window, sample=sample, deadline=deadline))
        frame = self._frame(scene, traversal, rows, window, front, deadline)
        if frame.nothing:
            frame.stats["rows"] = frame.n_rows
            frame.stats.update(samples=0, ms=0.0, samples_per_second=0.0)
            return RenderResult(frame.rgba, frame.depth, frame.stats)
        self._check_samples_per_ray(scene.settings.sampling_rate)
        launch = self._launch(scene, frame, traversal, front is not None)
        drawn, total, seconds = self._draw(frame, launch, sample, front, deadline)
        spp = frame.spp
        if sample is not None and spp > 1:
            frame.rgba[:drawn] *= np.float32(spp)  # the kernel averages: this sample alone
        stats = frame.stats
        if launch.lod or scene.lighting.integrator == "path":
            opencl.read_back(self.dataset.queue, launch.level_buf, launch.level_samples)
        if launch.lod:
            stats["samples_per_level"] = {str(lv): int(c) for lv, c in enumerate(launch.level_samples) if c}
        if scene.lighting.integrator == "path":  # kernels/path.cl counts its collisions there
            stats["collisions"] = dict(zip(("real", "null", "ratio"), map(int, launch.level_samples[:3])))
        stats["lod"] = float(scene.settings.lod)
        stats.update(rows=drawn, samples=total, ms=1e3 * seconds,
                     ms_per_sample=1e3 * seconds / (spp if sample is None else 1),
                     samples_per_second=total / seconds if seconds > 0 else 0.0)
        return RenderResult(frame.rgba, frame.depth, stats)

    def light(self, scene: Scene) -> dict | None:
        """Have the shadow integrator's cached transmittance of `scene` hold this
        renderer's part (a domain's or an instance's: light_volume.Cache), drawing
        nothing: its stats ("light_volume"), or None where `scene` reads none."""
        if not light_volume.cached(scene):
            return None
        if self.dataset.empty:  # its part is nothing, whatever the light
            self.light_cache.empty.add(light_volume.part(self.domain, instances.placement(scene)))
            return None
        scene.check()
        one = scene.replace(settings=dataclass_replace(scene.settings, width=1, height=1, spp=1))
        frame = self._frame(one, self.traversal, None, None, None, None)
        self._launch(one, frame, self.traversal, False)
        return frame.stats["light_volume"]

    def _frame(self, scene: Scene, traversal: str, rows, window, front, deadline) -> _Frame:
        """What `integrate` draws of `scene`: the window, the spans, the host images
        (cleared, or `front` where no row may be drawn) and the frame's stats."""
        cfg = scene.settings
        width, height, spp = int(cfg.width), int(cfg.height), int(cfg.spp)
        col0, tile_row0, cols, n_rows = frame_window(window, width, height)
        if window is not None and rows is not None:
            raise ExabricksError("a tile is rendered whole: no spans of rows in it")
        if front is not None and (self.domain is None or front.shape != (n_rows, cols, 4)):
            raise ExabricksError("an image in front is for a domain's frame or tile of the same size")
        missing = [f for f in scene.fields() if f not in self.dataset.fields]
        if missing:
            raise ExabricksError(f"field(s) {', '.join(missing)} are not on the device "
                                 f"(uploaded: {', '.join(self.dataset.fields)})")
        s = self.dataset
        node_vis, region_vis = s.visibility(
            [(v.field, v.transfer_function) for v in scene.volumes],
            [(i.field, i.value) for i in scene.isosurfaces])
        stats = {
            "fields": list(scene.fields()), "width": width, "height": height, "spp": spp,
            "sampling_rate": float(cfg.sampling_rate), "seed": int(cfg.seed),
            "jitter": bool(cfg.jitter), "max_opacity": float(cfg.max_opacity),
            "unit_distance": s.finest_width_world if cfg.unit_distance is None else float(cfg.unit_distance),
            "shading": scene.lighting.shading, "gradient": scene.lighting.gradient,
            "volumes": len(scene.volumes), "isosurfaces": len(scene.isosurfaces),
            "slices": len(scene.slices), "clip": scene.clip.active,
            "ao_samples": scene.lighting.ao_samples,
            "traversal": traversal, "lookup": self.lookup,
            "packet_width": self._packet_width(cfg.reconstruction, scene.lighting.integrator),
            "integrator": scene.lighting.integrator,
            "reconstruction": cfg.reconstruction,
            "device": self.device_name,
            "visible_regions": int(np.count_nonzero(region_vis)), "regions": s.regions.n_regions,
        }
        if scene.volumes:
            stats["field"] = scene.volumes[0].field
        rgba = host_image(cols, n_rows, 4, "the image")
        depth = host_image(cols, n_rows, 1, "the depth image")[..., 0] if cfg.depth else None
        spans = [(0, n_rows)] if rows is None else [(int(a), int(n)) for a, n in rows]
        nothing = s.empty or not (node_vis[0] or scene.slices or scene.meshes)
        if rows is not None or nothing or deadline is not None:  # rows not rendered
            rgba[:] = 0.0 if front is None else front
            if depth is not None:
                depth[:] = np.inf
        return _Frame(width, height, spp, col0, tile_row0, cols, n_rows, spans, rgba, depth,
                      stats, nothing, node_vis, region_vis)

    def _launch(self, scene: Scene, frame: _Frame, traversal: str, has_front: bool) -> _Launch:
        """The kernel of `scene`'s frame, its eb_params and the buffers of one band."""
        s, cfg, lighting = self.dataset, scene.settings, scene.lighting
        q, up = s.queue, opencl.to_device
        band_rows = pacing.band_rows(s.device, frame.cols, frame.n_rows, TILE)
        band_pixels = frame.cols * band_rows
        rgba_buf = opencl.empty_buffer(q, band_pixels * 16)
        front_buf = opencl.empty_buffer(q, band_pixels * 16 if has_front else 16)
        counts_buf = opencl.empty_buffer(q, band_pixels * 8)
        point = self._point(scene, traversal)
        lod, integrator, surfaces = point.lod, point.integrator, point.surfaces
        kernel = self._kernel(point)
        level_samples = np.zeros(LOD_LEVELS, np.uint32)
        level_buf = opencl.to_device(q, level_samples, writable=True)
        # Pixels of a cell of width w at distance t: w / (t * 2 tan(fovy / 2) / H).
        pixel_angle = 2.0 * math.tan(math.radians(scene.camera.fovy) / 2.0) / frame.height
        lod_scale = cfg.lod * pixel_angle / s.min_spacing_world if lod else 0.0
        ao_distance = lighting.ao_distance or AO_DISTANCE_CELLS * s.finest_width_world
        flags = s.flags_for(frame.node_vis, frame.region_vis)
        args, layout = s.dataset_args(up(q, flags), cfg.reconstruction, lod, self.lookup == "cell-location")
        path, mu = {}, None
        if integrator == "path":
            grid, mu = frame_majorants(scene, s, frame.stats["unit_distance"], self._macrocells)
            path, frame.stats["macrocells"] = grid.params(), list(grid.dims)
        look_arrays, look_params, frame.stats["transfer_function_tables"] = frame_arrays(scene, s, self.copies, mu)
        mesh_args, mesh_params = self._meshes(scene)
        if scene.meshes:
            frame.stats["meshes"] = self._mesh_set.stats()
        origin, forward, du, dv = scene.camera.frame(frame.width, frame.height)
        params = s.params(
            **layout, **look_params, **mesh_params, **kernel_abi.option_params(scene),
            width=frame.width, height=frame.height, spp=frame.spp,
            seed=int(cfg.seed) & 0xFFFFFFFF, jitter=bool(cfg.jitter),
            cam_origin=(*origin, 0), cam_forward=(*forward, 0), cam_du=(*du, 0), cam_dv=(*dv, 0),
            step_base=s.min_spacing_world / cfg.sampling_rate,
            inv_unit_distance=1.0 / frame.stats["unit_distance"],
            max_opacity=cfg.max_opacity,
            shading=integrator == "headlight" and lighting.shading != "none",
            **light_params(scene, s.finest_width_world),
            ao_samples=lighting.ao_samples, ao_distance=ao_distance, lod_scale=lod_scale,
            **run_time_params(point), **path,
            **(dict(domain=True, domain_lower=self.domain[0], domain_upper=self.domain[1],
                    use_front=has_front) if self.domain else {}))
        look, by_value = [up(q, a) for a in look_arrays], kernel_abi.params_by_value(surfaces)
        placement = instances.placement(scene)
        light = () if integrator != "shadow" else (self.light_cache.buffer(
            s, s.program_for(program_variant(point)), by_value, lighting.shadow_rays, params,
            look_arrays, frame.region_vis, [*args, *look, *mesh_args], frame.stats,
            part=light_volume.part(self.domain, placement), placement=placement),)
        params = params if by_value else up(q, params)
        fixed = [*args, *look, *mesh_args, *light,
                 front_buf, rgba_buf, counts_buf, level_buf]
        return _Launch(kernel, params, fixed, band_rows, rgba_buf, front_buf, counts_buf,
                       np.empty(2 * band_pixels, np.uint32), lod, level_buf, level_samples)

    def _draw(self, frame: _Frame, launch: _Launch, sample, front, deadline) -> tuple[int, int, float]:
        """Draw `frame`'s spans in bands of rows into its host images, each band's
        samples in runs of launches that take about LAUNCH_SECONDS (pacing.Pace),
        with a check for a signal after each (Pace.waited): (rows drawn from the top,
        samples taken, seconds)."""
        q = self.dataset.queue
        q.finish()
        start = time.perf_counter()
        total = 0
        drawn = n_rows = frame.n_rows
        cols = frame.cols
        indices = range(frame.spp) if sample is None else (sample,)
        pace = Pace(len(indices), launch.band_rows, TILE)
        for span0, span_rows in frame.spans:
            row0, end = span0, min(span0 + span_rows, n_rows)
            while row0 < end:
                if deadline is not None and time.perf_counter() > deadline:
                    drawn = row0
                    break
                rows = pace.rows(end - row0)
                n = cols * rows
                if front is not None:
                    opencl.write_to(q, launch.front_buf, front[row0:row0 + rows].reshape(n, 4))
                if sample:  # the kernel adds samples after the first: start from 0
                    for buf, size in ((launch.rgba_buf, 16), (launch.counts_buf, 4)):
                        opencl.fill_zero(q, buf, n * size)
                self._band(frame, launch, pace, row0, rows, indices)
                opencl.read_back(q, launch.rgba_buf, frame.rgba[row0:row0 + rows].reshape(n, 4))
                opencl.read_back(q, launch.counts_buf, launch.counts[:2 * n])
                if frame.depth is not None:
                    frame.depth[row0:row0 + rows] = launch.counts[n:2 * n].view(np.float32).reshape(rows, cols)
                total += int(launch.counts[:n].sum(dtype=np.int64))
                row0 += rows
            if drawn < n_rows:
                break
        return drawn, total, time.perf_counter() - start

    def _band(self, frame: _Frame, launch: _Launch, pace: Pace, row0: int, rows: int, indices) -> None:
        """Draw the samples `indices` of the `rows` rows from `row0` into the band's
        buffers in runs (pace.run), checking for a signal after each (Pace.waited).
        The first run, one sample, is waited for alone: its time sizes the runs
        after it. Each later run waits in the queue while the host waits for the
        one before it, so that the device does not idle at a check."""
        q, cols = self.dataset.queue, frame.cols
        global_size = (-(-cols // TILE) * TILE, -(-rows // TILE) * TILE)
        band = opencl.int4(frame.tile_row0 + row0, rows, frame.col0, cols)

        def enqueue(run):
            for index in run:
                event = launch.kernel(q, global_size, (TILE, TILE), launch.params, band,
                                      np.int32(index), *launch.fixed)
            return event

        done, since = 0, time.perf_counter()
        waiting = None  # the run in the queue: (its last launch's event, its row-samples)
        while done < len(indices):
            count = pace.run(rows, done)
            event = enqueue(indices[done:done + count])
            if waiting is not None:
                since = pace.waited(*waiting, since)
            waiting = (event, rows * count)
            if not done:
                since, waiting = pace.waited(*waiting, since), None
            done += count
        if waiting is not None:
            pace.waited(*waiting, since)

    def _meshes(self, scene: Scene) -> tuple[tuple, dict]:
        """The mesh buffer of `scene` (kernels/render.cl `meshes`) and its eb_params:
        the MeshSet of its mesh files (exabricks.mesh.mesh_set), uploaded once for as
        long as the frames draw the same files."""
        paths = tuple(m.path for m in scene.meshes)
        if self._mesh_upload is None or self._mesh_upload[0] != paths:
            self._mesh_upload = None  # the old buffer goes before the new one comes
            meshes = mesh_set(paths) if paths else None
            at, words = {}, np.zeros(4, np.float32)
            if meshes is not None:
                normals = np.zeros(-(-meshes.normals.size // 4) * 4, np.uint32)
                normals[:meshes.normals.size] = meshes.normals.reshape(-1)
                t, n = meshes.n_triangles, len(meshes.nodes)
                words = np.concatenate([meshes.triangles.reshape(-1, 4), meshes.nodes.reshape(-1, 4),
                                        normals.view(np.float32).reshape(-1, 4)])
                at = {"mesh_tris_at": 0, "mesh_nodes_at": 3 * t, "mesh_normals_at": 3 * t + 2 * n}
            buffers = (opencl.to_device(self.dataset.queue, words),)
            self._mesh_set = meshes
            self._mesh_upload = (paths, buffers, at)
        return self._mesh_upload[1], self._mesh_upload[2]

    def _everywhere(self) -> "Renderer":
        """This Renderer of the same upload, as the one domain of all of space: its
        frames continue an image in front (an instance's frame)."""
        if self._whole is None:
            self._whole = copy.copy(self)
            self._whole.domain = instances.EVERYWHERE
            self._whole.light_cache = light_volume.Cache()  # over every instance
        self._whole.lookup, self._whole.packets = self.lookup, self.packets
        return self._whole

    def _mixture(self, box, copies: np.ndarray) -> "Renderer":
        """This Renderer of the same upload drawing copies of the data as one mixture
        of media (kernels/mixture.cl): `copies` float32 (n, rows, 4), each copy's
        map and object-space clipping and slices (instances.copy_rows), each cut
        at the object-space world `box` (instances.object_box)."""
        from .partition import eye_lattice

        other = copy.copy(self)
        other.domain = tuple((*eye_lattice(self.dataset.bricks, x), 0.0) for x in box)
        other.copies = np.ascontiguousarray(copies, np.float32)
        return other

    def _object_box(self, scene: Scene):
        """The world box of the data's cells and `scene`'s meshes (instances.object_box)."""
        s = self.dataset
        lower, upper = (None, None) if s.empty else schema.world_bounds(s.bricks)
        meshes = mesh_set(tuple(m.path for m in scene.meshes)) if scene.meshes else None
        return instances.object_box(lower, upper,
                                    None if meshes is None else meshes.nodes[0, :, :3])

    def _check_samples_per_ray(self, sampling_rate: float) -> None:
        """Refuse a sampling rate that would take more than MAX_SAMPLES_PER_RAY samples
        on a ray through the whole dataset (its bounding box's world diagonal at the
        finest step)."""
        s = self.dataset
        extent = (s.bvh.upper_lattice[0].astype(np.float64) - s.bvh.lower_lattice[0])
        diagonal = float(np.linalg.norm(extent * s.bricks.spacing_world))
        finest = int(s.regions.finest_level.min())
        step = s.min_spacing_world * 2.0 ** finest / sampling_rate
        bound = diagonal / step
        if not bound <= MAX_SAMPLES_PER_RAY:
            raise ExabricksError(
                f"a sampling rate of {sampling_rate:g} takes up to {bound:,.0f} samples on a ray "
                f"through the data, more than the {MAX_SAMPLES_PER_RAY:,} allowed: lower it")


def render(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh, *, camera,
           transfer_function, field: str | None = None, width: int = 512, height: int = 512,
           sampling_rate: float = 2.0, spp: int = 1, seed: int = 0, jitter: bool = True,
           max_opacity: float = 0.98, unit_distance: float | None = None,
           shading: str = "headlight", depth: bool = False, device=None,
           traversal: str | None = None, lookup: str = "regions",
           reconstruction: str = "basis") -> RenderResult:
    """Render one frame of one volume layer of `field` (default: the first); see
    `Renderer.render`."""
    return Renderer(bricks, regions, bvh, field=field, device=device, lookup=lookup).render(
        camera=camera, transfer_function=transfer_function, width=width, height=height,
        sampling_rate=sampling_rate, spp=spp, seed=seed, jitter=jitter,
        max_opacity=max_opacity, unit_distance=unit_distance, shading=shading, depth=depth,
        traversal=traversal, reconstruction=reconstruction)


def render_scene(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh,
                 scene: Scene, *, device=None, traversal: str | None = None,
                 lookup: str = "regions") -> RenderResult:
    """Render `scene` (exabricks.scene.Scene), uploading only the fields it uses."""
    return Renderer(bricks, regions, bvh, fields=scene.fields(), device=device,
                    lookup=lookup).render_scene(scene, traversal=traversal)


# Default ambient-occlusion distance, in finest cell widths of the dataset.
AO_DISTANCE_CELLS = 10.0


