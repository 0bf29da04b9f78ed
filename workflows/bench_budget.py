"""Rendering under a memory budget: time and peak memory against the in-memory
render (issue 11).

    .venv/bin/python workflows/bench_budget.py [--only shell,big] [--size 512] [--write-docs]

For each dataset (default make_big.py's 20.6 M-cell thin shells, made on first
use) one frame with early termination off (--max-opacity 1, so that the images
must agree) is rendered by whole `exabricks render` commands: in memory, and
with `--memory-budget` at 1/2, 1/4, 1/8 and 1/16 of the bytes of the three
structure files. The baseline is the same budgeted command on a dataset of 64
cells at the same image size (interpreter, numba, OpenCL runtime, images): the
issue's bound is peak <= budget + baseline. Each command's peak resident memory
comes from wait4 (benchdoc.run_child). The RMSE is against the in-memory image,
over its maximum.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchdoc  # noqa: E402
from bench_render import ensure_scene  # noqa: E402

ROOT = benchdoc.ROOT
SECTION = "Rendering under a memory budget"
FRACTIONS = (2, 4, 8, 16)


def tiny_scene(d: Path, field: str) -> list[Path]:
    """A 4^3-cell dataset of one field named `field` (the baseline's)."""
    from exabricks import schema
    from exabricks.stages.brick import build_bricks
    from exabricks.stages.bvh import build_bvh
    from exabricks.stages.regions import build_regions

    g = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = schema.Cells(fields=(field,), origin_world=np.zeros(3), spacing_world=np.ones(3),
                         lower_lattice=g.astype(np.int32), level=np.zeros(len(g), np.int8),
                         values=np.linspace(0, 1, len(g), dtype=np.float32)[None])
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    paths = [d / f"tiny_{n}.npz" for n in ("bricks", "regions", "bvh")]
    for path, obj in zip(paths, (bricks, regions, build_bvh(regions))):
        schema.save(path, obj)
    return paths


def bench_dataset(name: str, d: Path, field: str, size: int, tmp: Path) -> list[str]:
    from exabricks.image_io import read_image

    eb = benchdoc.exabricks_command()
    files = [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    nbytes = sum(f.stat().st_size for f in files)
    flags = ["--field", field, "--size", size, size, "--max-opacity", 1]

    def run(paths, out, *extra):
        benchdoc.run_child([*eb, "render", *paths, "-o", out, *flags, *extra])  # warm caches
        return benchdoc.run_child([*eb, "render", *paths, "-o", out, *flags, *extra])

    tiny = tiny_scene(tmp, field)
    wall, _, peak = run(files, tmp / "whole.exr")
    whole, _ = read_image(tmp / "whole.exr")
    rows = [f"| {name} | in memory | | {benchdoc.fmt_bytes(nbytes)} | 1 | {wall:.1f} | "
            f"{benchdoc.fmt_bytes(peak)} | | |"]
    for k in FRACTIONS:
        budget = nbytes // k
        _, _, base = run(tiny, tmp / "tiny.exr", "--memory-budget", budget)
        try:
            wall, _, peak = run(files, tmp / f"b{k}.exr", "--memory-budget", budget)
        except SystemExit as e:  # refused: its one error line
            reason = str(e).split("error: ", 1)[-1].strip()
            rows.append(f"| {name} | 1/{k} of the files | {benchdoc.fmt_bytes(budget)} | "
                        f"{benchdoc.fmt_bytes(nbytes)} | refused: {reason} | | | | |")
            continue
        image, meta = read_image(tmp / f"b{k}.exr")
        rmse = float(np.sqrt(np.mean((image.astype(np.float64) - whole) ** 2)) / np.abs(whole).max())
        over = peak - base
        rows.append(f"| {name} | 1/{k} of the files | {benchdoc.fmt_bytes(budget)} | "
                    f"{benchdoc.fmt_bytes(nbytes)} | {meta['settings']['pieces']} | {wall:.1f} | "
                    f"{benchdoc.fmt_bytes(peak)} | {benchdoc.fmt_bytes(over)} "
                    f"({over / budget:.2f} of the budget) | {rmse:.1e} |")
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="datasets (benchdoc keys; default shell)")
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--work", type=Path, default=ROOT / "bench-data" / "render")
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, list(sets)) if args.only else ["shell"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for key in keys:
            d = ensure_scene(args.work, sets[key])
            rows += bench_dataset(sets[key].name, d, sets[key].field, args.size, Path(tmp))
    command = f"`.venv/bin/python workflows/bench_budget.py --only {','.join(keys)} --write-docs`"
    section = (
        f"Command: {command}\n\n- machine: {benchdoc.machine(opencl=True)}\n"
        f"- one {args.size}² frame, default camera and transfer function, `--max-opacity 1`; "
        "whole `exabricks render` commands (each run twice, the second measured, so that PoCL's "
        "kernel cache is warm); files: the bytes of the bricks, regions and bvh files; "
        "peak: the command's peak resident memory; above baseline: the peak less that of the "
        "same budgeted command on a 64-cell dataset (the issue's bound is the budget); "
        "RMSE: against the in-memory image, over its maximum\n\n"
        "| dataset | budget | budget bytes | files | pieces | command s | peak | above baseline "
        "| RMSE |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n" + "\n".join(rows) + "\n")
    benchdoc.publish(SECTION, section, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
