"""exabricks against yt, VTK, per-sample cell location and the uniform-grid ceiling.

    .venv/bin/python -m benchmarks.bench_peers [--datasets amrex,athena,gerris,enzo,shell256,big]
        [--size 1024] [--runs 5] [--no-yt] [--yt-max-cells 10000000]
        [--no-vtk] [--vtk-threads CORES]
        [--docs docs/benchmarks.md] [--images docs/images]

For every dataset the workers run one after the other, each in its own
subprocess (so that each one's peak resident memory is its own), with the same
field, camera, transfer function and image size:

0. prepare (the offline stages, timed but not part of any comparison):
   readers.read, then brick + regions + BVH in memory, saved as .npz with
   exabricks.schema; it also fixes the shared view (below).
1. exabricks: loading the three .npz files, the OpenCL program build (pyopencl's
   binary cache warm after the first run), `Renderer` construction (buffer
   uploads), then the same Renderer with lookup="cell-location" (the
   tree over the brick supports built in memory, the -DEB_CELL_LOCATION
   program, no second upload), and the uniform-grid ceiling: the dataset
   resampled at its finest resolution (lattice bounding box, capped at
   --max-voxels) by the basis reconstruction itself and rendered by
   kernels/uniform_grid.cl (benchmarks/uniform_grid.py: `resample`,
   `UniformGridRenderer`; trilinear, constant step finest cell / sampling
   rate, the same sample placement, transfer function, opacity correction,
   compositing and early termination). Frames at the default sampling rate 2
   and at 10 samples per finest cell ("equal sample density" with yt's 10
   samples per cell): after one warm-up frame of each, --runs rounds of one
   regions frame, one cell-location frame and one uniform-grid frame, so that
   the load of a shared machine hits all three alike; the median (min-max) of
   each. Pure emission-absorption (shading="none", as yt's default and the
   uniform marcher), interleaved jitter on (the renderer's default; seed 0),
   early termination at 0.98. Samples are counted the same way in both
   kernels (every reconstruction / trilinear lookup, whether or not it is
   transparent). Peak RSS of ours is read before the uniform grid is made.
2. yt 4.4.3: `import yt`, `yt.load` (or yt.load_amr_grids, below) + `ds.index`,
   scene set-up (Scene, VolumeSource, transfer function, perspective camera,
   and the AMRKDTree with its vertex-centred bricks, which yt otherwise builds
   in the first render), then `sc.render()`: median of --runs after a warm-up.
   yt's default sampling: `num_samples = 10` samples per cell crossing. Skipped
   on datasets with more than --yt-max-cells leaf cells (default 10 M: yt never
   finished loading the 23.6 M-cell "big" dataset); the table says so.
3. VTK (the `vtk` wheel from PyPI, 9.7), ParaView's CPU way, offscreen: the worker sets
   VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow (EGL on Mesa's llvmpipe: Debian's libegl1,
   libegl-mesa0, libgl1-mesa-dri; no X server) and LP_NUM_THREADS=--vtk-threads before
   VTK loads. The reader ParaView would use (VTK_READERS: vtkAMReXGridReader,
   vtkAMREnzoReader in code units, vtkXdmfReader on Athena++'s .athdf.xdmf; Gerris and
   the ExaJet files have none: "no VTK reader"), every level, the field as cell data.
   (a) vtkResampleToImage to the finest level's cell centres over the domain (the finest
   cell size read from VTK's data; skipped above --max-voxels, e.g. Enzo's 2048^3), then
   vtkFixedPointVolumeRayCastMapper with --vtk-threads threads and a fixed sample
   distance of half a finest cell: resample seconds, first image (reader + resample +
   render window + first frame) and the median of --runs frames (render + read-back)
   after it. (b) vtkAMRVolumeMapper on the reader's vtkOverlappingAMR (Athena's XDMF
   gives disjoint blocks, not an AMR: not run): first image and frames likewise, and the
   grid it resampled to (its own vtkAMRResampleFilter's report on stderr, and the same
   filter run again outside it for the spacing) and the render mode its smart mapper
   chose. Images are compared with ours at rate 2 (the same sample spacing).

Regions vs cell location (paper §6.4.2, Table 3): both reconstructions take
the same samples (the regions decide where), and sum every sample's bricks in
the same order, so their frames are equal; only how a sample finds its bricks
differs (the region's list, or a descent of the brick-support tree from the
root, kernels/cell_location.cl).

The uniform-grid ceiling was checked when an earlier run showed it at 10-30 M
samples/s and slower per sample at rate 10 than at rate 2: its samples are
counted like ours (tests/test_bench_peers.py: on one region both take exactly
the same samples), and interleaved with ours it runs at about the same rate per
sample at both rates (rate 10 slightly faster: neighbouring samples share
voxels). The earlier figures came from timing each tool in its own process at
a different time on a shared machine. About three quarters of its time is the
transfer function lookup (a binary search over the preset's 256 knots) and the
opacity correction (exp2/log2), the same code as ours: without them its
trilinear lookups and stepping run about four times as fast (AMReX at 512^2:
180-190 instead of 42-45 M samples/s).

How yt is matched (yt/visualization/volume_rendering/lens.py, camera.py,
utilities/orientation.py, utilities/lib/image_samplers.pyx,
field_interpolation_tables.pxd):

* Camera: `cam.focus = look_at`, then `cam.set_position(position,
  north_vector=up)` (setting the focus resets north). yt's unit vectors are
  east = north x normal (= -our right), north (= our up'), normal = focus -
  position. PerspectiveLens (lens.py, _get_sampler_params) starts every ray at
  the camera position, ray [i, j] along ``normal w2 + w0 (i/(N-1) - 1/2) east +
  w1 (j/(M-1) - 1/2) north`` (w = cam.width; w1 is forced to w0 M/N): yt's
  first and last rays go through the image *edges*. Ours go through pixel
  centres, u = 2 (col + 1/2)/W - 1, so ``w0 / w2 = 2 tan(fovy/2) aspect (W - 1)/W``
  makes every yt ray one of ours exactly: ray [i, j] is our pixel (row H-1-j,
  col W-1-i) (square images; for W != H yt's forced w1 gives the vertical span
  (W-1)/W instead of (H-1)/H, so non-square sizes are refused). We use w2 = 2 L
  (L below) so that yt's brick-ordering viewpoint (lens.front_center = focus +
  w2/2 normal) lies beyond the data. The image `sc.render()` returns is that
  ray grid rotated by 180 degrees, i.e. ours transposed: ours[row, col] =
  yt_image[col, row]. tests/test_bench_peers.py checks the rays exactly and the
  orientation with an off-centre cube.
* Transfer function: a ColorTransferFunction with grey_opacity=True, bounds
  [lo - d, hi + d] (d = 1e-3 (hi - lo); yt makes values on or outside its
  bounds transparent, ours clamp), log_field = False (our function is linear
  in the data value), nbins = 4096, and its tables filled at yt's nodes
  (`tf.funcs[c].x`, the values where yt's piecewise-linear table is exact)
  from our `TransferFunction.evaluate`: red/green/blue = our colour, alpha =
  sigma(x) = -ln(1 - alpha(x)) * L / unit_distance. yt composites
  ``rgba = dt sigma rgb + (1 - dt sigma) rgba`` with dt in units of its ray
  parameter t (one t spans |ray vector| = L = |position - domain centre| +
  |domain width|/2 on the central ray), i.e. linearised emission-absorption
  with extinction sigma per unit t; ours is 1 - (1 - alpha)^(dt/unit) per step.
  Alpha is clipped to 1 - 1e-6 before the log. Off-axis rays are longer in
  yt's t (by 1/cos of the angle to the axis, <= 7 % at fovy 30), so their
  extinction per world length is that much lower; yt has no early termination.
* Differences that remain: yt walks each ray from the camera but composites
  every new sample *in front of* the accumulated colour (its brick order is
  furthest-first from front_center, which lies behind the data), so
  occlusion is reversed with respect to ours;
  yt's reconstruction is trilinear within each brick from vertex values it
  averages from cell values (no ghost zones), not the basis method.

ExaJet data (gerris, big, shell256) has no yt front end (and yt.load_octree says of
itself that "fluid fields will not work yet, or possibly ever"): our reader's
leaf cells are turned into properly nested grids
(`exabricks.readers.yt_bridge.to_amr_grids`) and given to
yt.load_amr_grids. yt then has exactly our leaves and values (checked on the
Gerris plume); the conversion is timed on its own and not counted as yt's
load, but it is part of the yt process's peak memory. Where the data has a
hole (make_big.py's thin shells drop every cell whose centre lies in a sphere,
so refined cells there lack children), yt, which has no empty cells, gets the
missing cells as leaves of a value below its transfer function's bounds:
transparent, as the hole is in ours (its vertex values next to the hole mix
that value in, so yt's image differs there).

shell256 is make_big.py's thin-shell layout at --size 256 (1.1 M cells, 4
levels; benchdoc.ensure_shell makes it): the octree-like layout of the other
benchmarks at a size yt loads.

How VTK is matched (vtk_camera_parameters, vtk_volume_property, vtk_image_to_ours;
tests/test_bench_peers.py checks each): the vtkCamera gets our position, look_at as focal
point, our up' as view up and fovy as (vertical) view angle, with a clipping range around
the data; VTK's perspective projection puts pixel centres where ours are, so the ray of
every pixel is ours; VTK's frame starts at the bottom row and is flipped. The colour and
opacity knots go into a vtkColorTransferFunction (RGB space) and a vtkPiecewiseFunction,
clamped as ours, with SetScalarOpacityUnitDistance(unit): VTK's opacity correction
1 - (1 - alpha)^(dt / unit) is ours. Differences that remain: the resampled grid holds
cell values at cell centres (coarse cells repeated) and is trilinear between them, and
stops half a finest cell inside each face; the fixed-point caster composites in 15 bits
and stops at full opacity; the 8-bit framebuffer; vtkAMRVolumeMapper's coarse grid.

Shared view: the default three-quarter camera of the world bounds; the
built-in default preset (viridis) over the field's (min, max) with its
opacity ramp 0 -> 1 scaled by --alpha-scale (0.1: semi-transparent, as volume
rendering is used; 1 is what `exabricks render` does by default); opacity
unit = largest domain extent / 128 (the finest cell of amrex, athena and gerris;
Enzo's finest cell, 1/2048 of the box, would make its 16^3 root cells opaque in
one step). Enzo renders x-velocity: every other Enzo field spans 3-7 decades,
which a transfer function linear in the value shows as almost nothing.

Results: the tables on stdout and as the section "## exabricks vs yt, cell
location and the uniform-grid ceiling" of --docs (benchmarks/benchdoc.py
replace_section; the other sections stay), and docs/images/peers-NAME.png
(ours | yt | VTK resample + fixed point | vtkAMRVolumeMapper | uniform grid,
un-premultiplied over black). All timings are
provisional on a shared machine; the command is written into the section.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc

ROOT = Path(__file__).resolve().parents[1]

DATA = ROOT / "tests" / "data"
if not (DATA / "amrex-advection3d").is_dir():
    DATA = ROOT.parent / "shared" / "data"

# name: (path, field, how yt gets the data: "native" = yt.load, "grids" = our leaf cells
# converted to nested grids for yt.load_amr_grids, see yt_bridge.to_amr_grids)
DATASETS = {
    "amrex": (DATA / "amrex-advection3d" / "plt00020", "phi", "native"),
    "athena": (DATA / "athena-blast3d" / "Blast.out2.00001.athdf", "rho", "native"),
    "gerris": (ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells", "T", "grids"),
    # Every other Enzo field spans 3-7 decades: under a transfer function linear in
    # the value (ours) almost all of the volume would be transparent.
    "enzo": (DATA / "enzo-moving7" / "moving7_0010", "x-velocity", "native"),
    # benchmarks/make_big.py's 512^3 volume merged to 23.6 M cells on 6 levels
    # (made by benchmarks/bench_ingest.py when missing).
    "big": (ROOT / "bench-data" / "big512.cells", "value", "grids"),
    # benchmarks/make_big.py's octree-like thin shells at --size 256: 1.1 M cells on 4
    # levels, small enough for yt (the 20.6 M-cell size of the other benchmarks is
    # not); made by benchdoc.ensure_shell(256) when missing.
    "shell256": (ROOT / "bench-data" / "shell256.cells", "rho", "grids"),
}
RATES = (2.0, 10.0)          # ours: the default, and yt's 10 samples per cell
RATE_KEYS = tuple(str(r) for r in RATES)  # the results' keys: '2.0', '10.0'
YT_NUM_SAMPLES = 10          # yt's VolumeSource default
MAX_OPACITY = 0.98
SEED = 0
YT_NBINS = 4096
YT_PAD = 1e-3                # yt's bounds: the value range widened by this fraction each side
ALPHA_CLIP = 1.0 - 1e-6      # -ln(1 - alpha) is infinite at alpha = 1
ALPHA_SCALE = 0.1           # opacity ramp 0 -> 0.1: semi-transparent, as volume rendering is used
OPACITY_UNIT_CELLS = 128    # opacity unit = largest domain extent / this (opacity_unit)
MAX_VOXELS = 512 ** 3        # the uniform grid's cap (float32: 512 MiB)
# yt is skipped above this many leaf cells: it never finished loading the 23.6 M-cell
# "big" dataset (hours, then killed), and every other dataset has under 1 M.
YT_MAX_CELLS = 10_000_000
SECTION = "exabricks vs yt, cell location and the uniform-grid ceiling"
# The targets: yt / ours frame time at each tool's default sampling and with ours
# at RATES[-1]; cell location / regions kernel time; ours / uniform-grid samples per second.
# Issue 15's targets (issue 10's for cell location): yt's on the block-structured
# datasets, VTK's as VTK time / ours (its frame at half a finest cell, ours at rate 2).
TARGETS = {"yt_default": 6.0, "yt_equal": 2.5, "cell_location": 2.0, "ceiling": 0.8,
           "vtk_frame": 2.0, "vtk_first_image": 3.0,
           # issue 10's, on octree-like data
           "yt_default_octree": 3.0, "yt_equal_octree": 1.2}
BLOCK_STRUCTURED = ("amrex", "athena")
OCTREE_LIKE = ("gerris", "shell256")


# ----------------------------------------------------------------------------- helpers


def timed_runs(fn, runs: int):
    """One warm-up call, then `runs` timed calls: (warm-up seconds, seconds list, last result)."""
    t = time.perf_counter()
    result = fn()
    first = time.perf_counter() - t
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
    return first, times, result


# ----------------------------------------------------------------------------- exabricks side


def build_scene(path: Path, field: str):
    """Cells -> bricks -> regions -> BVH in memory: (bricks, regions, bvh, seconds read, seconds build)."""
    from exabricks import readers
    from exabricks.stages.brick import build_bricks
    from exabricks.stages.bvh import build_bvh
    from exabricks.stages.regions import build_regions

    t0 = time.perf_counter()
    cells = readers.read(path, fields=[field])
    t1 = time.perf_counter()
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    bvh = build_bvh(regions)
    t2 = time.perf_counter()
    return cells, bricks, regions, bvh, t1 - t0, t2 - t1


def view_of(cells, alpha_scale: float):
    """The benchmark's camera (the default three-quarter view of the world bounds) and
    transfer function (the built-in default over the field's value range, its opacity
    ramp 0 -> 1 scaled by `alpha_scale`)."""
    from exabricks import schema
    from exabricks.camera import default_camera

    lo, hi = schema.world_bounds(cells)
    values = cells.values[0]
    value_range = (float(np.nanmin(values)), float(np.nanmax(values)))
    tf = transfer_function(value_range, alpha_scale)
    return default_camera(lo, hi), tf, (lo, hi), value_range


def transfer_function(value_range, alpha_scale: float = ALPHA_SCALE):
    """The benchmark's transfer function: the built-in default over `value_range`, its
    opacity ramp 0 -> 1 scaled by `alpha_scale`."""
    from exabricks.transfer_function import TransferFunction, default_transfer_function

    tf = default_transfer_function(value_range)
    alpha = tf.alpha_points.copy()
    alpha[:, 1] *= alpha_scale
    return TransferFunction(tf.rgb_points, alpha, tf.name)


def opacity_unit(bounds) -> float:
    """The opacity unit of every tool: the largest world extent / OPACITY_UNIT_CELLS.

    For the 128^3-finest datasets (amrex, athena, gerris) that is the finest cell,
    the renderer's default; Enzo's finest cell (1/2048 of the box) would make its
    16^3 root cells opaque in one step.
    """
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    return float((hi - lo).max()) / OPACITY_UNIT_CELLS


def scene_paths(spec: dict) -> dict:
    return {kind: spec["image_prefix"] + f"-{kind}.npz" for kind in ("bricks", "regions", "bvh")}


def worker_prepare(spec: dict) -> dict:
    """The offline stages (ingest, brick, regions, bvh) in memory, saved as .npz; the view."""
    from exabricks import schema
    from exabricks.render.device_data import finest_cell_width_world

    cells, bricks, regions, bvh, t_read, t_build = build_scene(Path(spec["path"]), spec["field"])
    camera, tf, bounds, value_range = view_of(cells, spec["alpha_scale"])
    stats = regions.meta["statistics"]
    t = time.perf_counter()
    for kind, obj in (("bricks", bricks), ("regions", regions), ("bvh", bvh)):
        schema.save(scene_paths(spec)[kind], obj)
    return {"cells": cells.n_cells, "bricks": bricks.n_bricks, "regions": regions.n_regions,
            "levels": int(cells.level.max()) + 1, "read_s": t_read, "build_s": t_build,
            "save_s": time.perf_counter() - t, "camera": camera.to_dict(),
            "transfer_function": tf.to_paraview_dict(), "world_bounds": [list(b) for b in bounds],
            "value_range": list(value_range), "unit_distance": opacity_unit(bounds),
            "finest_cell_world": finest_cell_width_world(bricks),
            "bricks_per_region_by_count": stats["avg_bricks_per_region_by_count"],
            "bricks_per_region_by_volume": stats["avg_bricks_per_region_by_volume"]}


def load_scene(spec: dict):
    from exabricks import schema

    paths = scene_paths(spec)
    return tuple(schema.load(paths[kind], kind) for kind in ("bricks", "regions", "bvh"))


def interleaved(frames: dict, runs: int) -> dict:
    """One warm-up call of every frame function, then `runs` rounds calling each in turn,
    so that machine load hits all alike. A frame function returns (kernel seconds,
    samples, rgba). Returns {name: {"first_frame_s", "frame_s" (list), "kernel_s" (list),
    "samples"}} and, apart, the last rgba of each."""
    out = {name: {"frame_s": [], "kernel_s": []} for name in frames}
    images = {}
    for name, frame in frames.items():
        t = time.perf_counter()
        frame()
        out[name]["first_frame_s"] = time.perf_counter() - t
    for _ in range(runs):
        for name, frame in frames.items():
            t = time.perf_counter()
            kernel_s, samples, images[name] = frame()
            out[name]["frame_s"].append(time.perf_counter() - t)
            out[name]["kernel_s"].append(kernel_s)
            out[name]["samples"] = samples
    return out, images


def worker_exabricks(spec: dict) -> dict:
    """Ours with the regions' brick lists, ours with per-sample cell location and the
    uniform-grid ceiling, their frames interleaved (module docstring)."""
    import resource

    from exabricks import opencl
    from exabricks.camera import Camera
    from benchmarks import uniform_grid
    from exabricks.render.cell_location import build_brick_tree
    from exabricks.render.renderer import Renderer
    from exabricks.transfer_function import TransferFunction

    field, size, runs, unit = spec["field"], spec["size"], spec["runs"], spec["unit_distance"]
    camera = Camera.from_dict(spec["camera"])
    tf = TransferFunction.from_paraview_dict(spec["transfer_function"])
    t = time.perf_counter()
    bricks, regions, bvh = load_scene(spec)
    t_load = time.perf_counter() - t
    t = time.perf_counter()
    device = opencl.choose_device(None)
    opencl.program_for(opencl.context_for(device)[0])  # memoised: Renderer reuses it
    t_kernels = time.perf_counter() - t
    t = time.perf_counter()
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    t_renderer = time.perf_counter() - t
    t = time.perf_counter()
    located = renderer.with_lookup("cell-location")
    t_located = time.perf_counter() - t
    tree = renderer.scene.brick_tree
    t = time.perf_counter()
    build_brick_tree(bricks)  # again, without numba's first-call cache load
    t_tree = time.perf_counter() - t
    out = {"load_s": t_load, "kernel_build_s": t_kernels, "upload_s": t_renderer,
           "device": renderer.device_name, "rates": {},
           "cell_location": {"setup_s": t_located, "tree_build_s": t_tree,
                             "tree_first_build_s": renderer.scene.brick_tree_seconds,
                             "tree_nodes": int(tree.first.shape[0]), "tree_depth": tree.depth,
                             "rates": {}},
           # Ours alone, before the uniform grid is resampled (Linux: KiB).
           "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}

    lower, dims = uniform_grid.finest_grid(bricks)
    uniform = out["uniform"] = {"dims": [int(d) for d in dims], "voxels": int(np.prod(dims)),
                                "fits": bool(np.prod(dims) <= spec["max_voxels"]), "rates": {}}
    marcher = None
    if uniform["fits"]:
        t = time.perf_counter()
        volume = uniform_grid.resample(renderer.scene, lower, dims)
        uniform["resample_s"] = time.perf_counter() - t
        uniform["nan_voxels"] = int(np.isnan(volume).sum())
        marcher = uniform_grid.UniformGridRenderer(volume, lower, bricks.origin_world,
                                                   bricks.spacing_world, device=device)
        del volume

    def ours(r, rate):
        def frame():
            result = r.render(camera=camera, transfer_function=tf, width=size, height=size,
                              sampling_rate=rate, seed=SEED, jitter=True,
                              max_opacity=MAX_OPACITY, unit_distance=unit, shading="none")
            return result.stats["ms"] / 1e3, result.stats["samples"], result.rgba
        return frame

    def ceiling(rate):
        def frame():
            rgba, samples, seconds = marcher.render(camera=camera, transfer_function=tf,
                                                    width=size, height=size, sampling_rate=rate,
                                                    unit_distance=unit)
            return seconds, samples, rgba
        return frame

    for rate in RATES:
        frames = {"regions": ours(renderer, rate), "cell-location": ours(located, rate)}
        if marcher is not None:
            frames["uniform"] = ceiling(rate)
        measured, images = interleaved(frames, runs)
        key = str(rate)
        out["rates"][key] = measured["regions"]
        out["cell_location"]["rates"][key] = {
            **measured["cell-location"],
            "max_abs_vs_regions": float(np.abs(images["cell-location"] - images["regions"]).max())}
        np.save(spec["image_prefix"] + f"-ours-{rate:g}.npy", images["regions"])
        if marcher is not None:
            uniform["rates"][key] = measured["uniform"]
            np.save(spec["image_prefix"] + f"-uniform-{rate:g}.npy", images["uniform"])
    return out


# ----------------------------------------------------------------------------- yt side


def yt_camera_width(camera, width: int, height: int, depth: float) -> list[float]:
    """yt `cam.width` whose perspective rays are exactly our pixel-centre rays (module docstring)."""
    if width != height:
        raise ValueError("yt's perspective lens forces width[1] = width[0] * H / W: use square images")
    half = math.tan(math.radians(camera.fovy) / 2.0)
    w0 = 2.0 * depth * half * (width / height) * (width - 1) / width
    return [w0, w0 * height / width, depth]


def yt_transfer_function(tf, x_bounds, *, ray_length: float, unit_distance: float,
                         nbins: int = YT_NBINS):
    """A yt ColorTransferFunction equal to `tf` at its nodes (module docstring).

    ray_length: world length of one unit of yt's ray parameter t; unit_distance:
    our opacity unit (world). Returns the ColorTransferFunction (grey opacity).
    """
    from yt.visualization.volume_rendering.transfer_functions import ColorTransferFunction

    ytf = ColorTransferFunction(x_bounds, nbins=nbins, grey_opacity=True)
    rgba = tf.evaluate(ytf.funcs[0].x)
    for c in range(3):
        ytf.funcs[c].y[:] = rgba[:, c]
    ytf.funcs[3].y[:] = yt_extinction(rgba[:, 3], ray_length, unit_distance)
    return ytf


def yt_extinction(alpha, ray_length: float, unit_distance: float) -> np.ndarray:
    """yt's alpha table: extinction per unit ray parameter from our slab opacity."""
    alpha = np.minimum(np.asarray(alpha, np.float64), ALPHA_CLIP)
    return -np.log1p(-alpha) * (ray_length / unit_distance)


