"""Write a smooth multi-scale raw volume for scale tests and print the command that ingests it.

    .venv/bin/python -m benchmarks.make_big [--size 512] [--out bench-data/big512.raw] [--check]
    .venv/bin/python -m benchmarks.make_big --amrex [--check]   # also bench-data/plt_big512
    .venv/bin/python -m benchmarks.make_big --thin-shell [--size 1024]   # bench-data/shell1024.cells
    .venv/bin/python -m benchmarks.make_big --thin-shell --size 2944     # 204 M cells

The field is a sum of separable terms (Gaussian blobs of widths from 1/4 to 1/100
of the domain, and a few sinusoids): one big smooth blob where 2x2x2 groups merge
to coarse cells, medium blobs, and small sharp features that stay at the finest
level.  Each term is a product g_x(x) g_y(y) g_z(z), so a z-slab of the volume is
one matrix product (slab terms x plane terms) -- a 512^3 volume takes seconds.
Values are float32, x fastest, little-endian, origin 0, spacing 1.

With --amrex the 512^3 volume also becomes a block-structured AMReX plotfile (see
`amrex_hierarchy`): 3 levels, refinement ratio 2, 32^3 boxes (AMReX's
max_grid_size), properly nested, 23.3 M leaf cells, written by
benchmarks/amrex_plotfile.py in double precision as AMReX does by default.

With --thin-shell it writes instead octree-like leaf cells directly, in ExaJet form
(bench-data/shellSIZE.cells and shellSIZE.rho.scalars; see `thin_shell_cells`): the
layout of tree codes and thin refinement (Gerris, RAMSES, ExaJet), where
refinement is a cell or two thick around a few spherical fronts, with a spherical
hole.  At --size 1024 it has 20.6 M cells on 4 levels, at 2944 204 M (in 2.6 min);
the cell count scales with size**2 (the fronts' area) plus (size / 8)**3 (the
coarse grid).  It is made and written a slab of coarse cells at a time, so any
size takes about 1.5 GB of memory.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# Threshold and coarsest level for the printed ingest command: with them the 512^3
# volume becomes 23.6 M cells over 6 levels (checked with --check; numbers in
# docs/benchmarks.md).
THRESHOLD = 0.005
MAX_LEVEL = 5

# AMReX form of the 512^3 volume: a 32^3-voxel block is a level-2 box when max - min
# of its voxels exceeds AMREX_T2; a 64^3-voxel block is a level-1 box when its max - min
# exceeds AMREX_T1 or proper nesting needs it.  With these, 316 level-1 and 423
# level-2 boxes: 802,816 + 8,622,080 + 13,860,864 = 23,285,760 leaves (levels 0, 1, 2).
AMREX_T1 = 0.1
AMREX_T2 = 0.18
AMREX_BOX = 32


def terms(seed: int) -> list[tuple[float, tuple, tuple]]:
    """(amplitude, (kind, params) per axis) of every separable term, in unit coordinates."""
    rng = np.random.default_rng(seed)
    out = []
    # Gaussian blobs at decreasing scales: (count, sigma, amplitude)
    for count, sigma, amp in ((1, 0.25, 1.0), (4, 0.08, 0.5), (12, 0.03, 0.3), (40, 0.01, 0.2)):
        for _ in range(count):
            centre = rng.uniform(0.15, 0.85, 3)
            s = sigma * rng.uniform(0.7, 1.3)
            out.append((amp * rng.uniform(0.5, 1.0), tuple(("gauss", c, s) for c in centre)))
    # Low-amplitude waves, so that no large region is exactly constant.
    for k in (2, 5):
        phase = rng.uniform(0, 2 * np.pi, 3)
        out.append((0.02, tuple(("sin", k, p) for p in phase)))
    return out


def axis_values(spec: tuple, n: int) -> np.ndarray:
    """One factor of a term on the n voxel centres of an axis, float64 (n,)."""
    x = (np.arange(n) + 0.5) / n
    kind, a, b = spec
    if kind == "gauss":
        return np.exp(-0.5 * ((x - a) / b) ** 2)
    return 0.5 + 0.5 * np.sin(2 * np.pi * a * x + b)


def generate(path: Path, size: int, seed: int, slab: int = 16) -> None:
    """Write the size^3 float32 volume to `path`, slab by slab along z."""
    spec = terms(seed)
    amp = np.array([a for a, _ in spec])
    gx = np.stack([axis_values(s[0], size) for _, s in spec])  # (T, X)
    gy = np.stack([axis_values(s[1], size) for _, s in spec])  # (T, Y)
    gz = np.stack([axis_values(s[2], size) for _, s in spec])  # (T, Z)
    plane = (gy[:, :, None] * gx[:, None, :]).reshape(len(spec), -1)  # (T, Y*X)
    weights = (amp[:, None] * gz).T  # (Z, T)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        for z0 in range(0, size, slab):
            block = (weights[z0:z0 + slab] @ plane).astype("<f4")
            block.tofile(f)
    tmp.replace(path)


def amrex_hierarchy(volume: np.ndarray, t1: float = AMREX_T1, t2: float = AMREX_T2,
                    box: int = AMREX_BOX) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """Boxes (lo, hi) (x, y, z) inclusive of a 3-level, ratio-2 hierarchy over volume (n, n, n).

    Level 2 is the voxel grid, level 1 is it coarsened by 2, level 0 by 4; every box is
    box^3 cells.  Level 0 tiles the domain.  A level-2 box covers a box^3 block of
    voxels whose max - min exceeds t2; a level-1 box covers a (2 box)^3 block of voxels
    whose max - min exceeds t1, or that lies within one level-1 cell of a level-2 box
    (AMReX's proper nesting with n_proper = 1: a level-2 box is never next to level 0).
    Boxes are in z, y, x order of their blocks.
    """
    n = volume.shape[0]
    m = n // box  # level-2 blocks per axis
    blocks = volume.reshape(m, box, m, box, m, box)
    vmax, vmin = blocks.max(axis=(1, 3, 5)), blocks.min(axis=(1, 3, 5))
    fine = vmax - vmin > t2
    coarse = (vmax.reshape(m // 2, 2, m // 2, 2, m // 2, 2).max(axis=(1, 3, 5))
              - vmin.reshape(m // 2, 2, m // 2, 2, m // 2, 2).min(axis=(1, 3, 5))) > t1
    # Nesting: one level-1 cell around a level-2 box reaches into the neighbouring
    # level-2-sized blocks (26-neighbourhood); their level-1 blocks must be refined.
    padded, grown = np.pad(fine, 1), np.zeros_like(fine)
    for dz in range(3):
        for dy in range(3):
            for dx in range(3):
                grown |= padded[dz:dz + m, dy:dy + m, dx:dx + m]
    coarse |= grown.reshape(m // 2, 2, m // 2, 2, m // 2, 2).any(axis=(1, 3, 5))

    def boxes(mask):
        lo = np.argwhere(mask)[:, ::-1] * box  # (x, y, z) corners
        return [(l, l + box - 1) for l in lo]
    return [boxes(np.ones((m // 4,) * 3, bool)), boxes(coarse), boxes(fine)]


def write_amrex(volume: np.ndarray, out: Path, t1: float = AMREX_T1, t2: float = AMREX_T2,
                box: int = AMREX_BOX) -> list[list]:
    """Write `volume` (n, n, n) float32 (z, y, x) as the plotfile directory `out`; its boxes.

    Each box holds the field averaged to its level: level 2 the voxels, level 1 means
    of 2^3 voxels, level 0 means of 4^3 voxels (float64, as AMReX's averageDown).
    """
    from benchmarks import amrex_plotfile

    n = volume.shape[0]
    hierarchy = amrex_hierarchy(volume, t1, t2, box)

    def data(L, lo, hi):
        f = 1 << (2 - L)  # voxels per cell of level L
        v = volume[lo[2] * f:(hi[2] + 1) * f, lo[1] * f:(hi[1] + 1) * f, lo[0] * f:(hi[0] + 1) * f]
        s = (hi - lo + 1)[::-1]
        return v.reshape(s[0], f, s[1], f, s[2], f).mean(axis=(1, 3, 5), dtype=np.float64)[None]

    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    amrex_plotfile.write_plotfile(tmp, hierarchy, [2, 2], ["value"], data, base=n // 4,
                                  prob_hi=(float(n),) * 3, keep=False)
    shutil.rmtree(out, ignore_errors=True)  # a directory cannot be replaced by a rename
    tmp.replace(out)
    return hierarchy


def check_amrex_with_yt(out: Path, volume: np.ndarray, sample: int = 40) -> None:
    """yt reads the plotfile to the same leaves per level as our reader, and the same
    values on `sample` boxes per level (yt's grids, child masks and raw fields); our
    finest leaves hold the voxels of `volume` (n, n, n) (z, y, x)."""
    import yt

    from exabricks.readers import amrex

    yt.set_log_level(40)
    ds = yt.load(str(out))
    ours = amrex.read(out)
    per_level = np.bincount(ours.level, minlength=3)[::-1]  # AMReX level order
    theirs = np.zeros(3, np.int64)
    rng = np.random.default_rng(0)
    grids = list(ds.index.grids)
    for g in grids:
        theirs[g.Level] += int(g.child_mask.sum())
    assert theirs.tolist() == per_level.tolist(), (theirs, per_level)
    # Values: a leaf cell of ours at (lattice, level) equals yt's grid value there;
    # cells are matched by a sort key of (lattice, level) (lattice < 2^11 per axis).
    key = (ours.lower_lattice.astype(np.int64) @ np.array([1, 1 << 11, 1 << 22])) * 4 + ours.level
    order = np.argsort(key)
    checked = 0
    for L in range(3):
        level_grids = [g for g in grids if g.Level == L]
        for g in rng.choice(len(level_grids), min(sample, len(level_grids)), replace=False):
            g = level_grids[g]
            ijk = np.argwhere(g.child_mask)
            width = 1 << (2 - L)
            corner = np.rint(g.LeftEdge.d).astype(np.int64)  # world = finest lattice here
            k = ((corner + ijk * width) @ np.array([1, 1 << 11, 1 << 22])) * 4 + (2 - L)
            at = order[np.searchsorted(key, k, sorter=order)]
            assert np.array_equal(key[at], k)
            np.testing.assert_array_equal(ours.values[0, at],
                                          g["boxlib", "value"].d[g.child_mask].astype(np.float32))
            checked += k.size
    fine = ours.level == 0
    x, y, z = ours.lower_lattice[fine].T
    np.testing.assert_array_equal(ours.values[0, fine], volume[z, y, x])
    print(f"yt: leaves per AMReX level {theirs.tolist()} as ours; values equal on "
          f"{checked:,} leaves of {3 * sample} sampled boxes", file=sys.stderr)


# Thin-shell layout: coarsest level, spherical fronts (centre and radius in units of
# the domain), the hole, and how far from a front (in cell widths of the level) a
# cell is refined.  Values: a narrow Gaussian ridge on every front over a smooth
# background.
SHELL_LEVELS = 4
SHELL_FRONTS = ((0.36, 0.40, 0.42, 0.22), (0.62, 0.58, 0.55, 0.28), (0.50, 0.55, 0.40, 0.16),
                (0.45, 0.42, 0.60, 0.33), (0.30, 0.66, 0.62, 0.29))
SHELL_HOLE = (0.78, 0.25, 0.30, 0.12)
SHELL_BAND = 0.9


def thin_shell_slabs(size: int = 1024, slab_cells: int = 1 << 21):
    """Octree leaf cells of the thin-shell layout, finest lattice `size` per axis,
    a slab of coarsest cells at a time: yields (lower int32 (n, 3), level int8 (n,),
    rho float32 (n,)) for the descendants of about `slab_cells` coarsest cells, so
    that any size is made in bounded memory.

    Level SHELL_LEVELS - 1 covers the domain (size / 8 cells per axis for 4 levels);
    a cell of width w is split into its 8 children while its centre lies within
    SHELL_BAND * w of a front's sphere, down to level 0, so each level's refinement is
    about one or two cells thick.  Cells whose centre lies in the hole sphere are
    dropped at every level.
    """
    top = SHELL_LEVELS - 1
    if size % (1 << top):
        raise SystemExit(f"--size must be a multiple of {1 << top} for the thin-shell layout")
    fronts = np.array(SHELL_FRONTS) * size
    hole = np.array(SHELL_HOLE) * size
    n = size >> top
    octet = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.int32)
    layers = max(1, slab_cells // (n * n))
    for z0 in range(0, n, layers):
        grid = np.stack(np.meshgrid(np.arange(z0, min(n, z0 + layers), dtype=np.int32),
                                    *(np.arange(n, dtype=np.int32),) * 2, indexing="ij"), -1)
        lower = (grid.reshape(-1, 3)[:, ::-1] << top).copy()  # x fastest
        out_lower, out_level = [], []
        for level in range(top, -1, -1):
            w = 1 << level
            centre = lower + 0.5 * w
            lower = lower[np.sum((centre - hole[:3]) ** 2, axis=1) > hole[3] ** 2]
            centre = lower + 0.5 * w
            near = np.zeros(len(lower), bool)
            for cx, cy, cz, r in fronts:
                d = np.sqrt(((centre - (cx, cy, cz)) ** 2).sum(axis=1))
                near |= np.abs(d - r) < SHELL_BAND * w
            if level == 0:
                near[:] = False
            out_lower.append(lower[~near])
            out_level.append(np.full(int((~near).sum()), level, np.int8))
            lower = (lower[near][:, None, :] + octet[None] * (w >> 1)).reshape(-1, 3)
        lower = np.concatenate(out_lower)
        level = np.concatenate(out_level)
        centre = lower + 0.5 * np.left_shift(1, level.astype(np.int32))[:, None]
        rho = 0.05 + 0.03 * np.sin(centre @ np.array([3.0, 5.0, 7.0]) * (2 * np.pi / size))
        for k, (cx, cy, cz, r) in enumerate(fronts):
            d = np.sqrt(((centre - (cx, cy, cz)) ** 2).sum(axis=1))
            rho += (0.5 + 0.15 * k) * np.exp(-(((d - r) / 1.5) ** 2))
        yield lower.astype(np.int32), level, rho.astype(np.float32)


def thin_shell_cells(size: int = 1024):
    """The thin-shell layout (`thin_shell_slabs`) as one exabricks.schema.Cells with
    field "rho" (float32), origin 0 and spacing 1 / size."""
    from exabricks import schema

    lower, level, rho = (np.concatenate(a) for a in zip(*thin_shell_slabs(size)))
    return schema.Cells(
        fields=("rho",), origin_world=np.zeros(3), spacing_world=np.full(3, 1.0 / size),
        lower_lattice=lower, level=level, values=rho[None],
    )


def write_exajet(path: Path, slabs, names) -> int:
    """Leaf cells as ExaJet files: `path` (int32 x, y, z, level per cell) and one
    STEM.NAME.scalars float32 file per name of `names` beside it, written a slab at a
    time from `slabs`, an iterable of (lower (n, 3), level (n,), *values (n,) in the
    order of `names`).  Returns the number of cells."""
    path.parent.mkdir(parents=True, exist_ok=True)
    stem = path.name[: -len(".cells")]
    files = [open(path, "wb")] + [open(path.with_name(f"{stem}.{n}.scalars"), "wb")
                                  for n in names]
    count = 0
    try:
        for lower, level, *values in slabs:
            raw = np.empty((len(level), 4), "<i4")
            raw[:, :3] = lower
            raw[:, 3] = level
            raw.tofile(files[0])
            for f, v in zip(files[1:], values):
                np.asarray(v).astype("<f4").tofile(f)
            count += len(level)
    finally:
        for f in files:
            f.close()
    return count


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=None,
                   help="voxels per axis (default 512; 1024 with --thin-shell)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", type=Path, default=None, help="default bench-data/bigSIZE.raw")
    p.add_argument("--check", action="store_true",
                   help="also run the merge and print cells per level (with --amrex: check "
                   "the plotfile with yt)")
    p.add_argument("--amrex", action="store_true",
                   help="also write the volume as the AMReX plotfile plt_bigSIZE next to it (an "
                   "existing volume at --out is reused, not regenerated)")
    p.add_argument("--thin-shell", action="store_true",
                   help="write the octree-like thin-shell layout as ExaJet files "
                   "bench-data/shellSIZE.cells and shellSIZE.rho.scalars instead (default "
                   "size 1024)")
    args = p.parse_args(argv)
    if args.thin_shell:
        size = args.size or 1024
        out = args.out or ROOT / "bench-data" / f"shell{size}.cells"
        t = time.perf_counter()
        per_level = np.zeros(SHELL_LEVELS, np.int64)

        def counted(slabs):
            for slab in slabs:
                per_level[:] += np.bincount(slab[1], minlength=SHELL_LEVELS)
                yield slab

        count = write_exajet(out, counted(thin_shell_slabs(size)), ["rho"])
        print(f"wrote {out}: {count:,} cells in {time.perf_counter() - t:.1f} s; per "
              "level " + ", ".join(f"{l}: {c:,}" for l, c in enumerate(per_level)),
              file=sys.stderr, flush=True)
        print(f"exabricks ingest {out} -o {out.with_suffix('.npz')}", flush=True)
        return 0
    args.size = args.size or 512
    out = args.out or ROOT / "bench-data" / f"big{args.size}.raw"
    n = args.size
    if not (args.amrex and out.is_file()):  # --amrex reuses an existing volume
        t = time.perf_counter()
        generate(out, args.size, args.seed)
        print(f"wrote {out} ({n}^3 float32) in {time.perf_counter() - t:.1f} s", file=sys.stderr,
              flush=True)
    if args.amrex:
        plt = out.with_name(f"plt_big{n}")
        t = time.perf_counter()
        volume = np.fromfile(out, dtype="<f4").reshape(n, n, n)
        boxes = write_amrex(volume, plt)
        print(f"wrote {plt} ({', '.join(str(len(b)) for b in boxes)} boxes on levels 0, 1, 2) "
              f"in {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
        if args.check:
            check_amrex_with_yt(plt, volume)
        print(f"exabricks ingest {plt} -o {plt.with_suffix('.npz')}", flush=True)
        return 0
    command = (f"exabricks ingest --format raw --dims {n} {n} {n} --dtype float32 "
               f"--max-level {MAX_LEVEL} --threshold {THRESHOLD} {out} -o {out.with_suffix('.npz')}")
    if args.check:
        from exabricks.builders.uniform import amr_from_uniform

        volume = np.fromfile(out, dtype="<f4").reshape(n, n, n)
        t = time.perf_counter()
        _, level, _ = amr_from_uniform(volume, max_level=MAX_LEVEL, threshold=THRESHOLD)
        per_level = np.bincount(level)
        print(f"merge: {level.size:,} cells in {time.perf_counter() - t:.1f} s; per level "
              + ", ".join(f"{l}: {c:,}" for l, c in enumerate(per_level)), file=sys.stderr)
    print(command, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
