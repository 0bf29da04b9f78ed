"""Leaf cells of anything yt loads (Enzo, FLASH, Chombo, GAMER, …), through yt.

yt is an optional dependency (`pip install 'exabricks[yt]'`), imported only here.
The leaves are the cells of `ds.all_data()`; each one's centre and width
(("index", "x"/"dx") etc., in code_length) give its lower corner, which is turned
into lattice units relative to the domain's left edge and the finest cell width.
Fields are read raw on the dataset's own fluid type (e.g. ("enzo", "Density")), so
their values are the file's, in code units.

The other way, `to_amr_grids` turns leaf cells into the nested grids of
yt.load_amr_grids (yt is not imported for it).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..errors import ExabricksError
from . import _checks

# yt's derived and generic fluid types; the rest of ds.fluid_types are on-disk types.
_GENERIC_TYPES = {"gas", "deposit", "index", "all", "nbody"}


def read(path: Path, *, fields: Sequence[str] | None = None) -> schema.Cells:
    """Leaf cells of a dataset yt can load, fields as float32 in the file's code units.

    Returns Cells with lower_lattice int32 (N, 3) in finest-cell units, level int8 (N,)
    (0 = the finest width present), values float32 (F, N), origin_world = the domain
    left edge and spacing_world = the finest cell width, both in code_length.
    """
    path = Path(path)
    yt = _import_yt()
    if not path.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    with _quiet_yt():
        try:
            ds = yt.load(str(path))
        except Exception as e:  # yt raises many types (YTUnidentifiedDataType, OSError, …)
            raise ExabricksError(f"{path}: yt cannot load it ({type(e).__name__}: {e})") from e
        try:
            return _read(ds, path, fields)
        except ExabricksError:
            raise
        except Exception as e:  # damaged grid files surface while yt reads the data
            raise ExabricksError(f"{path}: yt failed to read the data ({type(e).__name__}: {e})") from e


def _import_yt():
    try:
        import yt
    except ImportError:
        raise ExabricksError("yt is not installed: pip install 'exabricks[yt]'") from None
    return yt


@contextlib.contextmanager
def _quiet_yt():
    """Silence yt's log and progress bars while reading, then restore its settings."""
    from yt.config import ytcfg
    from yt.utilities.logger import ytLogger

    level = ytLogger.level
    suppress = ytcfg.get("yt", "suppress_stream_logging")
    ytLogger.setLevel(40)
    ytcfg.set("yt", "suppress_stream_logging", True)
    try:
        yield
    finally:
        ytLogger.setLevel(level)
        ytcfg.set("yt", "suppress_stream_logging", suppress)


def native_fields(ds) -> list[tuple[str, str]]:
    """The on-disk mesh fields of the dataset's own fluid type(s), in field_list order."""
    particle = set(getattr(ds, "particle_types", ()))
    native = [t for t in ds.fluid_types if t not in _GENERIC_TYPES and t not in particle]
    return [(t, n) for t, n in ds.field_list if t in native]