def yt_image_to_ours(image) -> np.ndarray:
    """The (N, N, 4) image `sc.render()` returns as our float32 (row, col, rgba) layout:
    yt's ray grid rotated by 180 degrees, i.e. ours transposed (module docstring)."""
    return np.ascontiguousarray(np.asarray(image).transpose(1, 0, 2)).astype(np.float32)


def yt_bounds(value_range) -> tuple[float, float]:
    """yt's transfer-function bounds: `value_range` widened by YT_PAD of its width each side
    (of max(1, |value|) for a constant field), since yt drops values on or outside them."""
    lo, hi = value_range
    pad = YT_PAD * (hi - lo) if hi > lo else YT_PAD * max(1.0, abs(lo))
    return lo - pad, hi + pad


def worker_yt(spec: dict) -> dict:
    from exabricks.camera import Camera
    from exabricks.transfer_function import TransferFunction

    camera = Camera.from_dict(spec["camera"])
    tf = TransferFunction.from_paraview_dict(spec["transfer_function"])
    size, runs = spec["size"], spec["runs"]
    t = time.perf_counter()
    import yt
    from yt.visualization.volume_rendering.api import Scene, create_volume_source
    t_import = time.perf_counter() - t
    yt.set_log_level(40)

    t_convert = None
    if spec["yt_mode"] == "grids":
        from exabricks import readers, schema
        from exabricks.readers import yt_bridge

        t = time.perf_counter()
        cells = readers.read(spec["path"], fields=[spec["field"]])
        # Cells missing from the data (the thin shells' hole) become leaves of a value
        # below yt's bounds, which its transfer function makes transparent.
        low, high = yt_bounds(spec["value_range"])
        grids, top = yt_bridge.to_amr_grids(cells, source=spec["path"],
                                            fill=low - (high - low))
        lo, hi = (np.asarray(b) for b in schema.world_bounds(cells))
        root = np.rint((hi - lo) / cells.spacing_world / (1 << top)).astype(int)
        del cells
        t_convert = time.perf_counter() - t
        t = time.perf_counter()
        ds = yt.load_amr_grids(grids, root, bbox=np.column_stack([lo, hi]), length_unit=1.0)
        del grids
    else:
        t = time.perf_counter()
        ds = yt.load(spec["path"])
    ds.index  # noqa: B018  (builds the grid hierarchy)
    t_load = time.perf_counter() - t
    fields = [f for f in ds.field_list if f[1] == spec["field"]]
    if not fields:
        raise SystemExit(f"yt: no field {spec['field']!r} in {spec['path']}")

    t = time.perf_counter()
    sc = Scene()
    source = create_volume_source(ds.all_data(), fields[0])
    source.log_field = False
    centre = ds.domain_center.to("code_length").d
    domain_width = ds.domain_width.to("code_length").d
    position = np.asarray(camera.position)
    ray_length = float(np.linalg.norm(position - centre) + 0.5 * np.linalg.norm(domain_width))
    source.transfer_function = yt_transfer_function(
        tf, yt_bounds(spec["value_range"]), ray_length=ray_length,
        unit_distance=spec["unit_distance"])
    sc.add_source(source)
    cam = sc.add_camera(ds, lens_type="perspective")
    cam.resolution = (size, size)
    cam.focus = ds.arr(camera.look_at, "code_length")
    cam.set_position(ds.arr(camera.position, "code_length"), north_vector=np.asarray(camera.up))
    depth = 2.0 * ray_length
    cam.width = ds.arr(yt_camera_width(camera, size, size, depth), "code_length")
    # The AMRKDTree and its vertex-centred bricks, exactly as yt's validate_volume
    # decorator builds them in the first render (render_source.py).
    source.volume.set_fields([source.field], [source.log_field], no_ghost=not source.use_ghost_zones)
    source._volume_valid = True
    t_setup = time.perf_counter() - t
    source.num_samples = YT_NUM_SAMPLES

    def frame():
        return np.asarray(sc.render())

    first_s, times, image = timed_runs(frame, runs)
    rgba = yt_image_to_ours(image)
    np.save(spec["image_prefix"] + "-yt.npy", rgba)
    return {"import_s": t_import, "convert_s": t_convert, "load_index_s": t_load, "setup_s": t_setup,
            "first_frame_s": first_s, "frame_s": times, "grids": int(ds.index.num_grids),
            "ray_length": ray_length, "num_samples": YT_NUM_SAMPLES,
            "unit_vectors": np.asarray(cam.unit_vectors).tolist()}


