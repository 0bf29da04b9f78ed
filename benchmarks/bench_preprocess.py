"""Preprocessing per dataset: time, cells/s, peak memory and the paper's statistics.

    .venv/bin/python -m benchmarks.bench_preprocess [--runs 5] [--only gerris,amrex,athena,enzo,big,shell]
                                                   [--work bench-data/preprocess] [--write-docs]

For each dataset (the four shared real ones, make_big.py's 512^3 volume merged
to 23.6 M AMR cells, bench-data/big512.cells, and its octree-like thin-shell layout
of 20.6 M cells, bench-data/shell1024.cells, both made on first use;
benchmarks/benchdoc.py)
the four stages run as the real commands, `exabricks -q ingest|brick|regions|bvh`,
each in its own child process, chained through --work/<key>/*.npz with the
default parameters (brick width 32, BVH leaf size 4).  One warm-up chain, then
--runs timed chains; per stage the script reports the command's wall and CPU time
(os.wait4 rusage of the child), cells/s (the dataset's leaf cells / median wall
time) and the child's peak RSS (ru_maxrss).  Then, in this process, the stage's
work alone: `readers.read` + `validate_cells`, `build_bricks`, `build_regions`,
`build_bvh` on the loaded input (no start-up, .npz load, sha256 or save), one
warm-up and --runs timed calls.

Statistics come from the stage outputs (their meta["statistics"], written by the
commands, and the arrays): cells and levels; bricks and cells per brick; k-d
leaves and stored regions, bricks per region by count and by volume (paper
Table 1); BVH nodes and depth; array bytes of the scalars (every cell's field
values), of the bricks file (all its arrays, the scalars included), of the
regions file and of the BVH file, and (regions + BVH) / scalars.
--write-docs replaces the "## preprocessing per dataset" section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import sys
import time
from pathlib import Path

from benchmarks import benchdoc
from benchmarks.benchdoc import fmt_bytes, fmt_seconds

from exabricks import readers, schema
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.builders.cells import validate_cells
from exabricks.builders.regions import build_regions

ROOT = Path(__file__).resolve().parents[1]


SECTION = "preprocessing per dataset"
STAGES = ("ingest", "brick", "regions", "bvh")
OUTPUT = {"ingest": "cells", "brick": "bricks", "regions": "regions", "bvh": "bvh"}
BUILDER = {"ingest": "read + validate_cells", "brick": "build_bricks",
           "regions": "build_regions", "bvh": "build_bvh"}
NOTES = """
Stage commands: wall and CPU time of the whole command (interpreter start-up and
imports, .npz load and validation, the work, sha256 of the inputs for the
provenance record, fsync'ed .npz write); peak RSS is the child's ru_maxrss.
"In process" is the work alone, on an input already in memory.  cells/s counts the
dataset's leaf cells for every stage.  Bytes are in-memory array bytes (the .npz
files are uncompressed, so they are the file sizes less a few KiB of headers):
scalars = every cell's field values (float32, all fields of the input); bricks =
all arrays of the bricks file (the scalars, reordered, plus per brick lower
corner, level, dims and value offset, whose size is given in brackets); regions =
bounds, CSR brick lists, per-field value ranges and finest level; BVH = node
bounds, first/count, region order, per-field value ranges, finest level.

"k-d leaves" is the paper's partition (§3.2.3); "regions" what is stored after merging
face-adjacent leaves with the same brick list (exact, fewer boxes). Bricks/region averages
and "max" refer to the stored regions.
"""

# The issues' preprocessing targets, per generated input (`targets`): the block-
# structured big one, and the octree-like thin shells (issue 10, where the peak memory
# of a stage is judged against twice its input plus output files).
TARGETS = {
    "big": {"brick_cells_per_s": 2e6, "regions_bvh_s": 60.0, "size_ratio": 1.5},
    "shell": {"brick_cells_per_s": 5e6, "regions_bvh_s": 15.0, "size_ratio": 3.0,
              "memory_factor": 2.0},
}
TARGET_CORES = 2


def defaults() -> dict:
    """The builders' default tuning parameters, as the stage commands use them."""
    return {"max_brick_width": inspect.signature(build_bricks).parameters["max_brick_width"].default,
            "leaf_size": inspect.signature(build_bvh).parameters["leaf_size"].default}


