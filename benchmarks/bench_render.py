"""Benchmark the OpenCL renderer (paper §4) on the shared datasets: region walks, sample paths.

    .venv/bin/python -m benchmarks.bench_render [--runs 5] [--size 512] [--only gerris,...]
                                               [--work bench-data/render] [--write-docs]

Each dataset is run through ingest, brick, regions and bvh (the `exabricks`
stage commands, once, into --work/<name>/; not timed). A `Renderer` uploads it,
then for each traversal ("ordered": the private min-heap walk, "retrace": the
paper's re-trace from the root per region, stackless) on each path (sample
packets or one sample at a time: on a CPU the packets and the ordered walk are
the default, on a GPU one sample and the re-trace walk), the script renders one warm-up
frame and --runs timed frames of size x size (the variants alternating) with the
default camera on the data bounds (exabricks.picture.camera.default_camera), the default transfer function
over the field's range (exabricks.picture.transfer_function.default_transfer_function)
and the render defaults (sampling rate 2, headlight shading, jitter, seed 0,
max opacity 0.98). Reported per frame: kernel wall time (median and min-max),
reconstructed samples, samples per second (samples / median time), and the
process CPU time per frame (median; all PoCL threads, less sensitive to other
jobs on a shared machine than wall time). All variants must give the same
image up to float rounding (checked: the largest difference is printed).
The datasets are the four shared real ones (benchmarks/benchdoc.py; `--only big`
renders the generated 23.6 M-cell one instead).
--write-docs replaces the "## render (PoCL)" section of docs/benchmarks.md (on a
GPU, the "## render (GPU)" section).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc

from exabricks.device import opencl
from exabricks import schema
from exabricks.picture.camera import default_camera
from exabricks.engine.renderer import TRAVERSALS, Renderer
from exabricks.picture.transfer_function import default_transfer_function

ROOT = Path(__file__).resolve().parents[1]


SECTIONS = {"CPU": "render (PoCL)", "GPU": "render (GPU)"}  # by the device's type
DEFAULT = ("gerris", "amrex", "athena", "enzo", "shell")

NOTES = """
ms/frame is the kernel's wall time per frame (`Renderer.render` stats "ms": enqueue
to finish, no upload or read-back); samples are the reconstructions the kernel
counts (one per sub-interval of the adaptive sampling, §4.2-4.3); CPU ms/frame is
the process CPU time of a `render` call (all of the OpenCL runtime's threads). Both
walks and both paths (sample packets, the CPU default, kernels/packet.cl; one sample
at a time, the GPU path) give the same image up to float rounding (the largest
difference is printed by the script).
"""

GPU_NOTES = """
On a GPU the default path runs one ray per work-item and one sample at a time; the
packet rows run the CPU's path on the GPU, for comparison. What each variant asks of
the GPU (registers, the stack frame that holds the region walk's heap) is printed
by benchmarks/kernel_resources.py, and docs/benchmarks-gpu.md "On a GPU" says what it
means for these figures.
"""


def time_notes(region_stats: dict) -> str:
    """Where a frame's time goes, with the bricks per region of the rendered datasets
    (`region_stats`: {dataset name: regions meta["statistics"]})."""
    if not region_stats:
        return ""
    count = [s["avg_bricks_per_region_by_count"] for s in region_stats.values()]
    volume = [s["avg_bricks_per_region_by_volume"] for s in region_stats.values()]
    return (
        "Where the time goes: per sample the reconstruction (the hat sums of every brick of "
        "the region's list, "
        f"{min(count):.1f}-{max(count):.1f} bricks per region by count and "
        f"{min(volume):.1f}-{max(volume):.1f} by volume on these datasets), the transfer "
        "function, the opacity and the compositing; per region visit a step of the walk. "
        "One sample at a time, PoCL runs the kernel as scalar code (the divergent loops "
        "defeat its work-group vectorizer) and each sample pays the latency of its "
        "dependent chain; with sample packets (kernels/packet.cl) a ray reconstructs and "
        "shades the next eight samples of a ray (up to three region visits) in vector "
        "registers. The profile of both "
        "paths is in the section \"Where a frame's time goes (perf)\" "
        "(benchmarks/profile_render.py). The uniform-grid marcher (same transfer function, "
        "opacity and compositing code, one trilinear lookup per sample, one sample at a "
        "time) is measured in the same run as ours in the section "
        "\"exabricks vs yt, cell location and the uniform-grid ceiling\".")


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
    if not benchdoc.up_to_date(d / "cells.npz"):
        stage("ingest", str(dataset.path), "-o", str(d / "cells.npz"), *dataset.ingest_flags)
    steps = [("brick", "cells", "bricks"), ("regions", "bricks", "regions"), ("bvh", "regions", "bvh")]
    for command, src, out in steps:
        if not benchdoc.up_to_date(d / f"{out}.npz", d / f"{src}.npz"):
            stage(command, str(d / f"{src}.npz"), "-o", str(d / f"{out}.npz"))
    return d


def variants(renderer) -> dict:
    """{label: renderer}: both walks on both paths, the device's default path first
    (sample packets on a CPU with the ordered walk, one sample at a time with the
    stackless re-trace walk on a GPU)."""
    path = lambda packets: "packets" if packets else "one sample"
    return {(t, path(p)): renderer.with_packets(p) for p in (renderer.packets, not renderer.packets)
            for t in TRAVERSALS}


def bench_one(d: Path, field: str, frames: int, size: int):
    """{(traversal, path): (times ms, samples, rgba, CPU ms)}, the device description, its
    kind ("CPU" or "GPU") and the regions' statistics (their meta["statistics"])."""
    b = schema.load(d / "bricks.npz", "bricks")
    r = schema.load(d / "regions.npz", "regions")
    v = schema.load(d / "bvh.npz", "bvh")
    renderer = Renderer(b, r, v, field=field)
    values = b.values[b.field_index(field)]
    tf = default_transfer_function((float(values.min()), float(values.max())))
    lo, hi = schema.world_bounds(b)
    cam = default_camera(np.asarray(lo), np.asarray(hi))
    runs = variants(renderer)
    times = {k: [] for k in runs}
    cpu = {k: [] for k in runs}
    last = {}
    # The variants alternate frame by frame, so a change in machine load hits all alike.
    for i in range(frames + 1):
        for (traversal, path), x in runs.items():
            c0 = time.process_time()
            result = x.render(camera=cam, transfer_function=tf, width=size, height=size,
                              traversal=traversal)
            if i:  # round 0 is the warm-up
                times[traversal, path].append(result.stats["ms"])
                cpu[traversal, path].append(1e3 * (time.process_time() - c0))
            last[traversal, path] = result
    out = {k: (np.array(times[k]), last[k].stats["samples"], last[k].rgba, np.array(cpu[k]))
           for k in runs}
    scene = renderer.dataset
    device = (f"{scene.device.name.strip()} ({scene.device.platform.version.strip()}, "
              f"{scene.device.max_compute_units} compute units)")
    kind = "CPU" if opencl.is_cpu(scene.device) else "GPU"
    return out, device, kind, r.meta["statistics"]


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

    rows, device, kind, region_stats, speedups = [], "?", "CPU", {}, []
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, list(sets)) if args.only else DEFAULT
    for key in keys:
        name, field = sets[key].name, sets[key].field
        d = ensure_scene(args.work, sets[key])
        results, device, kind, region_stats[name] = bench_one(d, field, args.runs, args.size)
        first = next(iter(results))
        diff = max(float(np.max(np.abs(results[k][2] - results[first][2]))) for k in results)
        med = {k: float(np.median(results[k][0])) for k in results}
        for (traversal, path), (times, samples, _, cpu) in results.items():
            row = (f"| {name} | {field} | {traversal} | {path} "
                   f"| {benchdoc.fmt_spread(times, '', 0)} | {samples:,} "
                   f"| {samples / med[traversal, path] / 1e3:.1f} | {np.median(cpu):.0f} |")
            rows.append(row)
            print(row, flush=True)
        speedup = med["ordered", "one sample"] / med["ordered", "packets"]
        speedups.append(f"{name} {speedup:.2f}x")
        print(f"  {name}: packets / one sample {speedup:.2f}x; largest difference between "
              f"the images of the variants {diff:.2e}", flush=True)

    command = "`.venv/bin/python -m benchmarks.bench_render" + (
        f" --only {','.join(keys)}" if args.only else "") + f" --runs {args.runs}" + (
        f" --size {args.size}" if args.size != 512 else "") + " --write-docs`"
    section = (f"Command: {command}\n\n"
               f"- machine: {benchdoc.machine()}, load average {benchdoc.load_average()} "
               f"at the end\n- OpenCL device: {device}\n"
               f"- frames: {args.size}x{args.size}, default camera and transfer function, "
               f"median of {args.runs} frames after one warm-up, the variants alternating "
               f"frame by frame (min-max in brackets)\n"
               f"- sample packets against one sample at a time (ordered walk, frame time): "
               f"{', '.join(speedups)}\n\n"
               "| dataset | field | traversal | path | ms/frame | samples/frame | M samples/s "
               "| CPU ms/frame |\n"
               "|---|---|---|---|---:|---:|---:|---:|\n"
               + "\n".join(rows) + "\n" + NOTES + "\n"
               + (GPU_NOTES if kind == "GPU" else time_notes(region_stats)) + "\n")
    benchdoc.publish(SECTIONS[kind], section, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