# ----------------------------------------------------------------------------- VTK side

# The VTK reader ParaView opens each dataset with (None: VTK has none) and the file it
# opens: the plotfile directory, Enzo's .hierarchy, Athena++'s .athdf.xdmf sidecar.
VTK_READERS = {"amrex": ("vtkAMReXGridReader", ""), "enzo": ("vtkAMREnzoReader", ".hierarchy"),
               "athena": ("vtkXdmfReader", ".xdmf"), "gerris": None, "big": None,
               "shell256": None}
VTK_WINDOW = "vtkEGLRenderWindow"   # offscreen OpenGL through EGL (Mesa's llvmpipe here)
VTK_SAMPLES_PER_CELL = RATES[0]     # fixed-point sample distance: finest cell / this (ours' rate 2)


def vtk_source(name: str, path) -> Path | None:
    """The file VTK's reader opens for dataset `name` at `path` (None: VTK has no reader).
    A sidecar missing beside `path` (tests/data holds no .xdmf) is looked for in the
    shared data folder's copy of the dataset."""
    reader = VTK_READERS.get(name)
    if reader is None:
        return None
    source = Path(str(path) + reader[1])
    shared = ROOT.parent / "shared" / "data" / source.parent.name / source.name
    return shared if not source.exists() and shared.exists() else source


def vtk_skip_reason(name: str, path) -> str | None:
    """Why VTK is not run on a dataset (None: it is run)."""
    source = vtk_source(name, path)
    if source is None:
        return "no VTK reader"
    if not source.exists():
        return f"no VTK input: {source.name} missing"
    return None


def vtk_finest_grid(bounds, spacing) -> tuple[list[int], list[float]]:
    """The finest level's cell-centred lattice over `bounds` (VTK's (xmin, xmax, ymin, ymax,
    zmin, zmax)) with cell size `spacing` (3,): (dims = extent / spacing, rounded;
    vtkResampleToImage's sampling bounds, the first and last cell centres on each axis)."""
    b = np.asarray(bounds, np.float64).reshape(3, 2)
    h = np.asarray(spacing, np.float64)
    if (h <= 0).any() or not np.isfinite(h).all():
        raise ValueError(f"finest cell size must be positive, got {h.tolist()}")
    dims = np.rint((b[:, 1] - b[:, 0]) / h).astype(np.int64)
    if (dims < 1).any():
        raise ValueError(f"bounds {b.tolist()} hold no cell of size {h.tolist()}")
    sampling = np.column_stack([b[:, 0] + 0.5 * h, b[:, 0] + (dims - 0.5) * h]).ravel()
    return [int(d) for d in dims], [float(x) for x in sampling]


def vtk_camera_parameters(camera, world_bounds) -> dict:
    """vtkCamera settings that see exactly what `camera` sees (module docstring): position,
    focal point = look_at, view up = our up' (orthogonal to the view), view angle = fovy
    (VTK's angle is vertical unless UseHorizontalViewAngle), and a clipping range
    (depths along the view direction) that holds the whole box `world_bounds` ([lo, hi])."""
    position = np.asarray(camera.position, np.float64)
    forward = np.asarray(camera.look_at, np.float64) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera.up, np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    lo, hi = (np.asarray(b, np.float64) for b in world_bounds)
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    depth = (corners - position) @ forward
    far = float(depth.max()) * 1.01
    if far <= 0.0:
        raise ValueError("the data lies behind the camera")
    near = max(float(depth.min()) * 0.99, far * 1e-4)
    return {"position": position.tolist(), "focal_point": list(camera.look_at),
            "view_up": up.tolist(), "view_angle": float(camera.fovy),
            "clipping_range": [near, far]}


