"""Ingest throughput: cells per second for a >= 20 M-cell ExaJet input and the AMReX plotfile.

    .venv/bin/python workflows/bench_ingest.py [--runs 5] [--no-docs]

(a) ExaJet: the 512^3 volume of workflows/make_big.py merged to AMR (23.6 M cells,
    6 levels) is written as bench-data/big512.cells + big512.value.scalars; then
    timed twice: in process (`readers.read` + `validate_cells`: read, level and
    alignment checks, non-finite check, O(N log N) overlap check) and end to end
    (`exabricks ingest` in a subprocess: also interpreter start, sha256 of the
    inputs for the provenance record, and writing the .npz).
(b) AMReX tests/data/amrex-advection3d/plt00020 (505,856 cells), the same two ways.
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


def timed(fn, runs: int) -> tuple[float, float, float]:
    """(median, min, max) seconds of `runs` calls after one warm-up call."""
    fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times), max(times)


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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--no-docs", action="store_true", help="print only; leave docs/benchmarks.md")
    args = p.parse_args(argv)
    BENCH.mkdir(exist_ok=True)
    cases = [("ExaJet big512 (make_big.py)", ensure_exajet(), {})]
    if (ROOT / "exabricks" / "readers" / "amrex.py").is_file() and AMREX.is_dir():
        cases.append(("AMReX plt00020", AMREX, {}))
    cases.append(("raw 512^3 -> AMR merge", BIG_RAW, dict(
        format="raw", dims=(512, 512, 512), max_level=make_big.MAX_LEVEL,
        threshold=make_big.THRESHOLD)))
    rows = []
    for name, path, options in cases:
        n = readers.read(path, **options).n_cells
        for how, fn in (("read + validate (in process)", in_process(path, options)),
                        ("`exabricks ingest` end to end",
                         end_to_end(path, BENCH / "bench-cells.npz", options))):
            med, lo, hi = timed(fn, args.runs)
            row = (f"| {name} | {n:,} | {how} | {med:.2f} s ({lo:.2f}-{hi:.2f}) "
                   f"| {n / med / 1e6:.1f} M ({n / hi / 1e6:.1f}-{n / lo / 1e6:.1f}) |")
            print(row, flush=True)
            rows.append(row)
    (BENCH / "bench-cells.npz").unlink(missing_ok=True)
    lines = [
        f"Provisional ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores shared with other jobs, "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}); "
        f"median of {args.runs} runs after a warm-up, (min-max) in brackets. Reproduce with "
        "`.venv/bin/python workflows/bench_ingest.py` (it makes the input with "
        "`workflows/make_big.py` on first use). Target: >= 5 M cells/s.",
        "",
        "| input | cells | what is timed | time | cells/s |",
        "|---|---:|---|---:|---:|",
        *rows,
        "",
        "End to end includes interpreter start-up and imports, sha256 of every input "
        "(provenance in `meta`), and the fsync'ed `.npz` write.",
    ]
    if not args.no_docs:
        write_docs(lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
