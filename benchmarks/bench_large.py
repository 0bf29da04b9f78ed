"""The thin shells at the largest size: every stage's time and peak memory, and the
render in memory and under budgets (issue 11).

    .venv/bin/python -m benchmarks.bench_large [--size 2944] [--image 512] [--write-docs]

make_big.py's octree-like thin-shell layout at --size (204 M cells at 2944, written
a slab at a time, bench-data/shellSIZE.cells, made when missing) goes through the
real commands, `exabricks ingest|brick|regions|bvh`, each once in its own child
process (wall and CPU time, peak resident memory from wait4; files in --work).
Then one --image² frame with `--max-opacity 1`: in memory, and under
`--memory-budget` of 1/2, 1/4 and 1/16 of the three structure files (the last
also in bands of 128 rows), as benchmarks/bench_budget.py measures them (baseline:
the same command on 64 cells; RMSE against the in-memory image). Rows are printed
as they come; --write-docs replaces the section "Thin shells at the largest size"
of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import benchdoc
from benchmarks.bench_budget import TABLE_HEAD, bench_dataset

SECTION = "Thin shells at the largest size"
STAGES = (("ingest", "cells"), ("brick", "bricks"), ("regions", "regions"), ("bvh", "bvh"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=2944, help="make_big.py --thin-shell --size")
    p.add_argument("--image", type=int, default=512, help="frame side")
    p.add_argument("--work", type=Path, default=benchdoc.BENCH / "large")
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    source = benchdoc.BENCH / f"shell{args.size}.cells"
    if not source.with_name(f"shell{args.size}.rho.scalars").is_file():
        subprocess.run([sys.executable, str(benchdoc.ROOT / "benchmarks" / "make_big.py"),
                        "--thin-shell", "--size", str(args.size), "--out", str(source)],
                       check=True, stdout=subprocess.DEVNULL)
    n_cells = source.stat().st_size // 16
    d = args.work / f"shell{args.size}"
    d.mkdir(parents=True, exist_ok=True)
    eb = benchdoc.exabricks_command()
    rows, src = [], source
    for stage, out in STAGES:
        dst = d / f"{out}.npz"
        wall, cpu, peak = benchdoc.run_child([*eb, stage, src, "-o", dst])
        files = (src.stat().st_size + (src.with_name(f"shell{args.size}.rho.scalars").stat()
                                       .st_size if stage == "ingest" else 0))
        rows.append(f"| {stage} | {wall:.1f} | {n_cells / wall / 1e6:.1f} | {cpu:.1f} | "
                    f"{benchdoc.fmt_bytes(peak)} | {benchdoc.fmt_bytes(files)} | "
                    f"{benchdoc.fmt_bytes(dst.stat().st_size)} | "
                    f"{peak / (files + dst.stat().st_size):.2f} |")
        print(rows[-1], flush=True)
        src = dst
    with tempfile.TemporaryDirectory() as tmp:
        renders = bench_dataset(f"thin shells, {n_cells / 1e6:.0f} M cells", d, "rho",
                                args.image, Path(tmp),
                                runs=[(2, ()), (4, ()), (16, ()),
                                      (16, ("--tile", args.image, 128))])
    body = (
        f"Command: `.venv/bin/python -m benchmarks.bench_large --size {args.size} --image "
        f"{args.image} --write-docs`\n\n- machine: {benchdoc.machine(opencl=True)}\n"
        f"- make_big.py --thin-shell --size {args.size}: {n_cells:,} cells on 4 levels; each "
        "stage one whole command (interpreter, load and checks, the work, sha256, fsync'ed "
        "write); peak: its peak resident memory; in, out: the bytes of its input and output "
        "files\n\n"
        "| stage | command s | M cells/s | CPU s | peak | in | out | peak / (in + out) |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|\n" + "\n".join(rows) + "\n\n"
        f"Render: one {args.image}² frame, default camera and transfer function, "
        "`--max-opacity 1`, measured as in \"Rendering under a memory budget\"\n\n"
        + TABLE_HEAD + "\n".join(renders) + "\n")
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
