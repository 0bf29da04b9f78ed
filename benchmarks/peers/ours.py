"""The exabricks side of benchmarks/bench_peers.py: the prepare worker (the offline
stages and the shared view) and ours, with the regions' brick lists, with per-sample
cell location and against the uniform-grid ceiling.

worker_prepare (the offline stages, timed but not part of any comparison):
readers.read, then brick + regions + BVH in memory, saved as .npz with
exabricks.schema; it also fixes the shared view (benchmarks/peers/common.py).

worker_exabricks: loading the three .npz files, the OpenCL program build (pyopencl's
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

Regions vs cell location (paper §6.4.2, Table 3): both reconstructions take
the same samples (the regions decide where), and sum every sample's bricks in
the same order, so their frames are equal; only how a sample finds its bricks
differs (the region's list, or a descent of the brick-support tree from the
root, kernels/cell_location.cl).

The uniform-grid ceiling was checked when an earlier run showed it at 10-30 M
samples/s and slower per sample at rate 10 than at rate 2: its samples are
counted like ours (tests/bench/test_bench_peers.py: on one region both take exactly
the same samples), and interleaved with ours it runs at about the same rate per
sample at both rates (rate 10 slightly faster: neighbouring samples share
voxels). The earlier figures came from timing each tool in its own process at
a different time on a shared machine. About three quarters of its time is the
transfer function lookup (a binary search over the preset's 256 knots) and the
opacity correction (exp2/log2), the same code as ours: without them its
trilinear lookups and stepping run about four times as fast (AMReX at 512^2:
180-190 instead of 42-45 M samples/s).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from benchmarks.peers.common import MAX_OPACITY, RATES, SEED, interleaved, opacity_unit, view_of


def build_scene(path: Path, field: str):
    """Cells -> bricks -> regions -> BVH in memory: (bricks, regions, bvh, seconds read, seconds build)."""
    from exabricks import readers
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions

    t0 = time.perf_counter()
    cells = readers.read(path, fields=[field])
    t1 = time.perf_counter()
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    bvh = build_bvh(regions)
    t2 = time.perf_counter()
    return cells, bricks, regions, bvh, t1 - t0, t2 - t1


def scene_paths(spec: dict) -> dict:
    return {kind: spec["image_prefix"] + f"-{kind}.npz" for kind in ("bricks", "regions", "bvh")}


def worker_prepare(spec: dict) -> dict:
    """The offline stages (ingest, brick, regions, bvh) in memory, saved as .npz; the view."""
    from exabricks import schema
    from exabricks.engine.device_data import finest_cell_width_world

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


def worker_exabricks(spec: dict) -> dict:
    """Ours with the regions' brick lists, ours with per-sample cell location and the
    uniform-grid ceiling, their frames interleaved (module docstring)."""
    import resource

    from exabricks.device import opencl
    from exabricks.engine import variants
    from exabricks.picture.camera import Camera
    from benchmarks import uniform_grid
    from exabricks.engine.cell_location import build_brick_tree
    from exabricks.engine.renderer import Renderer
    from exabricks.picture.transfer_function import TransferFunction

    field, size, runs, unit = spec["field"], spec["size"], spec["runs"], spec["unit_distance"]
    camera = Camera.from_dict(spec["camera"])
    tf = TransferFunction.from_paraview_dict(spec["transfer_function"])
    t = time.perf_counter()
    bricks, regions, bvh = load_scene(spec)
    t_load = time.perf_counter() - t
    t = time.perf_counter()
    device = opencl.choose_device(None)
    # the program of the frames below (memoised: the Renderer reuses it)
    program = variants.program_variant(variants.frame(kind=variants.device_kind(device)))
    opencl.program_for(opencl.context_for(device)[0], program.defines, capped=program.capped)
    t_kernels = time.perf_counter() - t
    t = time.perf_counter()
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    t_renderer = time.perf_counter() - t
    t = time.perf_counter()
    located = renderer.with_lookup("cell-location")
    t_located = time.perf_counter() - t
    tree = renderer.dataset.brick_tree
    t = time.perf_counter()
    build_brick_tree(bricks)  # again, without numba's first-call cache load
    t_tree = time.perf_counter() - t
    out = {"load_s": t_load, "kernel_build_s": t_kernels, "upload_s": t_renderer,
           "device": renderer.device_name, "rates": {},
           "cell_location": {"setup_s": t_located, "tree_build_s": t_tree,
                             "tree_first_build_s": renderer.dataset.brick_tree_seconds,
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
        volume = uniform_grid.resample(renderer.dataset, lower, dims)
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
