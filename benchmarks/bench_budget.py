"""Rendering under a memory budget: time and peak memory against the in-memory
render (issue 11).

    .venv/bin/python -m benchmarks.bench_budget [--only shell,big] [--size 512] [--poster 16384]
        [--write-docs]

For each dataset (default make_big.py's 20.6 M-cell thin shells, made on first
use) one frame with early termination off (--max-opacity 1, so that the images
must agree) is rendered by whole `exabricks render` commands: in memory, and
with `--memory-budget` at 1/2, 1/4, 1/8 and 1/16 of the bytes of the three
structure files. The baseline is the same budgeted command on a dataset of 64
cells at the same image size (interpreter, numba, OpenCL runtime, images): the
issue's bound is peak <= budget + baseline. Each command's peak resident memory
comes from wait4 (benchdoc.run_child). The RMSE is against the in-memory image,
over its maximum. Each budget is run again with `--tile SIZE TILE_ROWS` (bands
of rows: the budget then counts bands, not frames).

Posters (`--poster N`, Gerris plume): an N/2-square frame in memory and in
tiles, and an N-square one in tiles under a budget, each against the same
command on the 64-cell dataset.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.bench_render import ensure_scene

ROOT = benchdoc.ROOT
SECTION = "Rendering under a memory budget"
FRACTIONS = (2, 4, 8, 16)
# Rows of a tile of the tiled runs, and the poster's tiles.
TILE_ROWS = 32
POSTER_TILE = (4096, 64)
TABLE_HEAD = ("| dataset | budget | budget bytes | files | domains | command s | peak | "
              "above baseline | RMSE |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n")


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


def bench_dataset(name: str, d: Path, field: str, size: int, tmp: Path,
                  runs=None) -> list[str]:
    """Table rows: the in-memory render, then each (fraction k, extra flags) of `runs`
    (default: every FRACTIONS, whole frames and bands of TILE_ROWS rows) under a
    budget of 1/k of the files."""
    from exabricks.image_io import read_image

    eb = benchdoc.exabricks_command()
    files = [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    nbytes = sum(f.stat().st_size for f in files)
    flags = ["--field", field, "--size", size, size, "--max-opacity", 1]

    warm = set()

    def run(paths, out, *extra):
        if paths[0] not in warm:  # PoCL's kernel cache: one run of each dataset
            benchdoc.run_child([*eb, "render", *paths, "-o", out, *flags, *extra])
            warm.add(paths[0])
        return benchdoc.run_child([*eb, "render", *paths, "-o", out, *flags, *extra])

    tiny = tiny_scene(tmp, field)
    wall, _, peak = run(files, tmp / "whole.exr")
    whole, _ = read_image(tmp / "whole.exr")
    rows = [f"| {name} | in memory | | {benchdoc.fmt_bytes(nbytes)} | 1 | {wall:.1f} | "
            f"{benchdoc.fmt_bytes(peak)} | | |"]
    print(rows[-1], flush=True)
    if runs is None:
        runs = [(k, tiles) for k in FRACTIONS for tiles in ((), ("--tile", size, TILE_ROWS))]
    for k, tiles in runs:
        budget = nbytes // k
        extra = ("--memory-budget", budget, *tiles)
        label = f"1/{k} of the files" + (f", `{' '.join(map(str, tiles))}`" if tiles else "")
        _, _, base = run(tiny, tmp / "tiny.exr", *extra)
        try:
            wall, _, peak = run(files, tmp / f"b{k}.exr", *extra)
        except SystemExit as e:  # refused: its one error line
            reason = str(e).split("error: ", 1)[-1].strip()
            rows.append(f"| {name} | {label} | {benchdoc.fmt_bytes(budget)} | "
                        f"{benchdoc.fmt_bytes(nbytes)} | refused: {reason} | | | | |")
            print(rows[-1], flush=True)
            continue
        image, meta = read_image(tmp / f"b{k}.exr")
        rmse = float(np.sqrt(np.mean((image.astype(np.float64) - whole) ** 2))
                     / np.abs(whole).max())
        over = peak - base
        rows.append(f"| {name} | {label} | {benchdoc.fmt_bytes(budget)} | "
                    f"{benchdoc.fmt_bytes(nbytes)} | {meta['settings']['pieces']} | "
                    f"{wall:.1f} | {benchdoc.fmt_bytes(peak)} | {benchdoc.fmt_bytes(over)} "
                    f"({over / budget:.2f} of the budget) | {rmse:.1e} |")
        print(rows[-1], flush=True)
    return rows


def bench_poster(size: int, tmp: Path) -> list[str]:
    """Rows of the poster table: (frame, how, command s, peak, baseline, above it)."""
    from exabricks.image_io import read_image

    eb = benchdoc.exabricks_command()
    gerris = benchdoc.datasets()["gerris"]
    files = ensure_scene(ROOT / "bench-data" / "render", gerris)
    files = [files / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    tiny = tiny_scene(tmp, gerris.field)
    tile = ("--tile", *POSTER_TILE)
    budget = 256 << 20
    runs = [(size // 2, "in memory", ()), (size // 2, "tiles", tile),
            (size, f"tiles, `--memory-budget {budget >> 20}MiB`", (*tile, "--memory-budget", budget))]
    rows, reference = [], None
    for n, how, extra in runs:
        flags = ["--field", gerris.field, "--size", n, n, "--max-opacity", 1, *extra]
        _, _, base = benchdoc.run_child([*eb, "render", *tiny, "-o", tmp / "tiny.png", *flags])
        wall, _, peak = benchdoc.run_child([*eb, "render", *files, "-o", tmp / "p.png", *flags])
        same = ""
        if n == size // 2:  # the first two: the same frame in memory and in tiles
            image = read_image(tmp / "p.png")[0]
            if reference is None:
                reference = image
            else:
                same = "the same pixels" if np.array_equal(image, reference) else "DIFFERENT"
            del image
        rows.append(f"| {n}² | {how} | {benchdoc.fmt_bytes(n * n * 16)} | {wall:.1f} | "
                    f"{benchdoc.fmt_bytes(peak)} | {benchdoc.fmt_bytes(base)} | "
                    f"{benchdoc.fmt_bytes(peak - base)} | {same} |")
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="datasets (benchdoc keys; default shell)")
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--work", type=Path, default=ROOT / "bench-data" / "render")
    parser.add_argument("--poster", type=int, default=16384,
                        help="poster side (0: no poster table)")
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen([args.only], list(sets)) if args.only else ["shell"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for key in keys:
            d = ensure_scene(args.work, sets[key])
            rows += bench_dataset(sets[key].name, d, sets[key].field, args.size, Path(tmp))
        posters = bench_poster(args.poster, Path(tmp)) if args.poster else []
    command = (f"`.venv/bin/python -m benchmarks.bench_budget --only {','.join(keys)} "
               f"--poster {args.poster} --write-docs`")
    section = (
        f"Command: {command}\n\n- machine: {benchdoc.machine(opencl=True)}\n"
        f"- one {args.size}² frame, default camera and transfer function, `--max-opacity 1`; "
        "whole `exabricks render` commands (the first of each dataset run twice, the second "
        "measured, so that PoCL's kernel cache is warm for all); files: the bytes of the bricks, regions and bvh files; "
        "peak: the command's peak resident memory; above baseline: the peak less that of the "
        "same budgeted command on a 64-cell dataset (the issue's bound is the budget); "
        "RMSE: against the in-memory image, over its maximum\n\n"
        + TABLE_HEAD + "\n".join(rows) + "\n")
    if posters:
        section += (
            f"\nPosters: the Gerris plume (field T, `--max-opacity 1`), PNG; `--tile "
            f"{POSTER_TILE[0]} {POSTER_TILE[1]}`; float frame: the bytes of the whole frame's "
            "float RGBA; baseline: the same command on the 64-cell dataset (one run each, the "
            "kernels already in PoCL's cache)\n\n"
            "| frame | how | float frame | command s | peak | baseline | above baseline | "
            "against in memory |\n|---|---|---:|---:|---:|---:|---:|---|\n"
            + "\n".join(posters) + "\n")
    benchdoc.publish(SECTION, section, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
