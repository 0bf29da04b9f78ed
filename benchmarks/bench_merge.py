"""Merged regions against the paper's exact Active Brick Regions, per dataset.

    .venv/bin/python -m benchmarks.bench_merge [--runs 3] [--only gerris,...] [--write-docs]

For every dataset of benchmarks/benchdoc.py (the four shared real ones, the 23.6 M-cell
big input and the 20.6 M-cell thin shells) the bricks of bench_preprocess.py's work
folder (bench-data/preprocess/<key>/bricks.npz, made by the stage commands when
missing) are turned into regions and a BVH twice, in this process: with
`Merge()` (the default of `exabricks regions`) and with `EXACT` (`--exact`). Reported
per setting: the build times (median of --runs), bytes per leaf cell of the bricks'
index (everything but the values), of the regions and of the BVH, (regions + BVH) /
scalars, and the median kernel time of --runs frames (after a warm-up) at 512x512,
default camera and transfer function, no shading.

The exact regions of the thin shells are not built here: of the 2.33 M bricks the k-d
partition made before `brick` joined them (docs/design-structures.md "Bricks"), 83.4 M regions, 5.45 GB,
193 s at 13.7 GiB for `exabricks regions --exact` alone (measured once, docs/benchmarks-decisions.md
"Measurements behind design choices"); the row gives those figures.
--write-docs replaces the "## merged regions against exact ones" section of
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks import bench_preprocess

from exabricks import schema
from exabricks.picture.camera import default_camera
from exabricks.builders.bvh import build_bvh
from exabricks.builders.regions import EXACT, Merge, build_regions
from exabricks.engine.renderer import Renderer
from exabricks.picture.transfer_function import default_transfer_function

ROOT = Path(__file__).resolve().parents[1]


SECTION = "merged regions against exact ones"
SIZE = 512
# Measured once with the stage command (too large to build in a benchmark run).
SHELL_EXACT = {"regions": 83_364_768, "regions_bytes": 5_447_698_404, "seconds": 193.3,
               "peak_gib": 13.7}


def bricks_of(dataset: benchdoc.Dataset) -> schema.Bricks:
    work = benchdoc.BENCH / "preprocess" / dataset.key
    path = work / "bricks.npz"
    if not path.is_file():
        work.mkdir(parents=True, exist_ok=True)
        for _, argv in bench_preprocess.commands(dataset, work)[:2]:
            benchdoc.run_child(argv)
    return schema.load(path, "bricks")


def frame_ms(bricks, regions, bvh, field: str, runs: int) -> float:
    renderer = Renderer(bricks, regions, bvh, field=field)
    values = bricks.values[bricks.field_index(field)]
    tf = default_transfer_function((float(np.nanmin(values)), float(np.nanmax(values))))
    lo, hi = schema.world_bounds(bricks)
    camera = default_camera(np.asarray(lo), np.asarray(hi))
    times = []
    for i in range(runs + 1):
        result = renderer.render(camera=camera, transfer_function=tf, width=SIZE, height=SIZE,
                                 shading="none")
        if i:
            times.append(result.stats["ms"])
    return statistics.median(times)


def measure(dataset: benchdoc.Dataset, runs: int) -> dict:
    bricks = bricks_of(dataset)
    n_cells = bricks.values.shape[1]
    scalars = bricks.values[:1].nbytes * bricks.values.shape[0]
    index = sum(a.nbytes for k, a in bricks.arrays().items() if k != "values")
    out = {"dataset": dataset, "cells": n_cells, "bricks": bricks.n_bricks,
           "index_per_cell": index / n_cells, "scalars": scalars}
    for name, merge in (("merged", Merge()), ("exact", EXACT)):
        if name == "exact" and dataset.key == "shell":
            out[name] = None
            continue
        t = []
        for _ in range(runs):
            start = time.perf_counter()
            regions = build_regions(bricks, merge)
            t.append(time.perf_counter() - start)
        start = time.perf_counter()
        bvh = build_bvh(regions)
        bvh_s = time.perf_counter() - start
        r_bytes = sum(a.nbytes for a in regions.arrays().values())
        v_bytes = sum(a.nbytes for a in bvh.arrays().values())
        out[name] = {
            "regions": regions.n_regions, "regions_s": statistics.median(t), "bvh_s": bvh_s,
            "regions_per_cell": r_bytes / n_cells, "bvh_per_cell": v_bytes / n_cells,
            "ratio": (r_bytes + v_bytes) / scalars,
            "bricks_per_region": regions.meta["statistics"]["avg_bricks_per_region_by_count"],
            "ms": frame_ms(bricks, regions, bvh, dataset.field, runs),
        }
        del regions, bvh
    return out


def rows(r: dict) -> list[str]:
    name = r["dataset"].name
    lines = []
    for setting in ("exact", "merged"):
        m = r[setting]
        if m is None:
            e = SHELL_EXACT
            lines.append(
                f"| {name} | exact (of the 2.33 M k-d bricks before `brick` joined them; "
                f"measured once) | {e['regions']:,} | - | {r['index_per_cell']:.2f} "
                f"| {e['regions_bytes'] / r['cells']:.1f} | (not built) "
                f"| > {e['regions_bytes'] / r['scalars']:.0f} | {e['seconds']:.0f} as a command "
                f"at {e['peak_gib']} GiB | - | (not rendered) |")
            continue
        lines.append(
            f"| {name} | {setting} | {m['regions']:,} | {m['bricks_per_region']:.1f} "
            f"| {r['index_per_cell']:.2f} | {m['regions_per_cell']:.2f} | {m['bvh_per_cell']:.2f} "
            f"| {m['ratio']:.2f} | {m['regions_s']:.3g} | {m['bvh_s']:.3g} | {m['ms']:.0f} |")
    return lines


def section(results: list[dict], runs: int, command: str) -> str:
    return "\n".join([
        f"Command: `{command}`",
        "",
        f"- machine: {benchdoc.machine()}, load average {benchdoc.load_average()} at the end",
        f"- in process (no start-up, load or save); build times median of {runs}; frames "
        f"{SIZE}x{SIZE}, default camera and transfer function, no shading, median of {runs} "
        "after a warm-up",
        f"- merged: `Merge()` = {Merge().as_dict()}; exact: `--exact`",
        "",
        "| dataset | regions | count | bricks/region | bricks' index B/cell | regions B/cell "
        "| BVH B/cell | (regions + BVH) / scalars | regions s | bvh s | frame ms |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        *(line for r in results for line in rows(r)),
        "",
        "Bytes per leaf cell of every structure: the bricks' index (lower corner, level, dims, "
        "value offset per brick), the regions file and the BVH file; the scalars are 4 B per "
        "cell and field. Merging only ever joins pieces whose bricks hold at most "
        f"{Merge().max_brick_cells} cells, so block-structured data (AMReX, Athena++) keeps "
        "(nearly) its exact regions.",
        "",
    ])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(p, runs=3)
    args = p.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, list(sets))
    results = []
    for key in keys:
        results.append(measure(sets[key], args.runs))
        for line in rows(results[-1]):
            print(line, flush=True)
    command = (".venv/bin/python -m benchmarks.bench_merge"
               + (f" --only {','.join(keys)}" if args.only else "")
               + f" --runs {args.runs} --write-docs")
    benchdoc.publish(SECTION, section(results, args.runs, command), args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
