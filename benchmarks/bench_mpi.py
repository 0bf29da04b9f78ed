"""MPI rendering and SLURM job arrays: time and per-rank peak memory (issue 12).

    .venv/bin/python -m benchmarks.bench_mpi [--only shell,big] [--ranks 1,2,4] [--write-docs]

For each dataset (default: the two largest, make_big.py's 20.6 M-cell thin shells
and its 23.6 M-cell 512^3 AMR volume, made on first use) one 1024^2 frame with
early termination off (--max-opacity 1, so that the images must agree) is rendered
by `exabricks render` (1 rank) and by `mpiexec -n N exabricks render` in both MPI
modes, as whole commands. Each rank runs under a small launcher that records its
own peak resident memory (ru_maxrss from wait4). The table gives the command's
wall time, the frame's time from the image metadata (render and compositing),
the largest and the mean rank peak, and the RMSE of the image against one rank.
On a 2-core machine N = 4 is oversubscribed: four ranks share two cores (and each
PoCL runtime starts a thread per core).

Then the 120-frame orbit of the Gerris plume at 512^2: one process rendering
`--frames 0:120` (one upload) against workflows/slurm/render_frames.sbatch as a
SLURM job array (one frame per task, and 30 per task), from submission to the
last frame, on the one-node cluster of workflows/slurm/up.sh (skipped when no
cluster answers `sinfo`).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.bench_render import ensure_scene

ROOT = benchdoc.ROOT
SECTION = "MPI rendering and SLURM job arrays"
READING = """
Reading the figures. On this machine every rank's PoCL already uses both cores,
so more ranks only share them: the MPI frame is not faster here (data mode pays
the partition, each domain's BVH and the compositing on top; image mode is a
wash), and neither is a job array, whose tasks each pay the start-up of Python,
the OpenCL runtime and the upload (about 1 s): with one frame per task the array
is about 4 times slower than one process, with 30 frames per task 0.6-1.0
times as fast from run to run (four tasks share two cores). What MPI buys on one machine is memory.
One process uses the files' pages in place (the device shares the values and
brick lists with the page cache); a data-mode rank copies its domain (the bricks
cropped to it, its regions and lists, a BVH of its own), so above the baseline
it holds about 1.35-1.5/N of what one process holds on the thin shells (× N /
one), and about 2/N on the 512³ volume, whose big bricks cross the cuts and are
cropped with a margin. At 204 M cells the largest rank's peak falls from 4.24
GiB for one process to 3.08 and 1.66 GiB with 2 and 4 ranks.
The baseline itself (Python, numba, PoCL, mpi4py: about 270-350 MiB a rank) is
paid by every rank. The speed-ups MPI is for come from ranks on separate nodes,
which this machine cannot show.
"""
BIN = Path(sys.executable).parent

# Like benchdoc's launcher, one per rank: the file name gets the rank appended.
_RANK_LAUNCHER = """
import os, sys
pid = os.posix_spawnp(sys.argv[2], sys.argv[2:], os.environ)
_, status, ru = os.wait4(pid, 0)
rank = os.environ.get("PMI_RANK", "0")
with open(f"{sys.argv[1]}.{rank}", "w") as f:
    f.write(str(ru.ru_maxrss))
sys.exit(os.waitstatus_to_exitcode(status) & 255)
"""


def run_ranks(n: int, args: list, tmp: Path) -> tuple[float, list[int]]:
    """`exabricks ARGS` with n ranks (no launcher for 1): wall seconds, peak RSS bytes
    of each rank."""
    stem = tmp / "rss"
    for old in tmp.glob("rss.*"):
        old.unlink()
    rank = [sys.executable, "-S", "-c", _RANK_LAUNCHER, str(stem), str(BIN / "exabricks"), *map(str, args)]
    cmd = rank if n == 1 else [str(BIN / "mpiexec"), "-n", str(n), *rank]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "EXABRICKS_QUIET": "1"})
    wall = time.perf_counter() - start
    if proc.returncode:
        sys.exit(f"{' '.join(cmd)} failed: {proc.stderr.strip()}")
    return wall, [int(p.read_text()) * 1024 for p in sorted(tmp.glob("rss.*"))]


def baselines(ranks: list[int], size: int, tmp: Path) -> dict[int, int]:
    """Each rank count's largest rank peak in data mode on a 64-cell dataset."""
    from benchmarks.bench_budget import tiny_scene

    files = tiny_scene(tmp, "rho")
    out = {}
    for n in ranks:
        extra = ["--mpi-mode", "data"] if n > 1 else []
        out[n] = max(run_ranks(n, ["render", *files, "--size", size, size, "--max-opacity", 1,
                                   "-o", tmp / "tiny.exr", *extra], tmp)[1])
    return out


