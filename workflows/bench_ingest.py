"""Ingest throughput: cells per second for >= 20 M-cell ExaJet and AMReX inputs.

    .venv/bin/python workflows/bench_ingest.py [--runs 5] [--case exajet ...] [--no-docs]

(a) ExaJet: the 512^3 volume of workflows/make_big.py merged to AMR (23.6 M cells,
    6 levels) is written as bench-data/big512.cells + big512.value.scalars; then
    timed twice: in process (`readers.read` + `validate_cells`: read, level and
    alignment checks, non-finite check, O(N log N) overlap check) and end to end
    (`exabricks ingest` in a subprocess: also interpreter start, sha256 of the
    inputs for the provenance record, and writing the .npz).
(b) AMReX: the same volume as the block-structured plotfile bench-data/plt_big512
    of `make_big.py --amrex` (3 levels, ratio 2, 32^3 boxes, float64 data;
    23.3 M leaves out of 26.3 M stored cells), the same two ways; and, small,
    tests/data/amrex-advection3d/plt00020 (505,856 cells).
(c) For reference, the raw 512^3 volume itself through the numba 2x2x2 merge
    (134 M voxels in, 23.6 M cells out; cells/s counts output cells).

Each figure is the median of `--runs` runs after one warm-up run (which also
fills the numba cache and the page cache), with min and max as the spread.  The
results go to docs/benchmarks.md under "## ingest" (replacing that section).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "workflows"))

import make_big  # noqa: E402

from exabricks import readers  # noqa: E402
from exabricks.stages.ingest import amr_from_uniform, validate_cells  # noqa: E402

BENCH = ROOT / "bench-data"
BIG_RAW = BENCH / "big512.raw"
BIG_CELLS = BENCH / "big512.cells"
BIG_AMREX = BENCH / "plt_big512"
AMREX = ROOT / "tests" / "data" / "amrex-advection3d" / "plt00020"
EXABRICKS = [sys.executable, "-m", "exabricks.cli.main"]


def ensure_exajet() -> Path:
    """The big AMR in ExaJet form (made from the make_big volume when missing)."""
    scalars = BIG_CELLS.with_name("big512.value.scalars")
    if BIG_CELLS.is_file() and scalars.is_file():
        return BIG_CELLS
    if not BIG_RAW.is_file():
        make_big.generate(BIG_RAW, 512, 7)
    volume = np.fromfile(BIG_RAW, dtype="<f4").reshape(512, 512, 512)
    lower, level, values = amr_from_uniform(
        volume, max_level=make_big.MAX_LEVEL, threshold=make_big.THRESHOLD)
    raw = np.empty((level.size, 4), "<i4")
    raw[:, :3] = lower
    raw[:, 3] = level
    raw.tofile(BIG_CELLS)
    values.astype("<f4").tofile(scalars)
    return BIG_CELLS


def ensure_amrex() -> Path:
    """The big AMReX plotfile (written from the make_big volume when missing)."""
    if not (BIG_AMREX / "Header").is_file():
        if not BIG_RAW.is_file():
            make_big.generate(BIG_RAW, 512, 7)
        make_big.write_amrex(np.fromfile(BIG_RAW, dtype="<f4").reshape(512, 512, 512), BIG_AMREX)
    return BIG_AMREX


def _cpu() -> float:
    """CPU seconds (user + system) of this process and its waited-for children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def timed(fn, runs: int) -> tuple[float, float, float, float]:
    """(median, min, max) wall seconds and median CPU seconds of `runs` calls after a warm-up.

    CPU time (user + system, children included) is less disturbed than wall time by
    other jobs on a shared machine; wall >= CPU unless a call uses several cores.
    """
    fn()
    times, cpus = [], []
    for _ in range(runs):
        c, t = _cpu(), time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
        cpus.append(_cpu() - c)
    return statistics.median(times), min(times), max(times), statistics.median(cpus)


def in_process(path: Path, options: dict):
    def run():
        cells = readers.read(path, **options)
        validate_cells(cells, source=str(path))
        return cells
    return run