def apply_vtk_camera(vtk_camera, params: dict) -> None:
    """Set a vtkCamera from `vtk_camera_parameters`."""
    vtk_camera.SetParallelProjection(False)
    vtk_camera.SetUseHorizontalViewAngle(False)
    vtk_camera.SetPosition(*params["position"])
    vtk_camera.SetFocalPoint(*params["focal_point"])
    vtk_camera.SetViewUp(*params["view_up"])
    vtk_camera.SetViewAngle(params["view_angle"])
    vtk_camera.SetClippingRange(*params["clipping_range"])


def vtk_volume_property(tf, unit_distance: float):
    """A vtkVolumeProperty equal to `tf`: a vtkColorTransferFunction (RGB space) through its
    colour knots and a vtkPiecewiseFunction through its opacity knots, both clamped outside
    (as ours), opacity per `unit_distance` (VTK corrects a step dt to
    1 - (1 - alpha)^(dt / unit), as we do), no shading, trilinear interpolation."""
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction, vtkVolumeProperty

    colour = vtkColorTransferFunction()
    colour.SetColorSpaceToRGB()
    colour.SetClamping(True)
    for x, r, g, b in tf.rgb_points:
        colour.AddRGBPoint(float(x), float(r), float(g), float(b))
    opacity = vtkPiecewiseFunction()
    opacity.SetClamping(True)
    for x, a in tf.alpha_points:
        opacity.AddPoint(float(x), float(a))
    prop = vtkVolumeProperty()
    prop.SetColor(colour)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(float(unit_distance))
    prop.ShadeOff()
    prop.SetInterpolationTypeToLinear()
    return prop


def vtk_image_to_ours(pixels, width: int, height: int) -> np.ndarray:
    """VTK's RGBA floats (rows from the bottom, premultiplied over the transparent black
    background) as our float32 (row from the top, col, rgba) layout."""
    image = np.asarray(pixels, np.float32).reshape(height, width, 4)
    return np.ascontiguousarray(image[::-1])


# vtkAMRResampleFilter reports on stderr how it resampled (vtkAMRResampleFilter.cxx):
# the level it resolves to, the grid it made and the levels it took values from.
_AMR_LOG = {
    "requested_max_level": (r"Requested Max Level = (\d+)", int),
    "requested_dims": (r"Request Grid Dim : (\d+), (\d+), (\d+)", int),
    "computed_dims": (r"Computed Grid Dim: (\d+), (\d+), (\d+)", int),
    "adjusted_dims": (r"Adjusted Grid Dim: (\d+), (\d+), (\d+)", int),
    "levels_loaded": (r"Number Levels Loaded = (\d+)", int),
    "blocks_loaded": (r"Number of Blocks = (\d+)", int),
    "average_level": (r"Average Level: ([-+0-9.eE]+|nan)", float),
    "failed_points": (r"Number Of Failed Points: (\d+)", int),
}


def parse_amr_resampler_log(text: str) -> dict:
    """The figures vtkAMRResampleFilter printed (the last of each), as {key: value or list}."""
    import re

    out = {}
    for key, (pattern, kind) in _AMR_LOG.items():
        found = re.findall(pattern, text)
        if found:
            last = found[-1]
            out[key] = [kind(x) for x in last] if isinstance(last, tuple) else kind(last)
    return out


class _StderrCapture:
    """Collect what C++ code writes to file descriptor 2 inside a `with` block (.text)."""

    def __enter__(self):
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, *exc):
        sys.stderr.flush()
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._file.seek(0)
        self.text = self._file.read().decode(errors="replace")
        self._file.close()
        return False


def _vtk_reader(kind: str, source: str, field: str):
    """A VTK reader of `source` with `field` (cell data) selected and every level loaded."""
    if kind == "vtkXdmfReader":
        from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

        reader = vtkXdmfReader()
        reader.SetFileName(source)
        reader.UpdateInformation()
        for i in range(reader.GetNumberOfCellArrays()):
            name = reader.GetCellArrayName(i)
            reader.SetCellArrayStatus(name, int(name == field))
        return reader
    from vtkmodules import vtkIOAMR

    reader = getattr(vtkIOAMR, kind)()
    reader.SetFileName(source)
    if kind == "vtkAMREnzoReader":
        reader.SetConvertToCGS(False)  # code units, as our reader and the transfer function
    reader.UpdateInformation()
    reader.SetMaxLevel(max(reader.GetNumberOfLevels(), 1) + 1)  # default: level 0 only
    for i in range(reader.GetNumberOfCellArrays()):
        name = reader.GetCellArrayName(i)
        reader.SetCellArrayStatus(name, int(name == field))
    return reader


def _vtk_finest_spacing(data) -> list[float]:
    """The smallest cell size (per axis) of a vtkOverlappingAMR (its finest level) or of the
    leaf blocks of any other composite data set (image or rectilinear grids)."""
    from vtkmodules.vtkCommonDataModel import vtkOverlappingAMR
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if isinstance(data, vtkOverlappingAMR):
        h = [0.0, 0.0, 0.0]
        data.GetSpacing(data.GetNumberOfLevels() - 1, h)
        return h
    h = np.full(3, np.inf)
    it = data.NewIterator()
    it.InitTraversal()
    while not it.IsDoneWithTraversal():
        block = it.GetCurrentDataObject()
        if hasattr(block, "GetXCoordinates"):
            for a, coords in enumerate((block.GetXCoordinates(), block.GetYCoordinates(),
                                        block.GetZCoordinates())):
                c = vtk_to_numpy(coords)
                if c.size > 1:
                    h[a] = min(h[a], float(np.diff(c).min()))
        elif hasattr(block, "GetSpacing"):
            h = np.minimum(h, block.GetSpacing())
        it.GoToNextItem()
    return h.tolist()


def worker_vtk(spec: dict) -> dict:
    """VTK the way ParaView renders AMR on a CPU (module docstring): (a) the reader,
    vtkResampleToImage to the finest level's cell centres, vtkFixedPointVolumeRayCastMapper;
    (b) vtkAMRVolumeMapper on the reader's vtkOverlappingAMR. Offscreen through EGL."""
    threads = int(spec.get("vtk_threads") or os.cpu_count() or 1)
    # Read when the first render window is made (VTK) and when Mesa starts (llvmpipe).
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = VTK_WINDOW
    os.environ["LP_NUM_THREADS"] = str(threads)
    from exabricks.camera import Camera
    from exabricks.transfer_function import TransferFunction

    camera = Camera.from_dict(spec["camera"])
    tf = TransferFunction.from_paraview_dict(spec["transfer_function"])
    size, runs, field, unit = spec["size"], spec["runs"], spec["field"], spec["unit_distance"]
    kind = VTK_READERS[spec["name"]][0]
    source = str(vtk_source(spec["name"], spec["path"]))
    view = vtk_camera_parameters(camera, spec["world_bounds"])

    t = time.perf_counter()
    import importlib

    # The OpenGL render window and the OpenGL volume mappers, registered on import.
    for module in ("vtkmodules.vtkRenderingOpenGL2", "vtkmodules.vtkRenderingVolumeOpenGL2"):
        importlib.import_module(module)
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkFloatArray, vtkVersion
    from vtkmodules.vtkCommonDataModel import vtkOverlappingAMR
    from vtkmodules.vtkRenderingCore import vtkCamera, vtkRenderer, vtkRenderWindow, vtkVolume
    t_import = time.perf_counter() - t

    def window(volume):
        rw = vtkRenderWindow()
        rw.SetOffScreenRendering(True)
        rw.SetMultiSamples(0)
        rw.SetAlphaBitPlanes(True)
        rw.SetSize(size, size)
        ren = vtkRenderer()
        ren.SetBackground(0.0, 0.0, 0.0)
        ren.SetBackgroundAlpha(0.0)
        cam = vtkCamera()
        apply_vtk_camera(cam, view)
        ren.SetActiveCamera(cam)
        ren.AddVolume(volume)
        rw.AddRenderer(ren)
        out["window"] = rw.GetClassName()  # vtkEGLRenderWindow unless VTK fell back
        return rw, ren

    def frame(rw):
        """Render, and read the frame back (as ours does): our image layout."""
        rw.Render()
        pixels = vtkFloatArray()
        rw.GetRGBAPixelData(0, 0, size - 1, size - 1, 0, pixels, 0)
        return vtk_image_to_ours(vtk_to_numpy(pixels), size, size)

    def steady(rw):
        times = []
        for _ in range(runs):
            t = time.perf_counter()
            image = frame(rw)
            times.append(time.perf_counter() - t)
        return times, image

    out = {"version": vtkVersion.GetVTKVersion(), "import_s": t_import, "reader": kind,
           "threads": threads, "camera": view}

    # (a) ParaView's CPU way: resample to the finest grid, fixed-point ray caster.
    t0 = time.perf_counter()
    reader = _vtk_reader(kind, source, field)
    reader.Update()
    t_read = time.perf_counter() - t0
    data = reader.GetOutputDataObject(0)
    if data is None:
        raise SystemExit(f"VTK {kind}: nothing read from {source}")
    is_amr = isinstance(data, vtkOverlappingAMR)
    bounds = [0.0] * 6
    data.GetBounds(bounds)
    spacing = _vtk_finest_spacing(data)
    dims, sampling = vtk_finest_grid(bounds, spacing)
    out.update(bounds=bounds, finest_spacing=spacing, finest_dims=dims, amr=is_amr,
               levels=data.GetNumberOfLevels() if is_amr else None)
    a = out["resample"] = {"read_s": t_read, "dims": dims}
    if int(np.prod(dims)) > spec["max_voxels"]:
        a["error"] = f"finest grid {'x'.join(map(str, dims))} > --max-voxels {spec['max_voxels']:,}"
    else:
        from vtkmodules.vtkFiltersCore import vtkResampleToImage
        from vtkmodules.vtkRenderingVolume import vtkFixedPointVolumeRayCastMapper

        t = time.perf_counter()
        resample = vtkResampleToImage()
        resample.SetInputConnection(reader.GetOutputPort())
        resample.SetUseInputBounds(False)
        resample.SetSamplingBounds(*sampling)
        resample.SetSamplingDimensions(*dims)
        resample.Update()
        a["resample_s"] = time.perf_counter() - t
        image = resample.GetOutput()
        valid = image.GetPointData().GetArray("vtkValidPointMask")
        a["invalid_points"] = 0 if valid is None else int((vtk_to_numpy(valid) == 0).sum())
        step = min(spacing) / VTK_SAMPLES_PER_CELL
        mapper = vtkFixedPointVolumeRayCastMapper()
        mapper.SetInputData(image)
        mapper.SetScalarModeToUsePointFieldData()
        mapper.SelectScalarArray(field)
        mapper.SetNumberOfThreads(threads)
        mapper.SetAutoAdjustSampleDistances(False)
        mapper.SetLockSampleDistanceToInputSpacing(False)
        mapper.SetSampleDistance(step)
        mapper.SetInteractiveSampleDistance(step)
        mapper.SetImageSampleDistance(1.0)
        volume = vtkVolume()
        volume.SetMapper(mapper)
        volume.SetProperty(vtk_volume_property(tf, unit))
        t = time.perf_counter()
        rw, _ = window(volume)
        frame(rw)
        a["first_frame_s"] = time.perf_counter() - t
        a["first_image_s"] = time.perf_counter() - t0
        a["frame_s"], rgba = steady(rw)
        a["sample_distance"] = mapper.GetSampleDistance()
        a["mapper_threads"] = mapper.GetNumberOfThreads()
        out["gl_renderer"] = _gl_renderer(rw)
        np.save(spec["image_prefix"] + "-vtk.npy", rgba)
        del rw, mapper, volume, image, resample
    del reader, data

    # (b) vtkAMRVolumeMapper: the reader's AMR, resampled by the mapper itself.
    if not is_amr:
        out["amr_mapper"] = {"error": "not an AMR data set (vtkAMRVolumeMapper needs a "
                                      "vtkOverlappingAMR)"}
        return out
    from vtkmodules.vtkRenderingVolumeAMR import vtkAMRVolumeMapper

    b = out["amr_mapper"] = {}
    t0 = time.perf_counter()
    reader = _vtk_reader(kind, source, field)
    mapper = vtkAMRVolumeMapper()
    mapper.SetInputConnection(reader.GetOutputPort())
    mapper.SetScalarModeToUseCellFieldData()
    mapper.SelectScalarArray(field)
    volume = vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(vtk_volume_property(tf, unit))
    rw, ren = window(volume)
    with _StderrCapture() as log:
        frame(rw)
    b["first_image_s"] = time.perf_counter() - t0
    b["frame_s"], rgba = steady(rw)
    out.setdefault("gl_renderer", _gl_renderer(rw))
    b["samples_requested"] = list(mapper.GetNumberOfSamples())
    b["render_mode_requested"] = mapper.GetRequestedRenderMode()
    b["resampler"] = parse_amr_resampler_log(log.text)
    b.update(_amr_mapper_grid(reader, ren, mapper, field))
    np.save(spec["image_prefix"] + "-vtk-amr.npy", rgba)
    return out


