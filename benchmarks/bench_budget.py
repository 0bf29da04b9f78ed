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
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions

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


LAYOUTS_SECTION = "The memory budget on every layout"
LAYOUT_NOTES = """
What did not scale with the budget (issue 38), found on the octree-like layout at
small budgets, where the peak above the baseline was 11.6 MiB at 6, 12 and 24 MiB
alike (the same probe on this machine before the changes; 6.0 and 8.0 MiB on the
shells at 6 and 12 MiB):

- *Per-region and per-node arrays read whole.* Loading for a budget maps the
  large arrays of the three files, but read every array under 1 MiB (5.6 MB of
  them on the octree layout: region list starts, value ranges, levels and the BVH's
  arrays, which a budgeted frame does not use). Arrays from 64 KiB up are now
  mapped (`NpzArchive.MAP_BYTES`).
- *Steps of 1 M elements.* A pass over a mapped array in steps of 2^20 elements
  held its 4 MiB of pages and temporaries a few times that (`field_range`, the
  default transfer function's range, peaked 11 MB above the baseline); the steps
  are 2^18 elements now (`schema.CHUNK`), and the scans of the region bounds 2^14
  regions (`partition.SCAN`) instead of 2^18.
- *Page-cache folios.* On Linux 6.16 and later, ext4 caches files in folios of up
  to 2 MiB, and a read fault maps the whole folio: reading one float of a mapped
  file raised the resident memory by 2.0 MiB (measured in /proc/self/smaps:
  Rss 2048 kB, PTE-mapped, with MADV_RANDOM and MADV_NOHUGEPAGE alike). The copy
  of a domain's brick values from the mapped file, 1024 bricks a step, brought in
  up to a folio per brick. It now goes in steps of at most a quarter of a
  domain's share, each brick counted as a folio (`partition.GRAIN`, `_copy_parts`),
  and the plan keeps one folio (or the values' bytes, if fewer) for these reads
  besides the images and indices. Small budgets therefore make more, smaller
  domains than before (the octree layout at 6 MiB: 83 domains instead of 45).
"""
LAYOUT_BUDGETS = (8, 16, 32)  # MiB


def make_layouts(d: Path) -> dict[str, tuple[list[Path], str]]:
    """{name: (bricks, regions and bvh files, field)} of make_big.py's layouts at
    test size, built into `d`: octree-like (a smooth volume merged to coarse cells
    where it is smooth: 3.0 M cells in 22 K bricks), block-structured (such a
    volume as an AMReX plotfile: 1.4 M cells in 51 bricks) and thin shells (1.1 M
    cells in 60 K bricks of 19 cells). tests/engine/test_streaming.py draws budgets over
    them."""
    from benchmarks import make_big
    from exabricks import schema
    from exabricks.stages.ingest import ingest
    from exabricks.structures import build

    make_big.generate(d / "octree.raw", 192, 7)
    make_big.generate(d / "blocks.raw", 128, 7)
    make_big.write_amrex(np.fromfile(d / "blocks.raw", "<f4").reshape(128, 128, 128), d / "plt")
    cells = {"octree": ingest(d / "octree.raw", format="raw", dims=(192, 192, 192), dtype="float32",
                              max_level=make_big.MAX_LEVEL, threshold=make_big.THRESHOLD),
             "blocks": ingest(d / "plt"), "shells": make_big.thin_shell_cells(256)}
    out = {}
    for name, c in cells.items():
        files = [d / f"{name}_{k}.npz" for k in ("bricks", "regions", "bvh")]
        for path, obj in zip(files, build(c)):
            schema.save(path, obj)
        out[name] = (files, c.fields[0])
    return out