def size_notes(results: list[dict]) -> list[str]:
    """Why (regions + BVH) / scalars is what it is, per dataset, from its bytes and counts."""
    lines = [
        "Where the (regions + BVH) / scalars ratio comes from: a region stores its bounds, a "
        "CSR pointer, one index per listed brick, a value range per field and its finest "
        "level, and the BVH adds its nodes; even bricks on a regular grid give at least 8 "
        "regions per brick (interior, 6 faces/2, 12 edges/4, 8 corners/8: every support "
        "overlaps its 26 neighbours), so the ratio is small only where bricks hold many cells. "
        "Per brick, in this run:",
        "",
    ]
    for r in results:
        b, n_bricks = r["bytes"], r["n_bricks"]
        n_regions = r["region_stats"]["n_regions"]
        per_brick = (b["regions"] + b["bvh"]) / n_bricks
        ratio = (b["regions"] + b["bvh"]) / b["scalars"]
        lines.append(
            f"- {r['dataset'].name}: {n_regions / n_bricks:.1f} regions x "
            f"({b['regions'] / n_regions:.0f} B of region + {b['bvh'] / n_regions:.0f} B of BVH) "
            f"= {per_brick:.0f} B against {b['scalars'] / n_bricks:.0f} B of scalars "
            f"({r['cells'] / n_bricks:.1f} cells x {r['fields']} field(s)): {ratio:.2f}x"
            + (f", {'within' if ratio <= t['size_ratio'] else 'above'} the "
               f"{t['size_ratio']:g}x target" if (t := TARGETS.get(r["dataset"].key)) else ""))
    return lines


def commands(dataset: benchdoc.Dataset, work: Path) -> list[tuple[str, list[str]]]:
    """(stage, argv) of the four stage commands of `dataset`, chained through `work`."""
    eb = [*benchdoc.exabricks_command(), "-q"]
    out = {s: str(work / f"{OUTPUT[s]}.npz") for s in STAGES}
    return [
        ("ingest", [*eb, "ingest", str(dataset.path), "-o", out["ingest"], *dataset.ingest_flags]),
        ("brick", [*eb, "brick", out["ingest"], "-o", out["brick"]]),
        ("regions", [*eb, "regions", out["brick"], "-o", out["regions"]]),
        ("bvh", [*eb, "bvh", out["regions"], "-o", out["bvh"]]),
    ]


def rate(n: int, seconds) -> str:
    """Cells per second in millions at the median time: '5.3', '0.84'."""
    m = n / statistics.median(seconds) / 1e6
    return f"{m:.1f}" if m >= 10 else f"{m:.2f}"