def _gl_renderer(render_window) -> str:
    """The OpenGL renderer string of a render window that has rendered (e.g. llvmpipe)."""
    caps = render_window.ReportCapabilities() or ""
    return next((line.split(":", 1)[1].strip() for line in caps.splitlines()
                 if line.startswith("OpenGL renderer string")), "?")


def _amr_mapper_grid(reader, ren, mapper, field: str) -> dict:
    """The grid vtkAMRVolumeMapper resampled to, made again outside it the same way
    (vtkAMRVolumeMapper.cxx UpdateResamplerFrustrumMethod: a vtkAMRResampleFilter in
    demand-driven mode over the data's part of the view frustum, NumberOfSamples points,
    biased along the view direction), and which mode its smart mapper renders in."""
    from vtkmodules.vtkFiltersAMR import vtkAMRResampleFilter
    from vtkmodules.vtkRenderingVolumeAMR import vtkAMRVolumeMapper
    from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkSmartVolumeMapper

    cam = ren.GetActiveCamera()
    region = [0.0] * 6
    bounds = [0.0] * 6
    reader.GetOutputDataObject(0).GetBounds(bounds)
    vtkAMRVolumeMapper.ComputeResamplerBoundsFrustumMethod(cam, ren, bounds, region)
    resampler = vtkAMRResampleFilter()
    resampler.SetInputConnection(reader.GetOutputPort())
    resampler.SetDemandDrivenMode(0)  # as in the mapper: its input carries no AMR meta-data
    resampler.SetNumberOfSamples(*mapper.GetNumberOfSamples())
    resampler.SetMin(region[0], region[2], region[4])
    resampler.SetMax(region[1], region[3], region[5])
    resampler.SetBiasVector(*cam.GetDirectionOfProjection())
    resampler.SetUseBiasVector(True)
    with _StderrCapture() as log:
        resampler.Update()
    grid = resampler.GetOutput().GetBlock(0)
    out = {"frustum_region": region, "replica_log": parse_amr_resampler_log(log.text)}
    if grid is None:
        return out
    out.update(grid_dims=list(grid.GetDimensions()), grid_spacing=list(grid.GetSpacing()),
               grid_origin=list(grid.GetOrigin()))
    smart = vtkSmartVolumeMapper()
    smart.SetInputData(grid)
    smart.SetScalarModeToUsePointFieldData()
    smart.SelectScalarArray(field)
    probe = ren.GetVolumes().GetLastProp()
    probe.SetMapper(smart)
    ren.GetRenderWindow().Render()
    used = smart.GetLastUsedRenderMode()
    out["render_mode"] = {smart.RayCastRenderMode: "ray cast (CPU)", smart.GPURenderMode: "GPU",
                          smart.OSPRayRenderMode: "OSPRay"}.get(used, str(used))
    probe.SetMapper(mapper)
    return out


WORKERS = {"prepare": worker_prepare, "exabricks": worker_exabricks, "yt": worker_yt,
           "vtk": worker_vtk}


# ----------------------------------------------------------------------------- driver


def run_worker(kind: str, spec: dict, workdir: Path) -> dict:
    """Run one worker in a subprocess; its result plus peak RSS (MiB), unless the worker
    measured its own (the exabricks worker: before the uniform grid). The worker starts
    from benchdoc's small launcher, so its peak is its own and not this process's."""
    spec_path = workdir / f"{spec['name']}-{kind}-spec.json"
    result_path = workdir / f"{spec['name']}-{kind}-result.json"
    spec_path.write_text(json.dumps(spec))
    try:
        _, _, peak = benchdoc.run_child([sys.executable, str(Path(__file__).resolve()), "--worker",
                                         kind, str(spec_path), str(result_path)])
    except SystemExit as e:
        return {"error": f"{kind} worker failed: {str(e).splitlines()[-1][:200]}"}
    if not result_path.is_file():
        return {"error": f"{kind} worker wrote no result"}
    result = json.loads(result_path.read_text())
    result.setdefault("peak_rss_mib", peak / 2**20)
    return result