def end_to_end(path: Path, out: Path, options: dict):
    flags = []
    for key, value in options.items():
        flags += [f"--{key.replace('_', '-')}", *map(str, value if isinstance(value, tuple) else [value])]

    def run():
        subprocess.run([*EXABRICKS, "ingest", str(path), "-o", str(out), *flags], check=True,
                       env={**os.environ, "EXABRICKS_QUIET": "1"})
    return run


def write_docs(lines: list[str]) -> None:
    doc = ROOT / "docs" / "benchmarks.md"
    text = doc.read_text() if doc.exists() else (
        "# Benchmarks\n\nMeasured figures of each stage, with the commands that reproduce them.\n")
    section = "## ingest\n\n" + "\n".join(lines) + "\n"
    start = text.find("\n## ingest\n")
    if start < 0:
        text = text.rstrip("\n") + "\n\n" + section
    else:
        end = text.find("\n## ", start + 1)
        text = text[: start + 1] + section + (text[end:] if end >= 0 else "")
    doc.write_text(text)


CASES = ("exajet", "amrex", "amrex-small", "raw")


def section(rows: list[str], runs: int) -> list[str]:
    """The "## ingest" section of docs/benchmarks.md around the table rows."""
    return [
        f"Provisional ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores shared with other jobs, "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}); "
        f"median of {runs} runs after a warm-up, (min-max) in brackets. Reproduce with "
        "`.venv/bin/python workflows/bench_ingest.py` (it makes the inputs with "
        "`workflows/make_big.py` on first use). Target: >= 5 M cells/s.",
        "",
        "| input | cells | what is timed | wall time | cells/s (wall) | CPU time | cells/s (CPU) |",
        "|---|---:|---|---:|---:|---:|---:|",
        *rows,
        "",
        "End to end includes interpreter start-up and imports, sha256 of every input "
        "(provenance in `meta`), and the fsync'ed `.npz` write.  CPU time is the median "
        "user + system time (the command's, for end to end); on a shared machine it is "
        "less disturbed by the other jobs than wall time, but it leaves out waits "
        "(the fsync) and still grows somewhat under contention.",
    ]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--case", choices=CASES, action="append",
                   help="time only this input (repeatable; default: all)")
    p.add_argument("--no-docs", action="store_true", help="print only; leave docs/benchmarks.md")
    args = p.parse_args(argv)
    chosen = args.case or CASES
    BENCH.mkdir(exist_ok=True)
    cases = []
    if "exajet" in chosen:
        cases.append(("ExaJet big512 (make_big.py)", ensure_exajet(), {}))
    if "amrex" in chosen:
        cases.append(("AMReX plt_big512 (make_big.py --amrex)", ensure_amrex(), {}))
    if "amrex-small" in chosen and AMREX.is_dir():
        cases.append(("AMReX plt00020", AMREX, {}))
    if "raw" in chosen:
        if not BIG_RAW.is_file():
            make_big.generate(BIG_RAW, 512, 7)
        cases.append(("raw 512^3 -> AMR merge", BIG_RAW, dict(
            format="raw", dims=(512, 512, 512), max_level=make_big.MAX_LEVEL,
            threshold=make_big.THRESHOLD)))
    rows = []
    for name, path, options in cases:
        n = readers.read(path, **options).n_cells
        for how, fn in (("read + validate (in process)", in_process(path, options)),
                        ("`exabricks ingest` end to end",
                         end_to_end(path, BENCH / "bench-cells.npz", options))):
            med, lo, hi, cpu = timed(fn, args.runs)
            row = (f"| {name} | {n:,} | {how} | {med:.2f} s ({lo:.2f}-{hi:.2f}) "
                   f"| {n / med / 1e6:.1f} M ({n / hi / 1e6:.1f}-{n / lo / 1e6:.1f}) "
                   f"| {cpu:.2f} s | {n / cpu / 1e6:.1f} M |")
            print(row, flush=True)
            rows.append(row)
    (BENCH / "bench-cells.npz").unlink(missing_ok=True)
    if not args.no_docs:
        write_docs(section(rows, args.runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
