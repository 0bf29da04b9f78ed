"""Write a small synthetic AMReX time series: plotfiles plt00000, plt00010, ... in OUTDIR.

    .venv/bin/python workflows/make_series.py OUTDIR [--steps 8] [--size 32] [--max-level 2]
        [--fixed-hierarchy]

The input of the time-series pipelines: the Make pipeline that turns every plotfile
of a series into cells, bricks, regions, bvh and a frame (then `exabricks movie`),
and the SLURM array job whose task N preprocesses plotfile N. Small enough to run
in seconds on a laptop or in CI, and shaped like a real run:

- one field `phi`: a Gaussian blob (sigma 0.08) that travels once around a circle
  of radius 0.25 in the plane z = 0.5 over the series, so each frame differs and
  the last one leads back to the first; values in [0, 1] (`render --range 0 1`);
- a SIZE^3 base grid on [0, 1]^3 and MAX_LEVEL finer levels of refinement ratio 2
  that follow the blob: level 1 covers the blob +- 0.25 (about 3 sigma), level 2
  +- 0.125 (with --fixed-hierarchy, where the blob is in the first plotfile, so
  that every plotfile has the same leaf cells), each SIZE^3 cells in boxes of at most SIZE/2 per side, aligned to
  8 cells (AMReX's blocking factor) and properly nested (at least 8 cells of the
  level below around each box where the domain allows);
- step numbers 0, 10, 20, ... (`plt%05d`, as AMReX names them), time = step / 100;
- double precision, written by benchmarks/amrex_plotfile.py as AMReX writes it:
  3 x SIZE^3 x 8 bytes per plotfile (786 KB at SIZE 32).

Each plotfile is written under a temporary name in OUTDIR and renamed into place, so
an interrupted run leaves no half plotfile that `make` would take as up to date; an
existing plotfile of the same name is replaced.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from benchmarks.amrex_plotfile import write_plotfile

ROOT = Path(__file__).resolve().parents[1]


SIGMA = 0.08      # blob width, world units
ORBIT = 0.25      # radius of the blob's circle around the domain's centre
BLOCKING = 8      # box corners on multiples of 8 cells (AMReX blocking_factor)
STRIDE = 10       # step numbers between plotfiles
DT = 0.01         # simulated time per step


def centre(k: int, steps: int) -> np.ndarray:
    """The blob's centre in plotfile k of `steps` (one full circle over the series)."""
    angle = 2.0 * math.pi * k / steps
    return np.array([0.5 + ORBIT * math.cos(angle), 0.5 + ORBIT * math.sin(angle), 0.5])


def phi(x, y, z, c) -> np.ndarray:
    """The field at world points (broadcasting arrays): the blob, in [0, 1]."""
    r2 = (x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2
    return np.exp(-r2 / (2.0 * SIGMA ** 2))


def split(lo, width: int, piece: int) -> list[tuple[tuple, tuple]]:
    """The cube of `width` cells at index `lo` as (lo, hi) inclusive boxes of `piece`^3."""
    starts = [range(lo[a], lo[a] + width, piece) for a in range(3)]
    return [((i, j, k), (i + piece - 1, j + piece - 1, k + piece - 1))
            for k in starts[2] for j in starts[1] for i in starts[0]]


def hierarchy(c, size: int, max_level: int) -> list[list[tuple[tuple, tuple]]]:
    """Boxes per level: the whole base grid, then a size^3 cube per finer level
    centred on the blob `c`, clipped to the domain and nested in the level below."""
    piece = size // 2
    levels = [split((0, 0, 0), size, piece)]
    below_lo, below_hi, below_n = np.zeros(3, int), np.full(3, size), size  # [lo, hi) cells
    for _ in range(1, max_level + 1):
        n, width = 2 * below_n, size
        ideal = np.rint((c * n - width / 2) / BLOCKING).astype(int) * BLOCKING
        # Inside the level below's cube (refined), BLOCKING cells in from each of its
        # faces that is not on the domain's boundary (proper nesting).
        lo_min = 2 * below_lo + np.where(below_lo > 0, BLOCKING, 0)
        hi_max = 2 * below_hi - np.where(below_hi < below_n, BLOCKING, 0)
        lo = np.clip(ideal, lo_min, hi_max - width)
        levels.append(split(tuple(int(v) for v in lo), width, piece))
        below_lo, below_hi, below_n = lo, lo + width, n
    return levels


def write_step(outdir: Path, k: int, steps: int, size: int, max_level: int,
               fixed: bool = False) -> Path:
    """Write plotfile k of the series into `outdir`; returns its path. `fixed`: the
    refinement stays where it is in plotfile 0 while the blob moves on."""
    step = k * STRIDE
    c = centre(k, steps)
    boxes = hierarchy(centre(0, steps) if fixed else c, size, max_level)

    def data(level, glo, ghi):
        dx = 1.0 / (size * 2 ** level)
        x, y, z = ((np.arange(glo[a], ghi[a] + 1) + 0.5) * dx for a in range(3))
        values = phi(x[None, None, :], y[None, :, None], z[:, None, None], c)
        return values[None]  # (1 field, nz, ny, nx)

    final = outdir / f"plt{step:05d}"
    tmp = outdir / f".plt{step:05d}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    write_plotfile(tmp, boxes, [2] * max_level, ["phi"], data, real="<f8", base=size, keep=False)
    _set_time(tmp / "Header", step * DT, boxes)
    if final.exists():
        if not (final / "Header").is_file():
            shutil.rmtree(tmp)
            raise SystemExit(f"error: {final} exists and is not a plotfile; not replacing it")
        shutil.rmtree(final)
    tmp.rename(final)
    return final


def _set_time(header: Path, t: float, boxes) -> None:
    """The writer puts the time 1.5 in the Header (after the dimension line, and on
    each level's `LEVEL NBOXES TIME` line): put this plotfile's time there."""
    lines = header.read_text().split("\n")
    at = 3 + int(lines[1])  # version, field count, the names, dimension, then the time
    assert lines[at] == "1.5", lines[at]
    lines[at] = repr(float(t))
    for level, level_boxes in enumerate(boxes):
        i = lines.index(f"{level} {len(level_boxes)} 1.5", at)
        lines[i] = f"{level} {len(level_boxes)} {float(t)!r}"
    header.write_text("\n".join(lines))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("outdir", type=Path, help="directory of the plotfiles (created if missing)")
    p.add_argument("--steps", type=int, default=8, help="number of plotfiles (default 8)")
    p.add_argument("--size", type=int, default=32,
                   help="base grid cells per side, a multiple of 16 (default 32)")
    p.add_argument("--max-level", type=int, default=2, choices=range(0, 5),
                   help="levels of refinement above the base grid (default 2)")
    p.add_argument("--fixed-hierarchy", action="store_true",
                   help="keep the refinement of the first plotfile in every plotfile (the leaf "
                        "cells stay the same, as in many CFD runs; docs/time-series.md)")
    args = p.parse_args(argv)
    if args.steps < 1:
        p.error("--steps must be at least 1")
    if args.size < 16 or args.size % 16:
        p.error("--size must be a positive multiple of 16")
    args.outdir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    for k in range(args.steps):
        path = write_step(args.outdir, k, args.steps, args.size, args.max_level,
                          args.fixed_hierarchy)
        print(path)
    print(f"{args.steps} plotfiles in {time.perf_counter() - start:.2f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