def measure(dataset: benchdoc.Dataset, work: Path, runs: int) -> dict:
    """Command and in-process timings, peak RSS, statistics and bytes of one dataset."""
    work.mkdir(parents=True, exist_ok=True)
    steps = commands(dataset, work)
    cmd = {s: {"wall": [], "cpu": [], "rss": []} for s in STAGES}
    for i in range(runs + 1):  # chain 0 is the warm-up
        walls = []
        for stage, argv in steps:
            wall, cpu, rss = benchdoc.run_child(argv)
            walls.append(f"{stage} {wall:.2f} s")
            if i:
                cmd[stage]["wall"].append(wall)
                cmd[stage]["cpu"].append(cpu)
                cmd[stage]["rss"].append(rss)
        print(f"  {dataset.key} chain {i}{' (warm-up)' if not i else ''}: {', '.join(walls)}",
              flush=True)

    files = {s: work / f"{OUTPUT[s]}.npz" for s in STAGES}
    source, fmt = dataset.path, dataset.format

    def ingest():
        validate_cells(readers.read(source, format=fmt), source=str(source))

    built = {"ingest": benchdoc.timed(ingest, runs)[0]}
    cells = schema.load(files["ingest"], "cells")
    n_cells, scalar_bytes = cells.n_cells, cells.values.nbytes
    built["brick"] = benchdoc.timed(lambda c=cells: build_bricks(c), runs)[0]
    cell_stats, n_fields = cells.meta["statistics"], cells.n_fields
    del cells
    bricks = schema.load(files["brick"], "bricks")
    built["regions"] = benchdoc.timed(lambda b=bricks: build_regions(b), runs)[0]
    brick_arrays = {k: a.nbytes for k, a in bricks.arrays().items()}
    brick_stats, n_bricks = bricks.meta["statistics"], bricks.n_bricks
    del bricks
    regions = schema.load(files["regions"], "regions")
    built["bvh"] = benchdoc.timed(lambda r=regions: build_bvh(r), runs)[0]
    region_stats = regions.meta["statistics"]
    del regions
    bvh_stats = schema.load(files["bvh"], "bvh").meta["statistics"]
    return {
        "files": {s: files[s].stat().st_size for s in STAGES},
        "dataset": dataset, "cells": n_cells, "fields": n_fields, "cmd": cmd, "built": built,
        "cell_stats": cell_stats, "brick_stats": brick_stats, "region_stats": region_stats,
        "bvh_stats": bvh_stats, "n_bricks": n_bricks,
        "bytes": {"scalars": scalar_bytes, "bricks": sum(brick_arrays.values()),
                  "brick_index": sum(v for k, v in brick_arrays.items() if k != "values"),
                  "regions": region_stats["bytes"], "bvh": bvh_stats["bytes"]},
    }


def time_rows(r: dict) -> list[str]:
    n, name = r["cells"], r["dataset"].name
    rows = []
    for s in STAGES:
        c, b = r["cmd"][s], r["built"][s]
        mib = [x / 2**20 for x in c["rss"]]
        rows.append(f"| {name} | {s} | {fmt_seconds(c['wall'])} | {rate(n, c['wall'])} "
                    f"| {statistics.median(c['cpu']):.2f} | {benchdoc.fmt_spread(mib, '', 0)} "
                    f"| {BUILDER[s]}: {fmt_seconds(b)} | {rate(n, b)} |")
    return rows


def stats_row(r: dict) -> str:
    c, b, g, v = r["cell_stats"], r["brick_stats"], r["region_stats"], r["bvh_stats"]
    return (f"| {r['dataset'].name} | {r['cells']:,} | {c['levels']} | {b['bricks']:,} "
            f"| {b['mean_cells_per_brick']:.1f} | {g['n_partition_leaves']:,} | {g['n_regions']:,} "
            f"| {g['n_regions'] / b['bricks']:.1f} | {g['avg_bricks_per_region_by_count']:.2f} "
            f"| {g['avg_bricks_per_region_by_volume']:.2f} | {g['max_bricks_per_region']} "
            f"| {v['n_nodes']:,} | {v['depth']} |")


def bytes_row(r: dict) -> str:
    b = r["bytes"]
    s = b["scalars"]
    return (f"| {r['dataset'].name} | {r['fields']} | {fmt_bytes(s)} | {fmt_bytes(b['bricks'])} "
            f"({fmt_bytes(b['brick_index'])}) | {fmt_bytes(b['regions'])} | {fmt_bytes(b['bvh'])} "
            f"| {(b['regions'] + b['bvh']) / s:.2f} | {(b['bricks'] + b['regions'] + b['bvh']) / s:.2f} |")


