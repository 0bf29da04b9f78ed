"""What the peers of benchmarks/bench_peers.py share: the datasets, the settings every
tool renders with, the shared view, and the timing helpers.

Shared view: the default three-quarter camera of the world bounds; the
built-in default preset (viridis) over the field's (min, max) with its
opacity ramp 0 -> 1 scaled by --alpha-scale (0.1: semi-transparent, as volume
rendering is used; 1 is what `exabricks render` does by default); opacity
unit = largest domain extent / 128 (the finest cell of amrex, athena and gerris;
Enzo's finest cell, 1/2048 of the box, would make its 16^3 root cells opaque in
one step). Enzo renders x-velocity: every other Enzo field spans 3-7 decades,
which a transfer function linear in the value shows as almost nothing.

shell256 is make_big.py's thin-shell layout at --size 256 (1.1 M cells, 4
levels; benchdoc.ensure_shell makes it): the octree-like layout of the other
benchmarks at a size yt loads.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

DATA = ROOT / "tests" / "data"
if not (DATA / "amrex-advection3d").is_dir():
    DATA = ROOT.parent / "shared" / "data"

# name: (path, field, how yt gets the data: "native" = yt.load, "grids" = our leaf cells
# converted to nested grids for yt.load_amr_grids, see yt_grids.to_amr_grids)
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
MAX_OPACITY = 0.98
SEED = 0
ALPHA_SCALE = 0.1           # opacity ramp 0 -> 0.1: semi-transparent, as volume rendering is used
OPACITY_UNIT_CELLS = 128    # opacity unit = largest domain extent / this (opacity_unit)
MAX_VOXELS = 512 ** 3        # the uniform grid's cap (float32: 512 MiB)


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


def view_of(cells, alpha_scale: float):
    """The benchmark's camera (the default three-quarter view of the world bounds) and
    transfer function (the built-in default over the field's value range, its opacity
    ramp 0 -> 1 scaled by `alpha_scale`)."""
    from exabricks import schema
    from exabricks.picture.camera import default_camera

    lo, hi = schema.world_bounds(cells)
    values = cells.values[0]
    value_range = (float(np.nanmin(values)), float(np.nanmax(values)))
    tf = transfer_function(value_range, alpha_scale)
    return default_camera(lo, hi), tf, (lo, hi), value_range


def transfer_function(value_range, alpha_scale: float = ALPHA_SCALE):
    """The benchmark's transfer function: the built-in default over `value_range`, its
    opacity ramp 0 -> 1 scaled by `alpha_scale`."""
    from exabricks.picture.transfer_function import TransferFunction, default_transfer_function

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