def _read(ds, path: Path, fields: Sequence[str] | None) -> schema.Cells:
    if ds.dimensionality != 3:
        raise ExabricksError(f"{path}: a {ds.dimensionality}D dataset; exabricks reads 3D data only")
    if str(getattr(ds, "geometry", "cartesian")).split(".")[-1].lower() != "cartesian":
        raise ExabricksError(f"{path}: {ds.geometry} geometry; only Cartesian data is supported")
    available = native_fields(ds)
    by_name = {}
    for ftype, name in available:
        by_name.setdefault(name, (ftype, name))
    if fields is None:
        chosen = list(by_name.values())
    else:
        missing = [f for f in fields if f not in by_name]
        if missing:
            raise ExabricksError(
                f"{path}: no field {missing[0]!r} on disk (fields: {', '.join(by_name) or 'none'})"
            )
        if len(set(fields)) != len(fields):
            raise ExabricksError(f"{path}: field listed twice in {list(fields)}")
        chosen = [by_name[f] for f in fields]
    if not chosen:
        raise ExabricksError(f"{path}: yt finds no on-disk mesh fields")

    ad = ds.all_data()
    left = ds.domain_left_edge.to("code_length").d.astype(np.float64)
    centre = np.stack([ad["index", a].to("code_length").d for a in "xyz"], axis=1)
    size = np.stack([ad["index", "d" + a].to("code_length").d for a in "xyz"], axis=1)
    if centre.shape[0] == 0:
        raise ExabricksError(f"{path}: the dataset has no cells")
    fine = size.min(axis=0)                                                  # (3,)
    _checks.check_cell_size(path, fine, "finest cell width")
    ratio = size / fine                                                      # (N, 3)
    width = np.rint(ratio).astype(np.int64)
    if np.any(np.abs(ratio - width) > 1e-6 * width) or np.any(width & (width - 1)) \
            or np.any(width != width[:, :1]):
        i = int(np.flatnonzero(np.any(np.abs(ratio - width) > 1e-6 * width, axis=1)
                               | np.any(width & (width - 1), axis=1)
                               | np.any(width != width[:, :1], axis=1))[0])
        raise ExabricksError(
            f"{path}: cell {i} has widths {size[i].tolist()}, not the same power of two times "
            f"the finest widths {fine.tolist()} on every axis"
        )
    width = width[:, 0]
    level = np.log2(width).astype(np.int64)
    if level.max() > MAX_LEVEL:
        raise ExabricksError(f"{path}: more than {MAX_LEVEL + 1} levels of cell widths")
    lower = (centre - 0.5 * size - left) / fine                             # (N, 3) lattice
    lattice = np.rint(lower).astype(np.int64)
    # yt computes centres as left + (i + 1/2) dx in float64: far below 1e-3 finest cells.
    off = np.abs(lower - lattice) > 1e-3
    misaligned = np.any(lattice % width[:, None], axis=1)
    if np.any(off) or np.any(misaligned) or np.any(lattice < 0) or lattice.max() >= 2**31:
        i = int(np.flatnonzero(np.any(off, axis=1) | misaligned | np.any(lattice < 0, axis=1)
                               | np.any(lattice >= 2**31, axis=1))[0])
        raise ExabricksError(
            f"{path}: cell {i} at {(centre[i] - 0.5 * size[i]).tolist()} does not sit on the "
            f"lattice of its width {int(width[i])} x the finest width {fine.tolist()}"
        )
    _checks.check_frame(path, left, fine, lattice.max(axis=0) + width.max())
    values = np.empty((len(chosen), centre.shape[0]), dtype=VALUE_DTYPE)
    for i, key in enumerate(chosen):
        with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond float32: inf
            values[i] = np.asarray(ad[key].d)
    return schema.Cells(
        fields=tuple(name for _, name in chosen),
        origin_world=left.astype(WORLD_DTYPE),
        spacing_world=fine.astype(WORLD_DTYPE),
        meta={"source": {"format": "yt", "frontend": type(ds).__name__,
                         "time": float(ds.current_time.d)}},
        lower_lattice=lattice.astype(LATTICE_DTYPE),
        level=level.astype(LEVEL_DTYPE),
        values=values,
    )


def to_amr_grids(cells: schema.Cells, *, source: str = "cells",
                 fill: float | None = None) -> tuple[list[dict], int]:
    """Leaf cells (their first field) as properly nested grids for yt.load_amr_grids.

    yt needs every level to cover what the finer levels refine, grids aligned to
    their parent level's cells and each grid inside one parent grid. Level l's
    "covering" cells are its leaves plus the parents of level l-1's covering
    cells (value: the mean of their children; yt only shows leaves); the
    coarsest level is cut into bricks (exabricks.stages.brick) of its cells,
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
    """Bricks (exabricks.stages.brick) of same-level cells `units` (N, 3) int64 that never
    mix two values of `group` (N,): yields (lower (B, 3) int64, dims (B, 3) int64) batches.

    Groups are moved apart along x by a multiple of the cell width before one
    build_bricks call (a brick must be filled, so it cannot bridge the gap), and
    moved back; one call per group where the shifted lattice would leave int32.
    """
    from ..stages.brick import build_bricks

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
