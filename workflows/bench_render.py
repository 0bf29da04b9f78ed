"""Benchmark the OpenCL renderer (paper §4) on the four shared datasets, both region walks.

    .venv/bin/python workflows/bench_render.py [--runs 5] [--size 512] [--only gerris,...]
                                               [--work bench-data/render] [--write-docs]

Each dataset is run through ingest, brick, regions and bvh (the `exabricks`
stage commands, once, into --work/<name>/; not timed). A `Renderer` uploads it,
then for each traversal ("ordered": the private min-heap walk, "retrace": the
paper's re-trace from the root per region) the script renders one warm-up
frame and --runs timed frames of size x size (the walks alternating) with the
default camera on the data bounds (exabricks.camera.default_camera), the default transfer function
over the field's range (exabricks.transfer_function.default_transfer_function)
and the render defaults (sampling rate 2, headlight shading, jitter, seed 0,
max opacity 0.98). Reported per frame: kernel wall time (median and min-max),
reconstructed samples, samples per second (samples / median time), and the
process CPU time per frame (median; all PoCL threads, less sensitive to other
jobs on a shared machine than wall time). The two
walks must give the same image (checked: max abs difference printed).
The datasets are the four shared real ones (workflows/benchdoc.py; `--only big`
renders the generated 23.6 M-cell one instead).
--write-docs replaces the "## render (PoCL)" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "workflows"))

import benchdoc  # noqa: E402

from exabricks import schema  # noqa: E402
from exabricks.camera import default_camera  # noqa: E402
from exabricks.stages.render import TRAVERSALS, Renderer  # noqa: E402
from exabricks.transfer_function import default_transfer_function  # noqa: E402

SECTION = "render (PoCL)"
DEFAULT = ("gerris", "amrex", "athena", "enzo")

NOTES = """
ms/frame is the kernel's wall time per frame (`Renderer.render` stats "ms": enqueue
to finish, no upload or read-back); samples are the reconstructions the kernel
counts (one per sub-interval of the adaptive sampling, §4.2-4.3); CPU ms/frame is
the process CPU time of a `render` call (both PoCL threads). Both walks give the
same image (max abs difference printed by the script).

Changes that helped (each checked against the float64 reference tests; figures
are kernel ms per 512x512 frame, headlight / shading none, quiet machine):
the ordered min-heap walk (one BVH traversal per ray instead of one per region;
re-tracing costs 3.5-4.5x the ordered walk per region visited, which matters
most on octree data such as the Gerris plume, about one region per cell);
forcing inlining of the per-brick and heap helpers (PoCL had kept eb_add_brick
and eb_queue_expand as calls); -cl-no-signed-zeros -cl-denorms-are-zero (about
5 %); the opacity correction 1 - (1 - alpha)^(len / unit) with log2 and exp2
inlined as polynomials (PoCL calls its library pair out of line; that one line
was a quarter of a shading-none frame) and headlight shading with rsqrt on a
gradient prescaled on the host, so that no length() and division are needed:
AMReX 343 / 314 -> 293 / 247 ms, Gerris 412 / 345 -> 373 / 301 ms, Enzo
263 / 223 -> 236 / 186 ms; images within 1e-4 of before (rounding of the
shading normal where the field is locally constant), opacity within 2e-7 of
float64 (tests/test_render.py).
Tried without a measurable gain (within the +-5 % noise of interleaved runs):
work-groups of 16x16, 32x4 and 64x1 instead of 8x8; copying a region's brick
boxes, dims and value pointers into private memory once per region; one
32-byte record per brick instead of three arrays; guessing the transfer-function
segment from uniform knots before the binary search (the search is about 5 %
of a frame); native_exp2/native_log2 (the same code as exp2/log2 on PoCL).

