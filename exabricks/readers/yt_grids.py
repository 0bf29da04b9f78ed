"""Leaf cells as the properly nested grids of `yt.load_amr_grids` (`to_amr_grids`):
how the yt peer of the benchmarks (benchmarks/peers/yt.py) renders exactly our
leaves, the other way from the reader exabricks.readers.yt_bridge."""

from __future__ import annotations

import numpy as np

from .. import schema
from ..util.errors import ExabricksError


def to_amr_grids(cells: schema.Cells, *, source: str = "cells",
                 fill: float | None = None) -> tuple[list[dict], int]:
    """Leaf cells (their first field) as properly nested grids for yt.load_amr_grids.

    yt needs every level to cover what the finer levels refine, grids aligned to
    their parent level's cells and each grid inside one parent grid. Level l's
    "covering" cells are its leaves plus the parents of level l-1's covering
    cells (value: the mean of their children; yt only shows leaves); the
    coarsest level is cut into bricks (exabricks.builders.bricks) of its cells,
    every finer level into bricks of the refined parent cells, grouped by the
    parent's grid. The data must be octree-complete (every refined cell has all
    8 children, as in Gerris and benchmarks/make_big.py's merge); ExabricksError
    naming `source` otherwise, unless `fill` is given: then every missing child
    and every missing cell of the coarsest level over the cells' bounding box (a
    hole in the data, as in make_big.py's thin shells) is added as a leaf of
    value `fill` (yt has no empty cells; a value outside its transfer function's
    bounds is transparent there, as empty space is in ours).

    Returns (grids, top): one dict per grid with left_edge, right_edge (3,) float64
    world units, level (yt's: 0 = our coarsest level `top`), dimensions (3,) int64
    cells and {field: (float64 (X, Y, Z) values, "")}, and our coarsest level.
    """
    lower = cells.lower_lattice.astype(np.int64)
    level = cells.level.astype(np.int64)
    values = cells.values[0].astype(np.float64)
    top = int(level.max())
    covering = []
    for lev in range(top + 1):
        mine = level == lev
        lo, v = lower[mine], values[mine]
        if lev > 0:
            finer_lo, finer_v = covering[lev - 1]
            parents = (finer_lo >> lev) << lev
            _, first, inverse = np.unique(_cell_keys(parents), return_index=True, return_inverse=True)
            mean = np.bincount(inverse, weights=finer_v) / np.bincount(inverse)
            lo, v = np.vstack([lo, parents[first]]), np.concatenate([v, mean])
        if fill is not None:
            lo, v = _complete(lo, v, lev, top, lower, level, fill)
        covering.append((lo, v))
    origin, spacing = cells.origin_world, cells.spacing_world
    grids = []
    parent_keys = parent_grid = None
    for lev in range(top, -1, -1):
        lo, v = covering[lev]
        width = 1 << lev
        keys = _cell_keys(lo)
        order = np.argsort(keys)
        sorted_keys = keys[order]
        if lev == top:
            units, unit_level, group = lo, lev, np.zeros(len(lo), np.int64)
        else:
            units = np.unique((lo >> (lev + 1)) << (lev + 1), axis=0)
            unit_level = lev + 1
            group = parent_grid[np.searchsorted(parent_keys, _cell_keys(units))]
        ratio = 1 << (unit_level - lev)
        grid_of = np.empty(len(lo), np.int64)
        for brick_lower, brick_dims in _bricks_by_group(units, unit_level, group):
            for corner, unit_dims in zip(brick_lower, brick_dims):
                dims = unit_dims * ratio
                ijk = np.stack(np.meshgrid(*(np.arange(d) for d in dims), indexing="ij"), -1)
                points = corner + width * ijk.reshape(-1, 3)
                found = np.minimum(np.searchsorted(sorted_keys, _cell_keys(points)), len(lo) - 1)
                index = order[found]
                if not np.array_equal(lo[index], points):
                    raise ExabricksError(f"{source}: not octree-complete at level {lev} "
                                         "(a refined cell lacks some of its 8 children)")
                grid_of[index] = len(grids)
                left = origin + spacing * corner
                grids.append({"left_edge": left, "right_edge": left + spacing * dims * width,
                              "level": top - lev, "dimensions": dims,
                              cells.fields[0]: (v[index].reshape(dims), "")})
        parent_keys, parent_grid = sorted_keys, grid_of[order]
    return grids, top


def _complete(lo, v, lev: int, top: int, lower, level, fill: float):
    """Covering cells (lo, v) of level `lev` with the missing ones added, value `fill`:
    below the coarsest level every child of their parents, at it every cell of the
    bounding box of all leaves (lower, level)."""
    w = 1 << lev
    if lev < top:
        parents = np.unique((lo >> (lev + 1)) << (lev + 1), axis=0)
        octet = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.int64)
        want = (parents[:, None, :] + octet[None] * w).reshape(-1, 3)
    else:
        start = (lower.min(axis=0) >> lev) << lev
        end = (lower + (np.int64(1) << level)[:, None]).max(axis=0)
        want = np.stack(np.meshgrid(*(np.arange(a, b, w) for a, b in zip(start, end)),
                                    indexing="ij"), -1).reshape(-1, 3)
    missing = want[~np.isin(_cell_keys(want), _cell_keys(lo))]
    return np.vstack([lo, missing]), np.concatenate([v, np.full(len(missing), float(fill))])


def _cell_keys(lower) -> np.ndarray:
    """One int64 per lattice point (N, 3) (21 bits per axis)."""
    p = np.asarray(lower, np.int64)
    return (p[:, 0] << 42) | (p[:, 1] << 21) | p[:, 2]


def _bricks_by_group(units, level: int, group):
    """Bricks (exabricks.builders.bricks) of same-level cells `units` (N, 3) int64 that never
    mix two values of `group` (N,): yields (lower (B, 3) int64, dims (B, 3) int64) batches.

    Groups are moved apart along x by a multiple of the cell width before one
    build_bricks call (a brick must be filled, so it cannot bridge the gap), and
    moved back; one call per group where the shifted lattice would leave int32.
    """
    from ..builders.bricks import build_bricks

    def bricks_of(lower):
        b = build_bricks(schema.Cells(
            fields=("unit",), origin_world=np.zeros(3), spacing_world=np.ones(3),
            lower_lattice=lower.astype(np.int32), level=np.full(len(lower), level, np.int8),
            values=np.zeros((1, len(lower)), np.float32)))
        return b.lower_lattice.astype(np.int64), b.dims.astype(np.int64)

    width = 1 << level
    base = units.min(axis=0)
    shifted = units - base
    stride = (int(shifted[:, 0].max()) // width + 2) * width
    groups, dense = np.unique(group, return_inverse=True)
    if len(groups) * stride + int(shifted.max()) < np.iinfo(np.int32).max:
        shifted[:, 0] += dense * stride
        lower, dims = bricks_of(shifted)
        lower[:, 0] -= (lower[:, 0] // stride) * stride
        yield lower + base, dims
    else:
        for g in groups:
            yield bricks_of(units[group == g])