def bench_dataset(d: Path, field: str, ranks: list[int], size: int, tmp: Path,
                  base: dict[int, int], modes=("data", "image"), name=None) -> list[str]:
    from exabricks.film.image_io import read_image

    files = [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    structures = sum(f.stat().st_size for f in files)
    common = ["render", *files, "--field", field, "--size", size, size, "--max-opacity", 1]
    rows, reference, one = [], None, None
    for n in ranks:
        for mode in (modes if n > 1 else ("-",)):
            out = tmp / f"img_{n}_{mode}.exr"
            extra = ["--mpi-mode", mode] if n > 1 else []
            wall, rss = run_ranks(n, [*common, "-o", out, *extra], tmp)
            image, meta = read_image(out)
            if reference is None:
                reference = image
            rmse = float(np.sqrt(np.mean((image - reference) ** 2))) / float(np.abs(reference).max())
            above = max(rss) - base[n]
            one = above if one is None else one
            row = (f"| {name or d.name} | {n} | {mode} | {wall:.2f} | "
                   f"{meta['settings']['ms'] / 1e3:.2f} | {benchdoc.fmt_bytes(max(rss))} | "
                   f"{benchdoc.fmt_bytes(np.mean(rss))} | {max(rss) / structures:.2f} | "
                   f"{benchdoc.fmt_bytes(above)} | {above / one * n:.2f} | {rmse:.1e} |")
            print(row, flush=True)
            rows.append(row)
    return rows


def bench_orbit(d: Path, field: str, frames: int, size: int, tmp: Path) -> list[str]:
    if shutil.which("sinfo") is None or subprocess.run(["sinfo"], capture_output=True).returncode:
        print("no SLURM cluster (workflows/slurm/up.sh): orbit skipped", flush=True)
        return []
    files = [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    path = tmp / "orbit.json"
    subprocess.run([BIN / "exabricks", "camera", "orbit", files[0], "--frames", str(frames),
                    "-o", path], check=True)
    opts = ["--field", field, "--size", str(size), str(size)]
    rows = []
    (tmp / "one").mkdir()
    start = time.perf_counter()
    subprocess.run([BIN / "exabricks", "-q", "render", *files, "--camera-path", path, "--frames",
                    f"0:{frames}", "-o", tmp / "one" / "frame_%05d.png", *opts], check=True)
    one = time.perf_counter() - start
    rows.append(f"| one process, `--frames 0:{frames}` | 1 | {one:.1f} | 1.00 |")
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}"}
    for per in (1, 30):
        tasks = -(-frames // per)
        start = time.perf_counter()
        subprocess.run(["sbatch", "--wait", "--parsable", f"--export=ALL,FRAMES_PER_TASK={per}",
                        f"--array=0-{tasks - 1}", "-o", str(tmp / "task-%a.log"),
                        ROOT / "workflows" / "slurm" / "render_frames.sbatch", path,
                        tmp / f"array{per}", *files, *opts], check=True, env=env,
                       capture_output=True, cwd=tmp)
        wall = time.perf_counter() - start
        done = len(list((tmp / f"array{per}").glob("*.png")))
        assert done == frames, (per, done)
        rows.append(f"| job array, {per} frame(s) per task | {tasks} | {wall:.1f} | {one / wall:.2f} |")
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="datasets (benchdoc keys; default shell,big)")
    parser.add_argument("--ranks", default="1,2,4")
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--frames", type=int, default=120, help="frames of the orbit")
    parser.add_argument("--work", type=Path, default=ROOT / "bench-data" / "render")
    parser.add_argument("--large", type=Path, default=None, metavar="DIR",
                        help="also the structures in DIR (bricks, regions, bvh .npz; e.g. "
                        "bench-data/large/shell2944 of bench_large.py), in data mode only")
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen([args.only], list(sets)) if args.only else ["shell", "big"]
    ranks = [int(n) for n in args.ranks.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base = baselines(ranks, args.size, Path(tmp))
        for key in keys:
            d = ensure_scene(args.work, sets[key])
            rows += bench_dataset(d, sets[key].field, ranks, args.size, Path(tmp), base)
        if args.large:
            # image mode would hold the whole dataset in every rank
            rows += bench_dataset(args.large, "rho", ranks, args.size, Path(tmp), base,
                                  modes=("data",), name=f"{args.large.name} (204 M cells)"
                                  if args.large.name == "shell2944" else None)
        orbit = bench_orbit(ensure_scene(args.work, sets["gerris"]), "T", args.frames, 512, Path(tmp))
    command = (f"`.venv/bin/python -m benchmarks.bench_mpi --only {','.join(keys)} --ranks "
               f"{args.ranks}{f' --large {args.large}' if args.large else ''} --write-docs`")
    section = (
        f"Command: {command}\n\n- machine: {benchdoc.machine()}; ranks beyond 2 are "
        f"oversubscribed (they share the 2 cores)\n"
        f"- one {args.size}² frame, default camera and transfer function, `--max-opacity 1`; "
        "whole `exabricks render` commands (load, partition, upload, render, composite, write); "
        "frame: the render and compositing time the image records; peak: each rank's own peak "
        "resident memory; / files: the largest rank peak over the bytes of the three structure "
        "files; above baseline: the largest rank peak less that of the same rank count "
        "rendering a 64-cell dataset in data mode (" + ", ".join(
            f"{n}: {benchdoc.fmt_bytes(b)}" for n, b in base.items()) + "); × N / one: "
        "that over the one-process figure, times the rank count (1.00: exactly 1/N of one "
        "process); RMSE: against the one-rank image, over its maximum\n\n"
        "| dataset | ranks | mode | command s | frame s | largest rank peak | mean rank peak "
        "| peak / files | above baseline | × N / one | RMSE |\n"
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|\n"
        + "\n".join(rows) + "\n")
    if orbit:
        section += (f"\n{args.frames}-frame orbit of the Gerris plume at 512² "
                    "(workflows/slurm/render_frames.sbatch on the one-node cluster of "
                    "workflows/slurm/up.sh, which claims 4 CPUs on 2 cores; from submission to "
                    "the last frame):\n\n| how | tasks | wall s | speed-up |\n|---|---:|---:|---:|\n"
                    + "\n".join(orbit) + "\n")
    benchdoc.publish(SECTION, section + READING, args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