def side_by_side(paths, out: Path, size: int) -> None:
    """ours | yt | VTK (resample + fixed point) | VTK (vtkAMRVolumeMapper) | uniform grid
    (the images at `paths`, in that order) as one PNG, each composited over black; a
    missing image is a grey tile, so the columns line up across datasets."""
    from PIL import Image

    from exabricks.image_io import to_png_pixels

    tiles = []
    for p in paths:
        if Path(p).is_file():
            pixels = to_png_pixels(np.load(p)).astype(np.float64)
            tiles.append(np.rint(pixels[..., :3] * pixels[..., 3:4] / 255.0).astype(np.uint8))
        else:
            tiles.append(np.full((size, size, 3), 64, np.uint8))
    gap = np.full((size, 4, 3), 255, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(row).save(out)


def image_agreement(ours_path: str, other_path: str) -> dict | None:
    """compare_images metrics (rmse, psnr, max_abs, ssim) of two saved images, or None."""
    from exabricks.stages.compare import compare_images

    if not (Path(ours_path).is_file() and Path(other_path).is_file()):
        return None
    return compare_images(np.load(ours_path), np.load(other_path))


def fmt_s(times) -> str:
    """'median (min-max)' of a list of seconds; '-' for none."""
    return benchdoc.fmt_spread(times, unit="") if times else "-"


def fmt_ms(times) -> str:
    return benchdoc.fmt_spread(1e3 * np.asarray(times), unit="", digits=0) if times else "-"


def fmt_agreement(m: dict | None) -> str:
    if not m:
        return "-"
    ssim = "-" if m["ssim"] is None else f"{m['ssim']:.3f}"
    return f"{m['psnr']:.1f} / {ssim}"


def yt_skip_reason(cells: int, cap: int) -> str | None:
    """Why yt is not run on a dataset of `cells` leaf cells (None: it is run)."""
    if cells > cap:
        return f"skipped: {cells:,} cells > --yt-max-cells {cap:,}"
    return None


def bench_dataset(name: str, args, workdir: Path) -> dict:
    path, field, yt_mode = DATASETS[name]
    if name == "big" and not Path(path).exists():
        path = benchdoc.ensure_exajet()  # the big AMR in ExaJet form, from benchmarks/make_big.py
    if name == "shell256":
        path = benchdoc.ensure_shell(256)
    if not Path(path).exists():
        return {"name": name, "error": f"{path} missing"}
    base = {"name": name, "path": str(path), "field": field, "size": args.size, "runs": args.runs,
            "image_prefix": str(workdir / name), "max_voxels": args.max_voxels,
            "alpha_scale": args.alpha_scale}
    prep = run_worker("prepare", base, workdir)
    row = {"name": name, "field": field, "prep": prep}
    if "error" in prep:
        return row
    shared = {**base, "camera": prep["camera"], "transfer_function": prep["transfer_function"],
              "value_range": prep["value_range"], "unit_distance": prep["unit_distance"],
              "world_bounds": prep["world_bounds"]}
    row["ours"] = run_worker("exabricks", shared, workdir)
    row["uniform"] = row["ours"].pop("uniform", None)
    row["cell_location"] = row["ours"].pop("cell_location", None)
    if not args.no_yt:
        skip = yt_skip_reason(prep["cells"], args.yt_max_cells)
        row["yt"] = {"error": skip} if skip else \
            run_worker("yt", {**shared, "yt_mode": yt_mode}, workdir)
    if not args.no_vtk:
        import importlib.util

        skip = vtk_skip_reason(name, path) or (
            None if importlib.util.find_spec("vtk") else "vtk not installed (pip install vtk)")
        row["vtk"] = {"error": skip} if skip else \
            run_worker("vtk", {**shared, "vtk_threads": args.vtk_threads}, workdir)
    prefix = workdir / name
    low, high = (f"{r:g}" for r in RATES)
    side_by_side([f"{prefix}-ours-{low}.npy", f"{prefix}-yt.npy", f"{prefix}-vtk.npy",
                  f"{prefix}-vtk-amr.npy", f"{prefix}-uniform-{low}.npy"],
                 Path(args.images) / f"peers-{name}.png", args.size)
    row["agreement"] = {
        "yt": image_agreement(f"{prefix}-ours-{high}.npy", f"{prefix}-yt.npy"),
        # VTK samples every half finest cell: ours at the same density (rate 2).
        "vtk": image_agreement(f"{prefix}-ours-{low}.npy", f"{prefix}-vtk.npy"),
        "vtk-amr": image_agreement(f"{prefix}-ours-{low}.npy", f"{prefix}-vtk-amr.npy"),
        **{f"uniform-{r}": image_agreement(f"{prefix}-ours-{r}.npy", f"{prefix}-uniform-{r}.npy")
           for r in (low, high)}}
    return row


def _median(values) -> float:
    return benchdoc.median_spread(values)[0]


def _measured(r) -> bool:
    """Whether `r` has our frames (the prepare and exabricks workers both succeeded)."""
    o = r.get("ours", {})
    return bool(o) and "error" not in o and not r.get("error") and "error" not in r.get("prep", {})


def _span(values, digits: int = 1) -> str:
    """'lo-hi' of a list of figures, or one figure when both ends round alike."""
    lo, hi = (f"{v:.{digits}f}" for v in (min(values), max(values)))
    return lo if lo == hi else f"{lo}-{hi}"


def ceiling_ratios(rows) -> dict:
    """{(dataset, rate key): ours / uniform-grid samples per second (median kernel times)}."""
    out = {}
    for r in rows:
        u = r.get("uniform")
        if not _measured(r) or not u or not u.get("fits"):
            continue
        for rate in RATE_KEYS:
            a, b = r["ours"]["rates"][rate], u["rates"][rate]
            out[r["name"], rate] = ((a["samples"] / _median(a["kernel_s"]))
                                    / (b["samples"] / _median(b["kernel_s"])))
    return out


def yt_ratios(rows, rate: str) -> dict:
    """{dataset: median yt frame / median ours frame at `rate`} where yt ran."""
    return {r["name"]: _median(r["yt"]["frame_s"]) / _median(r["ours"]["rates"][rate]["frame_s"])
            for r in rows if _measured(r) and r.get("yt") and "error" not in r["yt"]}


def gaps(rows, machine_line: str) -> list[str]:
    """Where the time goes and what would close the gaps, with this run's figures."""
    measured = [r for r in rows if _measured(r)]
    if not measured:
        return []
    count = [r["prep"]["bricks_per_region_by_count"] for r in measured]
    volume = [r["prep"]["bricks_per_region_by_volume"] for r in measured]
    text = ("Where the time goes. Per sample ours evaluates the hat sums of every brick in its "
            f"region's list ({_span(count)} bricks per region by count, {_span(volume)} by "
            "volume on these datasets), then the same transfer function, opacity and "
            "compositing code as the uniform-grid marcher, which does one trilinear lookup "
            "per sample and no region walk.")
    if "pocl" in machine_line.lower():
        text += (" On PoCL ours reconstructs and shades the next eight samples of a ray at "
                 "once in vector registers (sample packets, kernels/packet.cl, spanning up to "
                 "three region visits), while the "
                 "marcher stays scalar (one sample at a time, as our GPU path), and yt's C ray "
                 "caster runs one OpenMP thread per core.")
    ceiling = ceiling_ratios(measured)
    if ceiling:
        (name, rate), worst = min(ceiling.items(), key=lambda kv: kv[1])
        prep = next(r["prep"] for r in measured if r["name"] == name)
        text += (f" Ours is furthest from the marcher on {name} at rate {float(rate):g} "
                 f"({worst:.2f} of its samples per second), with "
                 f"{prep['cells'] / prep['bricks']:.1f} cells per brick and "
                 f"{prep['regions'] / prep['cells']:.2f} regions per leaf cell: the smaller the "
                 "bricks and regions, the fewer samples each region visit (a heap step and a "
                 "box test) buys.")
    near = yt_ratios(measured, RATE_KEYS[-1])
    if near:
        name = min(near, key=near.get)
        text += (f" yt comes closest to ours on {name} ({near[name]:.1f}x our frame time at "
                 f"{RATES[-1]:g} samples per finest cell).")
    return [
        text,
        "",
        "What would close the gaps (these frames profiled: docs/benchmarks.md, \"Where "
        "bench_peers' frame goes (perf)\"; what bounds each missed target: \"What bounds the "
        "missed targets\"): with packets the reconstruction's gathers (one per corner, lane and "
        "listed brick) and the transfer function's are the largest parts, then the walk and the "
        "compositing; in a volume frame a packet of samples spans up to three region visits "
        "of its ray, with the union of their brick lists (7.3 of 8 lanes full on Gerris). On "
        "octree-like data the reconstruction from long lists and the region walk, which packets "
        "do not touch, weigh most, although `brick` now joins the small bricks the k-d "
        "partition leaves and packets pass over listed bricks that reach none of their lanes "
        "(docs/design.md \"Larger bricks\", \"Sample packets\"): a cheaper "
        "step from one region to the next would help there; packets of rays that share a walk "
        "would fill the lanes better on block-structured data. On a GPU the kernels run one "
        "ray per lane, one sample at a time.",
    ]


def _verdict(name: str, target: float, values: dict, unit: str) -> str:
    """One line of the targets summary: each figure, and where it falls short of `target`."""
    if not values:
        return f"- {name} (target {target:g}{unit}): not measured"
    shown = ", ".join(f"{k} {v:.2f}{unit}" for k, v in values.items())
    missed = {k: v for k, v in values.items() if v < target}
    if not missed:
        verdict = "met on every one"
    else:
        worst = min(missed.values())
        verdict = (f"missed on {', '.join(missed)} (worst {worst:.2f}{unit}, "
                   f"{target / worst:.1f}x short)")
    return f"- {name} (target {target:g}{unit}): {shown}; {verdict}"


def target_figures(rows) -> dict:
    """This run's figure for each of TARGETS: {target key: {label: figure}} (`targets`)."""
    low, high = RATE_KEYS
    cell = {}
    for r in rows:
        c = r.get("cell_location")
        if not _measured(r) or not c:
            continue
        for rate in RATE_KEYS:
            cell[f"{r['name']} rate {float(rate):g}"] = (
                _median(c["rates"][rate]["kernel_s"]) / _median(r["ours"]["rates"][rate]["kernel_s"]))
    block = lambda ratios: {k: v for k, v in ratios.items() if k in BLOCK_STRUCTURED}
    octree = lambda ratios: {k: v for k, v in ratios.items() if k in OCTREE_LIKE}
    vtk = vtk_ratios(rows)
    return {"yt_default": block(yt_ratios(rows, low)), "yt_equal": block(yt_ratios(rows, high)),
            "yt_default_octree": octree(yt_ratios(rows, low)),
            "yt_equal_octree": octree(yt_ratios(rows, high)),
            "vtk_frame": {k: v["frame"] for k, v in vtk.items() if "frame" in v},
            "vtk_first_image": {k: v["first_image"] for k, v in vtk.items() if "first_image" in v},
            "cell_location": cell,
            "ceiling": {f"{name} rate {float(rate):g}": v
                        for (name, rate), v in ceiling_ratios(rows).items()}}


def targets(rows) -> list[str]:
    """The issue's targets (TARGETS) against this run's figures, dataset by dataset."""
    figures = target_figures(rows)
    return [
        "Targets (from this run):",
        "",
        _verdict("yt / ours, each at its default sampling (block-structured datasets)",
                 TARGETS["yt_default"], figures["yt_default"], "x"),
        _verdict(f"yt / ours, ours at {RATES[-1]:g} samples per finest cell (block-structured)",
                 TARGETS["yt_equal"], figures["yt_equal"], "x"),
        _verdict("yt / ours, each at its default sampling (octree-like datasets)",
                 TARGETS["yt_default_octree"], figures["yt_default_octree"], "x"),
        _verdict(f"yt / ours, ours at {RATES[-1]:g} samples per finest cell (octree-like)",
                 TARGETS["yt_equal_octree"], figures["yt_equal_octree"], "x"),
        _verdict("VTK fixed-point frame / ours at rate 2", TARGETS["vtk_frame"],
                 figures["vtk_frame"], "x"),
        _verdict("VTK to the first image from the files / ours", TARGETS["vtk_first_image"],
                 figures["vtk_first_image"], "x"),
        _verdict("cell location / regions", TARGETS["cell_location"], figures["cell_location"], "x"),
        _verdict("ours / uniform-grid samples per second", TARGETS["ceiling"], figures["ceiling"], ""),
    ]


def _off_axis_stretch(camera_dict: dict, size: int) -> float:
    """Largest 1/cos(angle between a pixel's ray and the view axis) - 1 of a size^2 frame."""
    from exabricks.camera import Camera

    camera = Camera.from_dict(camera_dict)
    _, forward, _, _ = camera.frame(size, size)
    _, directions = camera.rays(size, size)
    cosine = (directions @ np.asarray(forward, np.float64)) / (
        np.linalg.norm(directions, axis=-1) * np.linalg.norm(forward))
    return float((1.0 / cosine).max() - 1.0)


def unit_note(rows) -> str:
    """What the opacity unit is, in finest cells, dataset by dataset (from the rows)."""
    cells = {}
    for r in rows:
        prep = r.get("prep", {})
        if "unit_distance" in prep:
            cells.setdefault(f"{prep['unit_distance'] / prep['finest_cell_world']:g}", []).append(
                r["name"])
    return "; ".join(f"{n} finest cell{'s' if n != '1' else ''} of {', '.join(names)}"
                     for n, names in cells.items())


def ours_first_image_s(r) -> float:
    """Our time from the raw dataset to the first image: read + brick/regions/BVH build (the
    prepare worker, without saving) + OpenCL program + upload + the first frame at rate 2."""
    prep, o = r["prep"], r["ours"]
    return (prep["read_s"] + prep["build_s"] + o["kernel_build_s"] + o["upload_s"]
            + o["rates"][RATE_KEYS[0]]["first_frame_s"])


def vtk_ratios(rows) -> dict:
    """{dataset: {figure: VTK / ours}} where VTK ran: "frame" (median fixed-point frame /
    median ours frame at rate 2), "first_image" (VTK's reader + resample + first frame /
    ours_first_image_s), and "amr_frame", "amr_first_image" for vtkAMRVolumeMapper."""
    out = {}
    for r in rows:
        v = r.get("vtk")
        if not _measured(r) or not v or "error" in v:
            continue
        ours_frame, ours_first = _median(r["ours"]["rates"][RATE_KEYS[0]]["frame_s"]), \
            ours_first_image_s(r)
        figures = {}
        for prefix, part in (("", v.get("resample", {})), ("amr_", v.get("amr_mapper", {}))):
            if part.get("frame_s") and "error" not in part:
                figures[prefix + "frame"] = _median(part["frame_s"]) / ours_frame
                figures[prefix + "first_image"] = part["first_image_s"] / ours_first
        out[r["name"]] = figures
    return out


def _amr_grid(b: dict, finest) -> str:
    """'48x58x46 points, 2.2-2.8 finest cells apart' of vtkAMRVolumeMapper's grid."""
    if "grid_dims" not in b:
        return "-"
    cells = np.asarray(b["grid_spacing"], np.float64) / np.asarray(finest, np.float64)
    points = "x".join(map(str, b["grid_dims"]))
    return f"{points} points, {_span(cells.tolist())} finest cells apart"


def vtk_tables(rows, args) -> list[str]:
    """The two VTK tables of the report (module docstring, "How VTK is matched")."""
    low = RATE_KEYS[0]
    ratios = vtk_ratios(rows)
    lines = [
        "| dataset (field) | VTK reader | finest grid (resampled) | VTK read / resample s "
        "| VTK frame s (fixed point) | VTK first image s | ours frame s, rate "
        f"{float(low):g} | VTK / ours frame | ours first image s | VTK / ours first image "
        f"| peak RSS VTK MiB | image VTK vs ours (rate {float(low):g}): PSNR dB / SSIM |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    amr = [
        "| dataset | vtkAMRVolumeMapper grid (default 128^3 samples over the view frustum) "
        "| its level of resolution / finest level / mean level sampled | render mode "
        "| frame s | first image s "
        "| frame / ours | first image / ours "
        f"| image vs ours (rate {float(low):g}): PSNR dB / SSIM |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        name = f"{r['name']} ({r.get('field', '-')})"
        v = r.get("vtk")
        failed = r.get("error") or r.get("prep", {}).get("error") or r.get("ours", {}).get("error")
        if failed or not v or "error" in v:
            why = failed or (v["error"] if v else "not run (--no-vtk)")
            lines.append(f"| {name} | {why} |" + " |" * 10)
            amr.append(f"| {r['name']} | {why} |" + " |" * 7)
            continue
        o, a, b = r["ours"], v.get("resample", {}), v.get("amr_mapper", {})
        f_low = o["rates"][low]["frame_s"]
        ours_first = ours_first_image_s(r)
        agreement = r.get("agreement", {})
        grid = "x".join(map(str, v["finest_dims"]))
        if "error" in a or not a.get("frame_s"):
            lines.append(f"| {name} | {v['reader']} | {a.get('error', 'no frames')} "
                         f"| {a.get('read_s', 0.0):.2f} / - | - | - | {fmt_s(f_low)} | - "
                         f"| {ours_first:.2f} | - | {v.get('peak_rss_mib', 0.0):.0f} | - |")
        else:
            lines.append(
                f"| {name} | {v['reader']} | {grid} | {a['read_s']:.2f} / {a['resample_s']:.2f} "
                f"| {fmt_s(a['frame_s'])} | {a['first_image_s']:.2f} | {fmt_s(f_low)} "
                f"| {ratios[r['name']]['frame']:.1f}x | {ours_first:.2f} "
                f"| {ratios[r['name']]['first_image']:.1f}x | {v.get('peak_rss_mib', 0.0):.0f} "
                f"| {fmt_agreement(agreement.get('vtk'))} |")
        if "error" in b or not b.get("frame_s"):
            amr.append(f"| {r['name']} | {b.get('error', 'no frames')} |" + " |" * 7)
        else:
            log = b.get("resampler", {})
            level, mean = log.get("requested_max_level"), log.get("average_level")
            levels = (f"{'-' if level is None else level} / {(v.get('levels') or 0) - 1} / "
                      f"{'-' if mean is None else f'{mean:.2f}'}")
            amr.append(
                f"| {r['name']} | {_amr_grid(b, v['finest_spacing'])} "
                f"| {levels} | {b.get('render_mode', '-')} "
                f"| {fmt_s(b['frame_s'])} | {b['first_image_s']:.2f} "
                f"| {ratios[r['name']]['amr_frame']:.1f}x "
                f"| {ratios[r['name']]['amr_first_image']:.1f}x "
                f"| {fmt_agreement(agreement.get('vtk-amr'))} |")
    ran = [r["vtk"] for r in rows if r.get("vtk") and "threads" in r["vtk"]]
    threads = ", ".join(map(str, sorted({v["threads"] for v in ran}))) or \
        str(getattr(args, "vtk_threads", "-"))
    renderer = ", ".join(sorted({v.get("gl_renderer", "?") for v in ran})) or "Mesa's llvmpipe"
    version = " " + "/".join(sorted({v["version"] for v in ran})) if ran else ""
    return [
        f"### exabricks vs VTK{version} (ParaView's CPU way; same field, camera, transfer "
        "function, image size)",
        "",
        "VTK renders offscreen through EGL (`VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow`) on "
        f"{renderer}, `LP_NUM_THREADS={threads}`. *Resample + fixed point*: the dataset's VTK "
        "reader (every level, the field as cell data), `vtkResampleToImage` to the finest "
        "level's cell centres over the domain (once), `vtkFixedPointVolumeRayCastMapper` "
        f"({threads} threads, sample distance half a finest cell, i.e. ours at rate "
        f"{float(low):g}, no automatic adjustment, trilinear, no shading); first image = "
        "reader + resample + render window + first frame; frame = render + read-back, the "
        f"median of {args.runs} after that. *vtkAMRVolumeMapper*: on the reader's "
        "vtkOverlappingAMR, which it resamples itself to NumberOfSamples (default 128^3) "
        "points spread over the bounding box of the view frustum between the data's nearest "
        "and farthest depth, clipped to the domain (so fewer points land in the data), and "
        "renders with a vtkSmartVolumeMapper (render mode: what it chose here). Its grid is "
        "rebuilt outside it the same way to read the spacing; the level of resolution is what "
        "its vtkAMRResampleFilter printed (it still takes values from every level the reader "
        "loaded). Ours: first image = read + build (no .npz round trip) + OpenCL program + "
        f"upload + first frame; frames at rate {float(low):g}, shading none. Ratios above 1: "
        "VTK slower. Datasets without a VTK reader say so.",
        "",
        *lines,
        "",
        *amr,
    ]


def report(rows, machine_line: str, args) -> list[str]:
    """The markdown body of the docs section (module docstring)."""
    low, high = RATE_KEYS
    rl, rh = float(low), float(high)
    command = (f".venv/bin/python -m benchmarks.bench_peers --datasets {args.datasets} "
               f"--size {args.size} --runs {args.runs}")
    if args.no_yt:
        command += " --no-yt"
    no_vtk = getattr(args, "no_vtk", False)
    if no_vtk:
        command += " --no-vtk"
    lines = [
        f"Command: `{command}`",
        "",
        f"- machine: {machine_line}",
        f"- frames: {args.size}x{args.size}, the median of {args.runs} frames after one warm-up "
        "(min-max in brackets); ours (both reconstructions) and the uniform grid take their "
        "frames in turn in one process, so machine load hits them alike",
        "",
        *targets(rows),
        "",
        "Where the time goes and what would close the gaps: see the notes after the tables.",
        "",
        "### exabricks vs yt (same field, camera, transfer function, image size)",
        "",
        "| dataset (field) | cells (levels) | offline: read + build s "
        "| ours: load / kernel build / upload s "
        f"| ours frame s, rate {rl:g} | ours frame s, rate {rh:g} "
        "| yt: import / load+index / scene s "
        f"| yt frame s ({YT_NUM_SAMPLES} samples/cell) | yt / ours (rate {rl:g}) "
        f"| yt / ours (rate {rh:g}) "
        f"| peak RSS ours / yt MiB | image yt vs ours (rate {rh:g}): PSNR dB / SSIM |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        prep, o = r.get("prep", {}), r.get("ours", {})
        failed = r.get("error") or prep.get("error") or o.get("error")
        if failed:
            lines.append(f"| {r['name']} | {failed} |" + " |" * 10)
            continue
        y = r.get("yt")
        f_low, f_high = o["rates"][low]["frame_s"], o["rates"][high]["frame_s"]
        if y and "error" not in y:
            yt_load = f"{y['import_s']:.2f} / {y['load_index_s']:.2f} / {y['setup_s']:.2f}"
            if y.get("convert_s") is not None:
                yt_load += f" (+ {y['convert_s']:.2f} our conversion)"
            yt_frame = fmt_s(y["frame_s"])
            ratio_low = f"{_median(y['frame_s']) / _median(f_low):.1f}x"
            ratio_high = f"{_median(y['frame_s']) / _median(f_high):.1f}x"
            rss = f"{o['peak_rss_mib']:.0f} / {y['peak_rss_mib']:.0f}"
        else:
            yt_load = yt_frame = y["error"] if y else "not run (--no-yt)"
            ratio_low = ratio_high = "-"
            rss = f"{o['peak_rss_mib']:.0f} / -"
        lines.append(
            f"| {r['name']} ({r['field']}) | {prep['cells']:,} ({prep['levels']}) "
            f"| {prep['read_s']:.2f} + {prep['build_s']:.2f} "
            f"| {o['load_s']:.2f} / {o['kernel_build_s']:.2f} / {o['upload_s']:.2f} "
            f"| {fmt_s(f_low)} | {fmt_s(f_high)} "
            f"| {yt_load} | {yt_frame} | {ratio_low} | {ratio_high} | {rss} "
            f"| {fmt_agreement(r.get('agreement', {}).get('yt'))} |")
    if not no_vtk:
        lines += ["", *vtk_tables(rows, args)]
    lines += [
        "",
        "### regions vs cell location (paper Table 3)",
        "",
        "Kernel ms per frame. Both use the regions to decide where to sample and take the "
        "same samples; *regions* reconstructs each sample from its region's brick list "
        "(paper §3.2), *cell location* finds the bricks by descending a binned-SAH tree "
        "over the brick supports (one brick per leaf) from the root for every sample "
        "(kernels/cell_location.cl, the paper's §6.4.2 comparison with the cell-location "
        "kernel of Wald et al. 2017). Speed-up: median cell location / median regions "
        "(min-max of the per-round ratios). Tree build: in a warm process (in brackets: the "
        "first build in the process, with numba loading its compiled code). Shading none, "
        "as in the rest of this section (the paper's Table 3 shades both with analytic "
        "gradients). On a CPU *regions* runs with sample packets (kernels/packet.cl) and "
        "cell location one sample at a time (a per-sample descent has no shared brick list "
        "to vectorise), so the speed-up there includes the packets' (docs/benchmarks.md, "
        "\"render (PoCL)\": 1.5-2.0x); on a GPU both run one sample at a time.",
        "",
        "| dataset | bricks | tree nodes / depth / build ms (first) | rate | samples | regions ms "
        "| cell location ms | speed-up | same frame (max abs diff) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        c = r.get("cell_location")
        if not _measured(r) or not c:
            continue
        tree = (f"{c['tree_nodes']:,} / {c['tree_depth']} / {1e3 * c['tree_build_s']:.1f} "
                f"({1e3 * c['tree_first_build_s']:.0f})")
        for rate in RATE_KEYS:
            a, b = r["ours"]["rates"][rate], c["rates"][rate]
            pairs = np.asarray(b["kernel_s"]) / np.asarray(a["kernel_s"])
            same = "yes" if b["samples"] == a["samples"] else f"no: {b['samples']:,} samples"
            lines.append(
                f"| {r['name']} | {r['prep']['bricks']:,} | {tree} | {float(rate):g} "
                f"| {a['samples']:,} | {fmt_ms(a['kernel_s'])} | {fmt_ms(b['kernel_s'])} "
                f"| {_median(b['kernel_s']) / _median(a['kernel_s']):.2f}x "
                f"({pairs.min():.2f}-{pairs.max():.2f}) "
                f"| {same} ({b['max_abs_vs_regions']:.1e}) |")
    lines += [
        "",
        "### exabricks vs the uniform-grid ceiling (median kernel time, samples counted alike)",
        "",
        "| dataset | finest grid | rate | ours samples | ours Msamples/s | uniform samples "
        "| uniform Msamples/s | ours / ceiling (samples/s) | kernel time uniform / ours "
        "| image uniform vs ours: PSNR dB / SSIM |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        u = r.get("uniform")
        if not _measured(r) or not u:
            continue
        grid = "x".join(map(str, u["dims"]))
        if not u.get("fits"):
            lines.append(f"| {r['name']} | {grid}: does not fit (> {args.max_voxels:,} voxels) |"
                         + " |" * 8)
            continue
        for rate in RATE_KEYS:
            a, b = r["ours"]["rates"][rate], u["rates"][rate]
            ka, kb = _median(a["kernel_s"]), _median(b["kernel_s"])
            rate_a, rate_b = a["samples"] / ka, b["samples"] / kb
            lines.append(
                f"| {r['name']} | {grid} | {float(rate):g} | {a['samples']:,} "
                f"| {rate_a / 1e6:.1f} | {b['samples']:,} | {rate_b / 1e6:.1f} "
                f"| {rate_a / rate_b:.2f} | {kb / ka:.2f} "
                f"| {fmt_agreement(r.get('agreement', {}).get(f'uniform-{float(rate):g}'))} |")
    preps = [r["prep"] for r in rows if "camera" in r.get("prep", {})]
    tf_names = sorted({f"`{p['transfer_function'].get('Name', 'custom')}`" for p in preps})
    skipped = [r["name"] for r in rows
               if r.get("yt") and str(r["yt"].get("error", "")).startswith("skipped")]
    lines += [
        "",
        f"Ours: pure emission-absorption (shading none), jitter on (seed {SEED}), early "
        f"termination at {MAX_OPACITY:g}, the preset {', '.join(tf_names) or '-'} "
        f"over the field's range with its opacity ramp scaled by {args.alpha_scale:g}, default "
        f"three-quarter camera, opacity unit = largest domain extent / {OPACITY_UNIT_CELLS} "
        f"({unit_note(rows) or '-'}). "
        "Offline: readers.read, then brick + regions + BVH in memory (the stages `exabricks "
        "ingest/brick/regions/bvh` run once per dataset). Ours load: the three .npz files "
        "(schema.load); kernel build: OpenCL context + program (pyopencl's binary cache warm "
        "after the first run); upload: `Renderer()` (buffers to the device). "
        "yt: `yt.load` + `ds.index`; "
        "scene = Scene, VolumeSource, transfer function, perspective camera and the AMRKDTree "
        "(vertex-centred bricks). Peak RSS of each tool in its own process (ours: before the "
        "uniform grid is resampled in the same process). yt is skipped on datasets with more "
        f"than --yt-max-cells ({args.yt_max_cells:,}) leaf cells"
        + (f" ({', '.join(skipped)} in this run). " if skipped else ". ")
        + "The uniform grid is resampled with exabricks' own basis "
        "reconstruction at every finest-cell centre (probe) and marched trilinearly with a "
        "constant step (kernels/uniform_grid.cl), with the same transfer function lookup, "
        "opacity correction and compositing code as ours. See benchmarks/bench_peers.py for "
        "how the yt camera and transfer function were matched and what still differs.",
        "",
        *gaps(rows, machine_line),
        "",
        "How yt was matched (details and the yt source lines in benchmarks/bench_peers.py):",
        "",
        "- Camera: `cam.focus = look_at`, `cam.set_position(position, north_vector=up)`, "
        "`lens_type=\"perspective\"`, `cam.width = [w0, w0, w2]` with "
        "`w0 = 2 w2 tan(fovy/2) (N-1)/N` (yt's outermost rays go through the image edges, "
        "ours through pixel centres; with this width every yt ray is exactly one of ours), "
        "w2 = 2 L (L below) so that yt's brick-ordering viewpoint lies behind the data; "
        "square images only. yt's image is ours transposed (`ours[row, col] = yt[col, row]`).",
        f"- Transfer function: ColorTransferFunction(grey_opacity=True, nbins={YT_NBINS}) over "
        f"the field range widened by {100 * YT_PAD:g} % (yt makes values on or outside its "
        "bounds transparent), "
        "`log_field = False`; tables filled at yt's nodes from our piecewise-linear function: "
        "colour = ours, alpha table = extinction `-ln(1 - alpha) L / unit_distance` per unit of "
        "yt's ray parameter (t in [0, 1] spans L = |camera - domain centre| + |domain width|/2 "
        "on the central ray); yt's step `1 - dt sigma` is the linearisation of our "
        "`(1 - alpha)^(dt / unit)`. Off-axis rays are up to 1/cos(angle) longer in t"
        + (f" (<= {100 * max(_off_axis_stretch(p['camera'], args.size) for p in preps):.1f} % "
           "in these frames)" if preps else "")
        + ", so slightly less opaque per world length in yt.",
        f"- Sampling: yt's default {YT_NUM_SAMPLES} samples per cell crossing (`num_samples`); "
        f"ours at the default {rl:g} and at {rh:g} samples per finest cell of each region.",
        "- Still different: yt walks each ray from the camera but composites each new sample "
        "*in front of* what it has accumulated, so occlusion is reversed relative to ours "
        "(two opaque slabs along the view: yt shows the far one); yt reconstructs trilinearly "
        "from vertex values averaged from cell values within each grid, we use the basis "
        "method; yt has no early ray termination. Images therefore agree in structure, "
        "not to the last bit (PSNR/SSIM column).",
        "",
    ]
    if not no_vtk:
        lines += [
            "How VTK was matched (benchmarks/bench_peers.py, `worker_vtk`):",
            "",
            "- Camera: a vtkCamera with our position, focal point = look_at, view up = our up' "
            "(orthogonal to the view), view angle = fovy (vertical) and a clipping range "
            "around the data; VTK's perspective rays and ours both go through pixel centres, "
            "so the frames coincide; VTK's image rows start at the bottom and are flipped.",
            "- Transfer function: a vtkColorTransferFunction (RGB space) through our colour "
            "knots and a vtkPiecewiseFunction through our opacity knots, both clamped, "
            "`SetScalarOpacityUnitDistance(unit_distance)`: VTK corrects a step's opacity "
            "to `1 - (1 - alpha)^(dt / unit)` as we do.",
            f"- Sampling: a constant step of half a finest cell (ours at rate {rl:g}), "
            "no jitter; images compared with ours at that rate. The frame is VTK's 8-bit "
            "framebuffer (premultiplied over transparent black), read back as floats.",
            "- Still different: the resampled grid holds each finest cell's value at its "
            "centre (coarse cells repeated), trilinear between centres, so half a finest "
            "cell at each face of the domain is not rendered; we reconstruct with the basis "
            "method. The fixed-point caster composites in 15-bit fixed point with its own "
            "tables and stops rays at full opacity (ours at "
            f"{MAX_OPACITY:g}). vtkAMRVolumeMapper samples a much coarser grid (its table "
            "row) and renders it with its own sample distance.",
            "",
        ]
    for r in rows:
        png = Path(args.images) / f"peers-{r['name']}.png"
        if png.is_file():
            lines.append(f"![{r['name']}: ours | yt | VTK resample + fixed point | "
                         "vtkAMRVolumeMapper | uniform grid (grey: not run)]"
                         f"({os.path.relpath(png, Path(args.docs).parent)})")
    return lines


def machine() -> str:
    """benchdoc's machine line with the OpenCL device and the pyopencl and yt versions."""
    versions = []
    for module, attribute in (("pyopencl", "VERSION_TEXT"), ("yt", "__version__")):
        try:
            versions.append(f"{module} {getattr(__import__(module), attribute)}")
        except ImportError:
            versions.append(f"{module} not installed")
    try:
        from importlib.metadata import version

        versions.append(f"vtk {version('vtk')}")
    except ImportError:
        versions.append("vtk not installed")
    return f"{benchdoc.machine(opencl=True)}, {', '.join(versions)} (yt: OpenMP, all cores)"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--datasets", default="amrex,athena,gerris,enzo,shell256,big")
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--docs", default=str(benchdoc.DOCS),
                   help=f"markdown file whose section '## {SECTION}' is replaced")
    p.add_argument("--images", default=str(ROOT / "docs" / "images"))
    p.add_argument("--max-voxels", type=int, default=MAX_VOXELS)
    p.add_argument("--alpha-scale", type=float, default=ALPHA_SCALE,
                   help="scale of the default preset's opacity ramp (1: the preset itself)")
    p.add_argument("--no-yt", action="store_true", help="skip yt (exabricks and the ceiling only)")
    p.add_argument("--yt-max-cells", type=int, default=YT_MAX_CELLS,
                   help="skip yt on datasets with more leaf cells than this")
    p.add_argument("--no-vtk", action="store_true",
                   help="skip VTK (resample + fixed-point ray caster, vtkAMRVolumeMapper)")
    p.add_argument("--vtk-threads", type=int, default=os.cpu_count() or 1,
                   help="threads of VTK's fixed-point ray caster and of Mesa's llvmpipe "
                        "(LP_NUM_THREADS); default: all cores")
    p.add_argument("--json", help="also write the raw results here")
    p.add_argument("--worker", nargs=3, metavar=("KIND", "SPEC", "RESULT"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        kind, spec_path, result_path = args.worker
        result = WORKERS[kind](json.loads(Path(spec_path).read_text()))
        Path(result_path).write_text(json.dumps(result))
        return 0
    names = [n.strip() for n in args.datasets.split(",") if n.strip()]
    unknown = [n for n in names if n not in DATASETS]
    if unknown:
        p.error(f"unknown dataset(s) {', '.join(unknown)} (known: {', '.join(DATASETS)})")
    if args.size < 2:
        p.error("--size must be at least 2")
    if args.runs < 1:
        p.error("--runs must be at least 1")
    if args.vtk_threads < 1:
        p.error("--vtk-threads must be at least 1")
    machine_line = machine()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-peers-") as tmp:
        for name in names:
            print(f"{name} ...", file=sys.stderr, flush=True)
            rows.append(bench_dataset(name, args, Path(tmp)))
    lines = report(rows, machine_line, args)
    print("\n".join(lines))
    benchdoc.replace_section(SECTION, "\n".join(lines), Path(args.docs))
    if args.json:
        Path(args.json).write_text(json.dumps({"machine": machine_line, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