Where the time goes now: PoCL runs the kernel as scalar code, one work-item
after another (the divergent loops defeat its work-group vectorizer), so a
frame costs the latency of each sample's dependent chain: the reconstruction
(the hat sums of every brick of the region's list, 3.2-4.4 per region by count,
1.1-2.9 by volume), the transfer function, the opacity and the compositing;
headlight shading adds 20-30 %. The walk alone is 8-30 % of a frame. The
uniform-grid marcher (same transfer function, opacity and compositing code, one
trilinear lookup per sample) is measured in the same run as ours in the section
"exabricks vs yt, cell location and the uniform-grid ceiling". Left to try:
several rays of a tile traced together with explicit SIMD (float8 over 8 rays),
which is what it takes to use the cores' vector units here.
"""


def stage(*args: str) -> None:
    """Run one `exabricks` stage command; stop with its message if it fails."""
    proc = subprocess.run([sys.executable, "-m", "exabricks.cli.main", *args],
                          capture_output=True, text=True, cwd=ROOT)
    if proc.returncode:
        sys.exit(f"exabricks {' '.join(args)} failed: {proc.stderr.strip()}")


def ensure_scene(work: Path, dataset: benchdoc.Dataset) -> Path:
    """--work/<key>/{cells,bricks,regions,bvh}.npz, built on first use."""
    d = work / dataset.key
    d.mkdir(parents=True, exist_ok=True)
    if not (d / "cells.npz").exists():
        stage("ingest", str(dataset.path), "-o", str(d / "cells.npz"), *dataset.ingest_flags)
    steps = [("brick", "cells", "bricks"), ("regions", "bricks", "regions"), ("bvh", "regions", "bvh")]
    for command, src, out in steps:
        if not (d / f"{out}.npz").exists():
            stage(command, str(d / f"{src}.npz"), "-o", str(d / f"{out}.npz"))
    return d


def bench_one(d: Path, field: str, frames: int, size: int):
    """{traversal: (times ms, samples, rgba)}, plus the device description."""
    b = schema.load(d / "bricks.npz", "bricks")
    r = schema.load(d / "regions.npz", "regions")
    v = schema.load(d / "bvh.npz", "bvh")
    renderer = Renderer(b, r, v, field=field)
    values = b.values[b.field_index(field)]
    tf = default_transfer_function((float(values.min()), float(values.max())))
    lo, hi = schema.world_bounds(b)
    cam = default_camera(np.asarray(lo), np.asarray(hi))
    times = {t: [] for t in TRAVERSALS}
    cpu = {t: [] for t in TRAVERSALS}
    last = {}
    # The walks alternate frame by frame, so a change in machine load hits both alike.
    for i in range(frames + 1):
        for traversal in TRAVERSALS:
            c0 = time.process_time()
            result = renderer.render(camera=cam, transfer_function=tf, width=size, height=size,
                                     traversal=traversal)
            if i:  # round 0 is the warm-up
                times[traversal].append(result.stats["ms"])
                cpu[traversal].append(1e3 * (time.process_time() - c0))
            last[traversal] = result
    out = {t: (np.array(times[t]), last[t].stats["samples"], last[t].rgba, np.array(cpu[t]))
           for t in TRAVERSALS}
    scene = renderer.scene
    device = (f"{scene.device.name.strip()} ({scene.device.platform.version.strip()}, "
              f"{scene.device.max_compute_units} compute units)")
    return out, device


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs_help="timed frames per walk after one warm-up "
                             "frame (default 5)")
    parser.add_argument("--frames", dest="runs", type=int, default=argparse.SUPPRESS,
                        help=argparse.SUPPRESS)  # old name
    parser.add_argument("--size", type=int, default=512, help="image width and height")
    parser.add_argument("--work", type=Path, default=ROOT / "bench-data" / "render",
                        help="where the stage outputs are kept")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")

    rows, device = [], "?"
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, list(sets)) if args.only else DEFAULT
    for key in keys:
        name, field = sets[key].name, sets[key].field
        d = ensure_scene(args.work, sets[key])
        results, device = bench_one(d, field, args.runs, args.size)
        images = [results[t][2] for t in TRAVERSALS]
        diff = float(np.max(np.abs(images[0] - images[1])))
        for traversal in TRAVERSALS:
            times, samples, _, cpu = results[traversal]
            med = float(np.median(times))
            row = (f"| {name} | {field} | {traversal} | {benchdoc.fmt_spread(times, '', 0)} "
                   f"| {samples:,} | {samples / med / 1e3:.1f} | {np.median(cpu):.0f} |")
            rows.append(row)
            print(row, flush=True)
        print(f"  {name}: max |ordered - retrace| = {diff:.2e}", flush=True)

    command = "`.venv/bin/python workflows/bench_render.py" + (
        f" --only {','.join(keys)}" if args.only else "") + f" --runs {args.runs}" + (
        f" --size {args.size}" if args.size != 512 else "") + " --write-docs`"
    section = (f"Command: {command}\n\n"
               f"- machine: {benchdoc.machine()}, load average {benchdoc.load_average()} "
               f"at the end\n- OpenCL device: {device}\n"
               f"- frames: {args.size}x{args.size}, default camera and transfer function, "
               f"median of {args.runs} frames after one warm-up, the two walks alternating "
               f"frame by frame (min-max in brackets)\n\n"
               "| dataset | field | traversal | ms/frame | samples/frame | M samples/s | CPU ms/frame |\n"
               "|---|---|---|---:|---:|---:|---:|\n"
               + "\n".join(rows) + "\n" + NOTES)
    benchdoc.publish(SECTION, section, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
