"""Ingest throughput: cells per second for >= 20 M-cell ExaJet and AMReX inputs.

    .venv/bin/python -m benchmarks.bench_ingest [--runs 5] [--only exajet,amrex,...] [--write-docs]

(a) exajet: the 512^3 volume of benchmarks/make_big.py merged to AMR (23.6 M cells,
    6 levels) as bench-data/big512.cells + big512.value.scalars; timed in process
    (`readers.read` + `validate_cells`: read, level and alignment checks,
    non-finite check, O(N log N) overlap check) and end to end (`exabricks ingest`
    in a subprocess: also interpreter start, sha256 of the inputs for the
    provenance record, and writing the .npz; with the command's peak RSS).
(b) amrex: the same volume as the block-structured plotfile bench-data/plt_big512
    of `make_big.py --amrex` (3 levels, ratio 2, 32^3 boxes, float64 data;
    23.3 M leaves out of 26.3 M stored cells), the same two ways; amrex-small:
    the shared plt00020 (505,856 cells).
(c) raw: the raw 512^3 volume itself through the numba 2x2x2 merge (134 M voxels
    in, 23.6 M cells out; cells/s counts output cells).

The generated inputs are made under bench-data/ on first use (benchmarks/benchdoc.py).
Each figure is the median of --runs runs after one warm-up run (which also fills
the numba cache and the page cache), with min and max as the spread.
--write-docs replaces the "## ingest" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.benchdoc import BENCH, ensure_amrex, ensure_exajet, ensure_raw, fmt_bytes

from exabricks import readers
from exabricks.builders.cells import validate_cells

ROOT = Path(__file__).resolve().parents[1]


SECTION = "ingest"
CASES = ("exajet", "amrex", "amrex-small", "raw")
TARGET_CELLS_PER_S = 5e6  # the ingest target (wall time)
NOTES = """
End to end includes interpreter start-up and imports, sha256 of every input
(provenance in `meta`), and the fsync'ed `.npz` write.  CPU time is the median
user + system time (the command's, for end to end); on a shared machine it is
less disturbed by the other jobs than wall time, but it leaves out waits (the
fsync) and still grows somewhat under contention.  Peak RSS is the command's
ru_maxrss (median over the runs).
"""


def levels_note(name: str, cells) -> str:
    """One line: the leaf cells of an input per level (0 = finest), from the cells read."""
    counts = np.bincount(cells.level.astype(np.int64))
    return (f"- {name}: {cells.n_cells:,} leaf cells on {np.count_nonzero(counts)} levels ("
            + ", ".join(f"level {lev}: {n:,}" for lev, n in enumerate(counts) if n) + ")")


def target_note(rates: dict) -> str:
    """The target against the end-to-end wall-time rates {input name: cells/s (median)}."""
    if not rates:
        return f"Target: >= {TARGET_CELLS_PER_S / 1e6:g} M cells/s (not measured)."
    met = [k for k, v in rates.items() if v >= TARGET_CELLS_PER_S]
    missed = [k for k, v in rates.items() if v < TARGET_CELLS_PER_S]
    return (f"Target: >= {TARGET_CELLS_PER_S / 1e6:g} M cells/s end to end: "
            + "; ".join(part for part in (
                f"met on {', '.join(met)}" if met else "",
                f"missed on {', '.join(missed)}" if missed else "") if part) + ".")


def in_process(path: Path, options: dict):
    def run():
        cells = readers.read(path, **options)
        validate_cells(cells, source=str(path))
        return cells
    return run


def ingest_flags(options: dict) -> list[str]:
    """`exabricks ingest` flags of reader options: {"max_level": 5} -> ["--max-level", "5"]."""
    flags = []
    for key, value in options.items():
        flags += [f"--{key.replace('_', '-')}",
                  *map(str, value if isinstance(value, tuple) else [value])]
    return flags


def end_to_end(path: Path, out: Path, options: dict, runs: int):
    """(wall s, CPU s, peak RSS bytes) lists of `runs` `exabricks ingest` runs after a warm-up."""
    cmd = [*benchdoc.exabricks_command(), "-q", "ingest", str(path), "-o", str(out),
           *ingest_flags(options)]
    benchdoc.run_child(cmd)
    walls, cpus, peaks = zip(*(benchdoc.run_child(cmd) for _ in range(runs)))
    return list(walls), list(cpus), list(peaks)


def row(name: str, n: int, how: str, walls, cpus, peak: str) -> str:
    med, lo, hi = benchdoc.median_spread(walls)
    cpu = statistics.median(cpus)
    return (f"| {name} | {n:,} | {how} | {benchdoc.fmt_seconds(walls)} s "
            f"| {n / med / 1e6:.1f} M ({n / hi / 1e6:.1f}-{n / lo / 1e6:.1f}) "
            f"| {cpu:.3g} s | {n / cpu / 1e6:.1f} M | {peak} |")


def section(rows: list[str], runs: int, command: str, levels: list[str] = (),
            rates: dict | None = None) -> str:
    """The body of the "## ingest" section of docs/benchmarks.md around the table rows,
    the inputs' `levels_note` lines and the end-to-end `rates` (`target_note`)."""
    return "\n".join([
        f"Command: `{command}` (it makes the inputs with `benchmarks/make_big.py` on first "
        f"use). {target_note(rates or {})}",
        "",
        f"- machine: {benchdoc.machine()}, load average {benchdoc.load_average()} at the end",
        f"- median of {runs} runs after a warm-up, (min-max) in brackets",
        "",
        "| input | cells | what is timed | wall time | cells/s (wall) | CPU time | cells/s (CPU) "
        "| peak RSS |",
        "|---|---:|---|---:|---:|---:|---:|---:|",
        *rows,
        NOTES,
        *(["Inputs:", "", *levels, ""] if levels else []),
    ])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(p)
    p.add_argument("--case", action="append", help=argparse.SUPPRESS)  # old name of --only
    p.add_argument("--no-docs", action="store_true", help=argparse.SUPPRESS)  # now the default
    args = p.parse_args(argv)
    chosen = benchdoc.chosen((args.only or []) + (args.case or []), CASES)
    BENCH.mkdir(exist_ok=True)
    cases = []
    if "exajet" in chosen:
        cases.append(("ExaJet big512 (make_big.py)", ensure_exajet(), {}))
    if "amrex" in chosen:
        cases.append(("AMReX plt_big512 (make_big.py --amrex)", ensure_amrex(), {}))
    if "amrex-small" in chosen:
        cases.append(("AMReX plt00020", benchdoc.datasets()["amrex"].path, {}))
    if "raw" in chosen:
        make_big = benchdoc._make_big()
        cases.append(("raw 512^3 -> AMR merge", ensure_raw(), dict(
            format="raw", dims=(512, 512, 512), max_level=make_big.MAX_LEVEL,
            threshold=make_big.THRESHOLD)))
    rows, levels, rates = [], [], {}
    out = BENCH / "bench-cells.npz"
    for name, path, options in cases:
        cells = readers.read(path, **options)
        n = cells.n_cells
        levels.append(levels_note(name, cells))
        del cells
        walls, cpus = benchdoc.timed(in_process(path, options), args.runs)
        rows.append(row(name, n, "read + validate (in process)", walls, cpus, "-"))
        print(rows[-1], flush=True)
        walls, cpus, peaks = end_to_end(path, out, options, args.runs)
        rows.append(row(name, n, "`exabricks ingest` end to end", walls, cpus,
                        fmt_bytes(statistics.median(peaks))))
        rates[name] = n / statistics.median(walls)
        print(rows[-1], flush=True)
    out.unlink(missing_ok=True)
    command = (".venv/bin/python -m benchmarks.bench_ingest"
               + (f" --only {','.join(chosen)}" if args.only or args.case else "")
               + f" --runs {args.runs} --write-docs")
    body = section(rows, args.runs, command, levels, rates)
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
