"""Builders by pieces: each stage in one process against N pieces and a join.

    .venv/bin/python -m benchmarks.bench_pieces [--pieces 4] [--only shell,big] [--write-docs]

For each dataset (the cells file of benchmarks/bench_preprocess.py's work
directory, bench-data/preprocess/KEY/cells.npz, or --cells), `brick`, `regions`
and `bvh` run as one command and then as --pieces commands with --piece K/N,
one after another, and `exabricks join` (each its own child process: wall
time and peak resident memory from wait4), after a warm-up on a small input
that fills numba's caches. On N machines the stage would take
its slowest piece plus the join; that sum against the one-process command is
the speed-up column. The joined file is checked to equal the one-process file
array for array. --write-docs replaces the section "Builders by pieces" of
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import benchdoc

from exabricks import schema  # noqa: E402

SECTION = "Builders by pieces"
READING = """Reading the figures. The cells come from `exabricks ingest`, in piece
order: a `brick` piece maps and checks only its own runs of cells and builds
their subtrees, so its time and memory are about 1/N of the work (what stays
whole is hashing the input for the provenance, on a background thread). A
`regions` piece checks that no two bricks share a cell among its own tasks'
bricks and reads the values of its own regions only, but computes every
support and the 64 top tasks; a `bvh` piece loads and checks every region and
makes the top SAH splits over all of them. A join holds about its output,
except `brick`'s, which also joins the small bricks of the shares
(`merge_bricks`, about 3 times its output at its peak): on N machines the
`brick` stage is bounded by its join.
"""
STAGES = (("brick", "cells", "bricks"), ("regions", "bricks", "regions"), ("bvh", "regions", "bvh"))


def identical(a: Path, b: Path, kind: str) -> bool:
    x, y = schema.load(a, kind, mapped=True), schema.load(b, kind, mapped=True)
    ya = y.arrays()
    return all(v.shape == ya[k].shape and all(
        np.array_equal(p, q, equal_nan=v.dtype.kind == "f") for _, (p, q) in schema.rows(v, ya[k]))
        for k, v in x.arrays().items())


def bench(label: str, cells: Path, n: int, work: Path) -> list[str]:
    eb = benchdoc.exabricks_command()
    rows = []
    src_whole = src_joined = cells
    for stage, _, out in STAGES:
        whole = work / f"{out}.npz"
        wall, _, peak = benchdoc.run_child([*eb, stage, src_whole, "-o", whole])
        pieces = []
        for k in range(n):
            pieces.append(benchdoc.run_child([*eb, stage, src_joined, "--piece", f"{k}/{n}",
                                              "-o", work / f"{out}.{k}.npz"]))
        joined = work / f"{out}.joined.npz"
        j_wall, _, j_peak = benchdoc.run_child(
            [*eb, "join", *[work / f"{out}.{k}.npz" for k in range(n)], "-o", joined])
        slowest = max(p[0] for p in pieces)
        same = identical(whole, joined, out)
        rows.append(
            f"| {label} | {stage} | {wall:.2f} | {benchdoc.fmt_bytes(peak)} | "
            f"{slowest:.2f} | {sum(p[0] for p in pieces):.2f} | "
            f"{benchdoc.fmt_bytes(max(p[2] for p in pieces))} | {j_wall:.2f} | "
            f"{benchdoc.fmt_bytes(j_peak)} | {wall / (slowest + j_wall):.2f} | "
            f"{'yes' if same else 'NO'} |")
        if label != "warm-up":
            print(rows[-1], flush=True)
        if not same:
            raise SystemExit(f"{label} {stage}: the joined pieces differ from the one-process file")
        for k in range(n):
            (work / f"{out}.{k}.npz").unlink()
        src_whole, src_joined = whole, joined
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pieces", type=int, default=4)
    p.add_argument("--only", default="shell", help="comma-separated keys of "
                   "bench-data/preprocess/KEY/cells.npz (default: shell)")
    p.add_argument("--cells", type=Path, action="append", default=[],
                   help="another cells file (repeatable)")
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    inputs = [(k, benchdoc.BENCH / "preprocess" / k / "cells.npz")
              for k in args.only.split(",") if k] + [
                  (c.parent.name if c.stem == "cells" else c.stem, c) for c in args.cells]
    with tempfile.TemporaryDirectory() as tmp:
        # numba's caches are filled by a first run (after an edit they are recompiled)
        from benchmarks.make_big import thin_shell_cells

        schema.save(Path(tmp) / "cells.npz", thin_shell_cells(32))
        bench("warm-up", Path(tmp) / "cells.npz", 2, Path(tmp))
    rows = []
    sets = benchdoc.datasets()
    for label, cells in inputs:
        if not cells.is_file() and label in sets:  # as benchmarks/bench_preprocess.py makes it
            import subprocess

            from benchmarks.bench_preprocess import commands

            cells.parent.mkdir(parents=True, exist_ok=True)
            subprocess.run(commands(sets[label], cells.parent)[0][1], check=True)
        if not cells.is_file():
            raise SystemExit(f"{cells}: missing")
        n_cells = schema.load(cells, "cells", mapped=True).n_cells
        with tempfile.TemporaryDirectory(dir=cells.parent) as tmp:
            rows += bench(f"{label}, {n_cells / 1e6:.1f} M cells", cells, args.pieces, Path(tmp))
    body = (
        f"Command: `.venv/bin/python -m benchmarks.bench_pieces --pieces {args.pieces} --only "
        f"{args.only}{''.join(f' --cells {c}' for c in args.cells)} --write-docs`\n\n"
        f"- machine: {benchdoc.machine()}\n"
        f"- each stage as one command, then as {args.pieces} commands `--piece K/{args.pieces}` "
        "run one after another, then `exabricks join`; s: wall seconds of a whole command; "
        "peak: peak resident memory; on N machines a stage takes its slowest piece plus the "
        "join (speed-up: one process / (slowest piece + join)); identical: the joined file "
        "equals the one-process file array for array\n\n"
        "| dataset | stage | one process s | peak | slowest piece s | all pieces s | "
        "piece peak | join s | join peak | speed-up | identical |\n"
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n" + "\n".join(rows) + "\n\n"
        + READING)
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
