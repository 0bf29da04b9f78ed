"""Time series on a fixed hierarchy: one step as its values against a full rebuild
(issue 38; docs/time-series.md).

    .venv/bin/python -m benchmarks.bench_values [--only gerris,amrex,shell] [--runs 3] [--write-docs]

For each dataset, as whole commands (wall, CPU and peak RSS of each process, the
median of --runs after a warm-up): a step's *full rebuild* is `ingest`, `brick`,
`regions` and `bvh` of its source; a step *as values* is `exabricks values SOURCE
--bricks BRICKS` of the same source on the first step's bricks (the data have one
output each; what a step costs does not depend on its values). Then the frame's
side: `render BRICKS REGIONS BVH` of a 64² frame (so small that the command is its
loading) with and without `--values`: the difference is reading the values file
and recomputing the region and node value ranges.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from benchmarks import benchdoc

SECTION = "Time series on a fixed hierarchy"
DEFAULT = ("gerris", "amrex", "athena", "enzo", "shell")
NOTES = """
*Full rebuild*: the four commands `ingest`, `brick`, `regions`, `bvh` of the step's
source, one after the other (walls and CPU added; peak: the largest of the four).
*As values*: `exabricks values SOURCE --bricks BRICKS -o STEP.npz` on the first
step's bricks: reading the source (the same reader as `ingest`), matching its cells
to the bricks' cell slots (two sorts of 64-bit lattice keys), and writing the
values in the bricks' order. Every dataset here has one output: a step is that
output again, which costs what any step of the same cells costs. *Render*: a 64²
frame of the structure files as a whole command, with `--values STEP.npz` and
without; the difference is loading the values file and recomputing the value
ranges of the regions (`leaf_ranges` of the regions builder) and of the BVH
nodes (its `refit`).

What it says. A step as values costs what reading it costs plus one pass over
its cells: on the 20.6 M-cell thin shells the reader takes 3.4 s of the 5.8 s
(in one process: reading 3.41 s, matching and laying out 1.19 s; the rest is
the interpreter and the write), against 16.0 s for the four commands of a full
rebuild, whose k-d partition of the bricks, regions and BVH are what the values
skip. Its peak is above the rebuild's largest command (1.26 GiB against 837
MiB): the step's cells, and for the matching two int64 keys and two sort orders
per cell (32 bytes a cell, 660 MB at 20.6 M cells). On the small datasets the
process start-up (about 0.4 s) and the reader dominate both. A frame with
`--values` pays once per command for the value ranges: about 0.4 s of numba's
import and compiled-code cache load, and the range pass over the cells (0.54 s
at 20.6 M cells, 1.30 M regions, on 2 cores, in a warm process; 1 ms at 0.5 M).
"""


def measure(dataset: benchdoc.Dataset, work: Path, runs: int) -> dict:
    eb = benchdoc.exabricks_command()
    d = work / dataset.key
    d.mkdir(parents=True, exist_ok=True)
    src = str(dataset.path)
    stages = [
        ["ingest", src, "-o", d / "cells.npz", *dataset.ingest_flags],
        ["brick", d / "cells.npz", "-o", d / "bricks.npz"],
        ["regions", d / "bricks.npz", "-o", d / "regions.npz"],
        ["bvh", d / "regions.npz", "-o", d / "bvh.npz"],
    ]
    values = ["values", src, "--bricks", d / "bricks.npz", "-o", d / "step.npz", *dataset.ingest_flags]
    frame = ["render", d / "bricks.npz", d / "regions.npz", d / "bvh.npz", "-o", d / "frame.png",
             "--field", dataset.field, "--size", "64", "64"]
    runs_of = {"full": [], "values": [], "render": [], "render_values": []}
    for k in range(runs + 1):  # the first round warms the caches (numba, PoCL, the page cache)
        full = [benchdoc.run_child(eb + stage) for stage in stages]
        rounds = {"full": (sum(f[0] for f in full), sum(f[1] for f in full), max(f[2] for f in full)),
                  "values": benchdoc.run_child(eb + values),
                  "render": benchdoc.run_child(eb + frame),
                  "render_values": benchdoc.run_child(eb + frame + ["--values", d / "step.npz"])}
        if k:
            for key, r in rounds.items():
                runs_of[key].append(r)
    from exabricks import schema

    bricks = schema.load(d / "bricks.npz", "bricks", mapped=True)
    return {"runs": runs_of, "cells": int(bricks.values.shape[1]),
            "bytes": {name: (d / f"{name}.npz").stat().st_size
                      for name in ("cells", "bricks", "regions", "bvh", "step")}}


def table(results: dict) -> str:
    med = lambda rs, i: statistics.median(r[i] for r in rs)  # noqa: E731
    lines = ["| dataset | cells | full rebuild s (CPU s) / peak | as values s (CPU s) / peak | "
             "full / values | files: structures / values | render 64² s: alone / with --values "
             "(+ s) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for key, r in results.items():
        runs = r["runs"]
        full, vals = runs["full"], runs["values"]
        structures = sum(r["bytes"][k] for k in ("bricks", "regions", "bvh"))
        alone, withv = med(runs["render"], 0), med(runs["render_values"], 0)
        lines.append(
            f"| {key} | {r['cells']:,} | {med(full, 0):.2f} ({med(full, 1):.2f}) / "
            f"{benchdoc.fmt_bytes(med(full, 2))} | {med(vals, 0):.2f} ({med(vals, 1):.2f}) / "
            f"{benchdoc.fmt_bytes(med(vals, 2))} | {med(full, 0) / med(vals, 0):.1f}x | "
            f"{benchdoc.fmt_bytes(structures)} / {benchdoc.fmt_bytes(r['bytes']['step'])} | "
            f"{alone:.2f} / {withv:.2f} (+{withv - alone:.2f}) |")
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    benchdoc.add_common_args(p, runs=3)
    p.add_argument("--work", type=Path, default=benchdoc.BENCH / "values",
                   help="where the steps' files go (default bench-data/values)")
    args = p.parse_args(argv)
    all_sets = benchdoc.datasets()
    results = {}
    for key in benchdoc.chosen(args.only, DEFAULT):
        print(f"{key}: ...", flush=True)
        results[key] = measure(all_sets[key], args.work, args.runs)
        print(table({key: results[key]}).splitlines()[-1], flush=True)
    command = ".venv/bin/python -m benchmarks.bench_values" + (
        f" --only {','.join(results)}" if list(results) != list(DEFAULT) else "") + f" --runs {args.runs}"
    body = (f"Command: `{command}`\n\n- machine: {benchdoc.machine(opencl=True)}\n"
            f"- load: {benchdoc.load_average()}\n\n{table(results)}\n{NOTES}")
    benchdoc.publish(SECTION, body, args.write_docs)


if __name__ == "__main__":
    main()
