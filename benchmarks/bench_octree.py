"""A RAMSES-like octree at scale: ingest, brick, regions and bvh against the builders'
bounds.

    .venv/bin/python -m benchmarks.bench_octree [--levelmin 7] [--levelmax 11]
        [--radius 0.44] [--write-docs]

tests/helpers/ramses_output.py writes a RAMSES output in RAMSES' own layout (2 cpus,
Hilbert domains) of an octree refined about a ball whose radius halves per level
(levels --levelmin..--levelmax, ball radius --radius of the box at levelmin; the
defaults give 23.8 M leaves on 5 levels, each but the finest only partly refined),
once, into bench-data/ramses-octree-LEVELMIN-LEVELMAX/output_00001 (kept and reused
while its `written.json` records the same parameters).  Then the real commands,
`exabricks ingest|brick|regions|bvh`, each once in its own child process (wall and
CPU time, peak resident memory from wait4; files next to the output), against the
bounds: ingest and brick at least 5 M cells/s, regions + bvh under 15 s, every
stage's peak at most 2 x (in + out) + 300 MiB.  --write-docs replaces the section
"RAMSES-like octree at scale" of docs/benchmarks-scale.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc

SECTION = "RAMSES-like octree at scale"
DOCS = benchdoc.ROOT / "docs" / "benchmarks-scale.md"
STAGES = (("ingest", "cells"), ("brick", "bricks"), ("regions", "regions"), ("bvh", "bvh"))
MIN_RATE = 5e6  # cells/s, ingest and brick
MAX_REGIONS_BVH_S = 15.0
PEAK_SLACK = 300 * 2 ** 20  # peak <= 2 x (in + out) + this


def ensure_output(folder: Path, levelmin: int, levelmax: int, radius: float) -> dict:
    """Write the RAMSES output under `folder` unless it is there with these parameters;
    what `written.json` records of it (parameters, leaves per level, seconds to write)."""
    marker = folder / "written.json"
    wanted = dict(levelmin=levelmin, levelmax=levelmax, radius=radius)
    if marker.is_file():
        record = json.loads(marker.read_text())
        if {k: record.get(k) for k in wanted} == wanted:
            return record
    shutil.rmtree(folder / "output_00001", ignore_errors=True)
    marker.unlink(missing_ok=True)
    folder.mkdir(parents=True, exist_ok=True)
    ramses_output = benchdoc.tests_module("helpers.ramses_output")
    print(f"writing {folder / 'output_00001'} (levels {levelmin}..{levelmax}, radius "
          f"{radius})", flush=True)
    t = time.perf_counter()
    _, leaves = ramses_output.write(folder, levelmin=levelmin, levelmax=levelmax,
                                    radius=radius)
    seconds = time.perf_counter() - t
    widths, counts = np.unique(leaves.width, return_counts=True)
    per_level = {str(int(round(-np.log2(w)))): int(n) for w, n in zip(widths, counts)}
    del leaves
    record = dict(wanted, leaves=int(counts.sum()), per_level=per_level,
                  write_s=round(seconds, 1))
    marker.write_text(json.dumps(record, indent=1) + "\n")
    return record


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--levelmin", type=int, default=7, help="coarsest leaf level (RAMSES)")
    p.add_argument("--levelmax", type=int, default=11, help="finest level (RAMSES)")
    p.add_argument("--radius", type=float, default=0.44,
                   help="refinement ball radius at levelmin, in units of the box")
    p.add_argument("--work", type=Path, default=benchdoc.BENCH,
                   help="folder of ramses-octree-LEVELMIN-LEVELMAX/")
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    folder = args.work / f"ramses-octree-{args.levelmin}-{args.levelmax}"
    record = ensure_output(folder, args.levelmin, args.levelmax, args.radius)
    n_cells = record["leaves"]
    source = folder / "output_00001"
    eb = benchdoc.exabricks_command()
    rows, walls, rates, peaks, src = [], {}, {}, {}, source
    load = benchdoc.load_average()
    for stage, out in STAGES:
        dst = folder / f"{out}.npz"
        wall, cpu, peak = benchdoc.run_child([*eb, stage, src, "-o", dst])
        size_in = folder_bytes(src) if src.is_dir() else src.stat().st_size
        size_out = dst.stat().st_size
        walls[stage], rates[stage] = wall, n_cells / wall
        peaks[stage] = (peak, size_in, size_out)
        rows.append(f"| {stage} | {wall:.1f} | {n_cells / wall / 1e6:.1f} | {cpu:.1f} | "
                    f"{benchdoc.fmt_bytes(peak)} | {benchdoc.fmt_bytes(size_in)} | "
                    f"{benchdoc.fmt_bytes(size_out)} | {peak / (size_in + size_out):.2f} |")
        print(rows[-1], flush=True)
        src = dst

    def verdict(ok: bool) -> str:
        return "met" if ok else "**missed**"

    bounds = [f"- {stage} >= {MIN_RATE / 1e6:.0f} M cells/s: {rates[stage] / 1e6:.1f} M "
              f"cells/s, {verdict(rates[stage] >= MIN_RATE)}" for stage in ("ingest", "brick")]
    both = walls["regions"] + walls["bvh"]
    bounds.append(f"- regions + bvh < {MAX_REGIONS_BVH_S:.0f} s: {both:.1f} s, "
                  f"{verdict(both < MAX_REGIONS_BVH_S)}")
    for stage, (peak, size_in, size_out) in peaks.items():
        limit = 2 * (size_in + size_out) + PEAK_SLACK
        bounds.append(f"- {stage} peak <= 2 x (in + out) + 300 MiB = {benchdoc.fmt_bytes(limit)}: "
                      f"{benchdoc.fmt_bytes(peak)}, {verdict(peak <= limit)}")
    levels = ", ".join(f"{level}: {n:,}" for level, n in
                       sorted(record["per_level"].items(), key=lambda kv: int(kv[0])))
    command = ("`.venv/bin/python -m benchmarks.bench_octree --levelmin "
               f"{args.levelmin} --levelmax {args.levelmax} --radius {args.radius} "
               "--write-docs`")
    body = (
        f"Command: {command}\n\n- machine: {benchdoc.machine()}; load average "
        f"{load} at the start (a shared machine)\n"
        f"- input: tests/helpers/ramses_output.py's RAMSES output (RAMSES' own Fortran-"
        f"record layout, 2 cpus, Hilbert domains), levels {args.levelmin}..{args.levelmax}, "
        f"refined about a ball of radius {args.radius} of the box at level {args.levelmin} "
        f"that halves per level: {n_cells:,} leaf cells (by RAMSES level: {levels}); "
        f"written once in {record['write_s']:.0f} s, `exabricks ingest` reads the folder "
        "natively\n"
        "- each stage one whole command (interpreter, load and checks, the work, sha256, "
        "fsync'ed write); M cells/s: leaf cells over its command time; peak: its peak "
        "resident memory; in, out: the bytes of its input (for ingest: the output folder) "
        "and output files\n\n"
        "| stage | command s | M cells/s | CPU s | peak | in | out | peak / (in + out) |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|\n" + "\n".join(rows) + "\n\n"
        "Bounds:\n\n" + "\n".join(bounds) + "\n")
    print(body)
    if args.write_docs:
        benchdoc.replace_section(SECTION, body, docs=DOCS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