def bench_layouts(tmp: Path, size: int) -> list[str]:
    """Rows: each layout of `make_layouts` under each of LAYOUT_BUDGETS, against the
    same budgeted command on the 64-cell dataset."""
    from exabricks.film.image_io import read_image

    eb = benchdoc.exabricks_command()
    rows = []
    for name, (files, field) in make_layouts(tmp).items():
        tiny = tiny_scene(tmp, field)
        nbytes = sum(f.stat().st_size for f in files)
        for mib in LAYOUT_BUDGETS:
            flags = ["--field", field, "--size", size, size, "--max-opacity", 1,
                     "--memory-budget", f"{mib}MiB"]
            benchdoc.run_child([*eb, "render", *files, "-o", tmp / "l.exr", *flags])  # warm
            _, _, base = benchdoc.run_child([*eb, "render", *tiny, "-o", tmp / "t.exr", *flags])
            wall, _, peak = benchdoc.run_child([*eb, "render", *files, "-o", tmp / "l.exr", *flags])
            pieces = read_image(tmp / "l.exr")[1]["settings"]["pieces"]
            over = peak - base
            rows.append(f"| {name} | {benchdoc.fmt_bytes(nbytes)} | {mib} MiB | {pieces} | "
                        f"{wall:.1f} | {benchdoc.fmt_bytes(peak)} | {benchdoc.fmt_bytes(base)} | "
                        f"{benchdoc.fmt_bytes(over)} ({over / (mib << 20):.2f} of the budget) |")
            print(rows[-1], flush=True)
    return rows


def bench_dataset(name: str, d: Path, field: str, size: int, tmp: Path,
                  runs=None) -> list[str]:
    """Table rows: the in-memory render, then each (fraction k, extra flags) of `runs`
    (default: every FRACTIONS, whole frames and bands of TILE_ROWS rows) under a
    budget of 1/k of the files."""
    from exabricks.film.image_io import read_image

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
        try:
            wall, _, peak = run(files, tmp / f"b{k}.exr", *extra)
        except SystemExit as e:  # refused: its one error line
            reason = str(e).split("error: ", 1)[-1].strip()
            rows.append(f"| {name} | {label} | {benchdoc.fmt_bytes(budget)} | "
                        f"{benchdoc.fmt_bytes(nbytes)} | refused: {reason} | | | | |")
            print(rows[-1], flush=True)
            continue
        try:  # the 64-cell baseline is refused where the images alone pass the budget
            _, _, base = run(tiny, tmp / "tiny.exr", *extra)
        except SystemExit:
            base = None
        image, meta = read_image(tmp / f"b{k}.exr")
        rmse = float(np.sqrt(np.mean((image.astype(np.float64) - whole) ** 2))
                     / np.abs(whole).max())
        above = ("its baseline refused" if base is None else
                 f"{benchdoc.fmt_bytes(peak - base)} ({(peak - base) / budget:.2f} of the budget)")
        rows.append(f"| {name} | {label} | {benchdoc.fmt_bytes(budget)} | "
                    f"{benchdoc.fmt_bytes(nbytes)} | {meta['settings']['pieces']} | "
                    f"{wall:.1f} | {benchdoc.fmt_bytes(peak)} | {above} | {rmse:.1e} |")
        print(rows[-1], flush=True)
    return rows


def bench_poster(size: int, tmp: Path) -> list[str]:
    """Rows of the poster table: (frame, how, command s, peak, baseline, above it)."""
    from exabricks.film.image_io import read_image

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
    parser.add_argument("--layouts", action="store_true",
                        help="instead: make_big.py's layouts at test size under budgets of "
                        f"{', '.join(map(str, LAYOUT_BUDGETS))} MiB (section \"{LAYOUTS_SECTION}\")")
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    if args.layouts:
        with tempfile.TemporaryDirectory() as tmp:
            rows = bench_layouts(Path(tmp), args.size)
        section = (
            f"Command: `.venv/bin/python -m benchmarks.bench_budget --layouts --size {args.size} "
            f"--write-docs`\n\n- machine: {benchdoc.machine(opencl=True)}\n"
            f"- one {args.size}² frame of each layout of `make_layouts` (tests/engine/test_streaming.py "
            "draws budgets over the same ones), default camera and transfer function, "
            "`--max-opacity 1`; whole commands, each run once before it is measured; baseline: "
            "the same budgeted command on a 64-cell dataset\n\n"
            "| layout | files | budget | domains | command s | peak | baseline | above baseline |\n"
            "|---|---:|---:|---:|---:|---:|---:|---:|\n" + "\n".join(rows) + "\n" + LAYOUT_NOTES)
        benchdoc.publish(LAYOUTS_SECTION, section, args.write_docs)
        return 0
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
