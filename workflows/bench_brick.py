"""Benchmark `build_bricks` (paper §3.1) on a large AMR input: throughput and peak memory.

    .venv/bin/python workflows/bench_brick.py [--cells bench-data/brick-cells.npz] [--repeat 3]
                                              [--max-brick-width 32] [--write-docs]

The input is the 512^3 multi-scale volume of workflows/make_big.py made AMR by
the raw ingest path (23.6 M cells over 6 levels); when --cells is missing it is
made (the volume too, if bench-data/big512.raw is missing) with the ingest
command that make_big.py prints.  After a numba warm-up on a small slice, build_bricks runs
--repeat times; the script reports the median time with its spread, cells per
second, and the peak resident memory the build adds on top of the loaded cells
(sampled every 5 ms from /proc/self/statm).  --write-docs replaces the
"## brick" section of docs/benchmarks.md with the figures.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from exabricks import schema  # noqa: E402
from exabricks.stages.brick import build_bricks  # noqa: E402

DEFAULT_CELLS = ROOT / "bench-data" / "brick-cells.npz"
DOCS = ROOT / "docs" / "benchmarks.md"
INTRO = "# Benchmarks\n\nFigures per stage, with the command that produced them.\n"


def ensure_cells(path: Path) -> Path:
    """`path`; when missing, the make_big.py volume through `exabricks ingest --format raw`."""
    if path.is_file():
        return path
    sys.path.insert(0, str(ROOT / "workflows"))
    import make_big

    raw = path.parent / "big512.raw"
    if not raw.is_file():
        make_big.generate(raw, 512, seed=7)
    print(f"{path} missing: ingesting {raw}", file=sys.stderr, flush=True)
    subprocess.run(
        [sys.executable, "-m", "exabricks.cli.main", "ingest", "--format", "raw",
         "--dims", "512", "512", "512", "--dtype", "float32",
         "--max-level", str(make_big.MAX_LEVEL), "--threshold", str(make_big.THRESHOLD),
         str(raw), "-o", str(path)],
        check=True, cwd=ROOT)
    return path


class PeakRss:
    """Highest resident set size seen while active, sampled from /proc/self/statm."""

    def __init__(self, interval: float = 0.005):
        self.interval = interval
        self.page = os.sysconf("SC_PAGE_SIZE")
        self.peak = 0
        self._stop = threading.Event()

    def rss(self) -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * self.page

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self.rss())
            time.sleep(self.interval)

    def __enter__(self):
        self.peak = self.rss()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self.rss())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cells", type=Path, default=DEFAULT_CELLS)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--max-brick-width", type=int, default=32)
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)

    import numba

    cells = schema.load(ensure_cells(args.cells), "cells")
    n = cells.n_cells
    small = cells.replace(lower_lattice=cells.lower_lattice[:1000], level=cells.level[:1000],
                          values=cells.values[:, :1000])
    build_bricks(small, max_brick_width=args.max_brick_width)  # numba compile / cache load

    times, added = [], []
    bricks = None
    for _ in range(args.repeat):
        del bricks
        bricks = None
        probe = PeakRss()
        base = probe.rss()
        with probe:
            t = time.perf_counter()
            bricks = build_bricks(cells, max_brick_width=args.max_brick_width)
            times.append(time.perf_counter() - t)
        added.append(probe.peak - base)
        print(f"run {len(times)}: {times[-1]:.2f} s", file=sys.stderr, flush=True)
    stats = bricks.meta["statistics"]
    assert stats["cells"] == n
    input_bytes = sum(a.nbytes for a in cells.arrays().values())
    output_bytes = sum(a.nbytes for a in bricks.arrays().values())
    median = float(np.median(times))
    figures = {
        "input": f"{args.cells.relative_to(ROOT) if args.cells.is_relative_to(ROOT) else args.cells}"
                 f": {n:,} cells, {cells.n_fields} field(s), levels "
                 + ", ".join(f"{l}: {c:,}" for l, c in
                             enumerate(np.bincount(cells.level.astype(np.int64))) if c),
        "time": f"median {median:.2f} s over {len(times)} runs "
                f"(min {min(times):.2f}, max {max(times):.2f}) after a warm-up",
        "throughput": f"{n / median / 1e6:.1f} M cells/s (target >= 2 M cells/s)",
        "memory": f"peak RSS added by the build {max(added) / 2**20:,.0f} MiB "
                  f"(input arrays {input_bytes / 2**20:,.0f} MiB, output arrays "
                  f"{output_bytes / 2**20:,.0f} MiB)",
        "bricks": f"{stats['bricks']:,}; per level "
                  + ", ".join(f"{l}: {c:,}" for l, c in stats["bricks_per_level"].items())
                  + f"; mean {stats['mean_cells_per_brick']:.1f} cells per brick",
        "machine": f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
                   f"{platform.machine()}, {os.cpu_count()} cores, numba {numba.__version__} "
                   f"with {numba.get_num_threads()} threads, load average "
                   f"{os.getloadavg()[0]:.1f} at the end (shared machine: provisional)",
    }
    figures["end to end"] = end_to_end(args.cells, args.max_brick_width)
    figures["timed"] = ("build_bricks in process: packing, k-d partition, brick placement and "
                        "value gather (not the .npz load and save)")
    command = ("`.venv/bin/python workflows/bench_brick.py"
               + (f" --cells {args.cells}" if args.cells != DEFAULT_CELLS else "")
               + (f" --max-brick-width {args.max_brick_width}" if args.max_brick_width != 32 else "")
               + f" --repeat {args.repeat}`")
    section = "## brick\n\n" + f"Command: {command}\n\n" + "".join(
        f"- {k}: {v}\n" for k, v in figures.items()) + real_datasets(args.max_brick_width)
    print(section)
    if args.write_docs:
        write_section(section)
    return 0


def end_to_end(cells_path: Path, max_brick_width: int) -> str:
    """Wall time and peak memory of one `exabricks brick` run (load, build, sha256, save)."""
    import resource

    out = cells_path.with_name("bench-brick-out.npz")
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "exabricks.cli.main", "brick", str(cells_path),
                    "-o", str(out), "--max-brick-width", str(max_brick_width)], check=True, cwd=ROOT)
    wall = time.perf_counter() - t
    out.unlink()
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # KiB on Linux
    return (f"`exabricks brick` {wall:.2f} s wall (one run: start-up, load and validate, build, "
            f"sha256 of the input, save), peak RSS {peak:,.0f} MiB")


def real_datasets(max_brick_width: int) -> str:
    """A markdown table of the bricks of the four real datasets, read by exabricks' readers."""
    from exabricks.readers import read

    data = ROOT / "tests" / "data"
    sets = [("Gerris plume (ExaJet)", ROOT / "exabricks/data/gerris-plume/plume7-1.cells"),
            ("AMReX advection", data / "amrex-advection3d/plt00020"),
            ("Athena++ blast", data / "athena-blast3d/Blast.out2.00001.athdf"),
            ("Enzo moving7 (yt)", data / "enzo-moving7/moving7_0010")]
    rows = ["", "Real datasets (time: median of 3 after a warm-up):", "",
            "| dataset | cells | bricks | bricks per level | mean cells/brick | time |",
            "|---|---:|---:|---|---:|---:|"]
    for name, path in sets:
        cells = read(path)
        s = build_bricks(cells, max_brick_width=max_brick_width).meta["statistics"]  # warm-up
        times = []
        for _ in range(3):
            t = time.perf_counter()
            build_bricks(cells, max_brick_width=max_brick_width)
            times.append(time.perf_counter() - t)
        dt = float(np.median(times))
        per_level = ", ".join(f"{l}: {c:,}" for l, c in s["bricks_per_level"].items())
        rows.append(f"| {name} | {cells.n_cells:,} | {s['bricks']:,} | {per_level} | "
                    f"{s['mean_cells_per_brick']:.1f} | {dt:.3f} s |")
    return "\n".join(rows) + "\n"


def write_section(section: str) -> None:
    """Replace (or append) the "## brick" section of docs/benchmarks.md, leaving the rest."""
    text = DOCS.read_text() if DOCS.exists() else INTRO
    pattern = re.compile(r"^## brick\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(text):
        text = pattern.sub(lambda _: section + "\n", text, count=1)
    else:
        text = text.rstrip("\n") + "\n\n" + section
    DOCS.write_text(text)


if __name__ == "__main__":
    sys.exit(main())