def targets(r: dict) -> str:
    """The issue's targets on a generated input, from its row."""
    t = TARGETS[r["dataset"].key]
    n = r["cells"]
    built = {s: statistics.median(r["built"][s]) for s in STAGES}
    cmd = {s: statistics.median(r["cmd"][s]["wall"]) for s in STAGES}
    size = (r["bytes"]["regions"] + r["bytes"]["bvh"]) / r["bytes"]["scalars"]
    text = (f"Targets on {r['dataset'].name} ({n:,} cells): brick >= "
            f"{t['brick_cells_per_s'] / 1e6:g} M cells/s: build_bricks "
            f"{n / built['brick'] / 1e6:.1f} M cells/s (the command {n / cmd['brick'] / 1e6:.1f} M); "
            f"regions + bvh < {t['regions_bvh_s']:g} s on {TARGET_CORES} "
            f"cores: {built['regions'] + built['bvh']:.1f} s in process "
            f"({cmd['regions'] + cmd['bvh']:.1f} s as commands); (regions + BVH) <= "
            f"{t['size_ratio']:g} x scalars: {size:.2f} x (see below)")
    if "memory_factor" in t:
        files = r["files"]
        parts = []
        for s, (inp, out) in {"brick": ("ingest", "brick"), "regions": ("brick", "regions"),
                              "bvh": ("regions", "bvh")}.items():
            peak = statistics.median(r["cmd"][s]["rss"])
            parts.append(f"{s} {peak / 2**20:.0f} MiB for {files[inp] / 2**20:.0f} + "
                         f"{files[out] / 2**20:.0f} MiB of files "
                         f"({peak / (files[inp] + files[out]):.2f}x)")
        text += (f"; peak memory within about {t['memory_factor']:g}x input + output: "
                 + ", ".join(parts))
    return text + "."


def section(results: list[dict], runs: int, command: str) -> str:
    import numba

    levels = "\n".join(
        f"- {r['dataset'].name}: " + ", ".join(f"{l}: {c:,}" for l, c in
                                               r["brick_stats"]["bricks_per_level"].items())
        for r in results)
    generated = [r for r in results if r["dataset"].key in TARGETS]
    return "\n".join([
        f"Command: `{command}` (it makes bench-data/big512.cells and shell1024.cells with "
        "`benchmarks/make_big.py` on first use)",
        "",
        f"- machine: {benchdoc.machine()}, numba {numba.__version__} with "
        f"{numba.get_num_threads()} threads, load average {benchdoc.load_average()} at the end",
        f"- median of {runs} runs after a warm-up, (min-max) in brackets; default parameters "
        f"(brick width {defaults()['max_brick_width']}, BVH leaf size {defaults()['leaf_size']})",
        "",
        "Time and memory per stage (seconds; cells/s in millions):",
        "",
        "| dataset | stage | command wall s | M cells/s | command CPU s | peak RSS MiB "
        "| in process s | M cells/s in process |",
        "|---|---|---:|---:|---:|---:|---|---:|",
        *(row for r in results for row in time_rows(r)),
        "",
        *(line for r in generated for line in (targets(r), "")),
        "Statistics (paper Table 1; bricks per region averaged by count and weighted by volume):",
        "",
        "| dataset | cells | levels | bricks | cells/brick | k-d leaves | regions | regions/brick "
        "| by count | by volume | max | BVH nodes | BVH depth |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        *(stats_row(r) for r in results),
        "",
        "Bytes (arrays; bricks with the brick index alone in brackets):",
        "",
        "| dataset | fields | scalars | bricks | regions | BVH | (regions + BVH) / scalars "
        "| (bricks + regions + BVH) / scalars |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
        *(bytes_row(r) for r in results),
        "",
        "Bricks per level:",
        "",
        levels,
        NOTES,
        *size_notes(results),
    ])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(p)
    p.add_argument("--work", type=Path, default=benchdoc.BENCH / "preprocess",
                   help="where the stage outputs go (one folder per dataset)")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error("--runs must be at least 1")
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, list(sets))
    results = []
    for key in keys:
        t = time.perf_counter()
        results.append(measure(sets[key], args.work / key, args.runs))
        for row in time_rows(results[-1]):
            print(row, flush=True)
        print(f"  {key}: {time.perf_counter() - t:.0f} s", flush=True)
    command = (".venv/bin/python -m benchmarks.bench_preprocess"
               + (f" --only {','.join(keys)}" if args.only else "")
               + f" --runs {args.runs} --write-docs")
    body = section(results, args.runs, command)
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
