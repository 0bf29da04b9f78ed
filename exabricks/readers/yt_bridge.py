"""Leaf cells of anything yt loads (Enzo, FLASH, Chombo, GAMER, …), through yt.

yt is an optional dependency (`pip install 'exabricks[yt]'`), imported only here.
The leaves are the cells of `ds.all_data()`; each one's centre and width
(("index", "x"/"dx") etc., in code_length) give its lower corner, which is turned
into lattice units relative to the domain's left edge and the finest cell width.

Fields: by default every on-disk mesh field of the dataset's own fluid type (e.g.
("enzo", "Density"), named "Density"), read raw, so their values are the file's, in
code units.  Any field yt can derive is asked for as a (TYPE, NAME) tuple, e.g.
("gas", "vorticity_magnitude"), or as the string "TYPE:NAME"; yt computes it grid by
grid (with ghost zones where it needs neighbours), in yt's default units for that
field (cm/s, 1/s, …).  `cells_from_dataset` takes an already loaded dataset;
`read` loads a path first.  meta["source"]["units"] records each field's units.

The other way, `to_amr_grids` turns leaf cells into the nested grids of
yt.load_amr_grids (yt is not imported for it).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..errors import ExabricksError
from . import _checks

# yt's derived and generic fluid types; the rest of ds.fluid_types are on-disk types.
_GENERIC_TYPES = {"gas", "deposit", "index", "all", "nbody"}

FieldRequest = str | tuple[str, str]
"""A field of `cells_from_dataset`: an on-disk field's name ("Density"), "TYPE:NAME"
("gas:vorticity_magnitude") or (TYPE, NAME) (("gas", "vorticity_magnitude"))."""


def read(path: Path, *, fields: Sequence[FieldRequest] | None = None) -> schema.Cells:
    """Leaf cells of a dataset yt can load, fields as float32 (`cells_from_dataset`)."""
    path = Path(path)
    return cells_from_dataset(load(path), fields, source=str(path))


def load(path: Path):
    """The yt dataset at `path`, loaded quietly; ExabricksError naming `path` if yt cannot."""
    path = Path(path)
    yt = _import_yt()
    if not path.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    with _quiet_yt():
        try:
            return yt.load(str(path))
        except Exception as e:  # yt raises many types (YTUnidentifiedDataType, OSError, …)
            raise ExabricksError(f"{path}: yt cannot load it ({type(e).__name__}: {e})") from e


def cells_from_dataset(ds, fields: Sequence[FieldRequest] | None = None, *,
                       source: str | None = None) -> schema.Cells:
    """Leaf cells of the loaded yt dataset `ds`, fields as float32.

    fields: None for every on-disk field of the dataset's own fluid type, or a list of
            an on-disk field's name, "TYPE:NAME" or (TYPE, NAME) of any field yt knows or
            derives.  A field is named as asked for when asked for by a string, and by
            NAME when asked for by a tuple, or "TYPE:NAME" where two tuples asked for
            share NAME or a string asked for is NAME.
    source: the name in error messages (default: the dataset's file name).
    Returns Cells with lower_lattice int32 (N, 3) in finest-cell units, level int8 (N,)
    (0 = the finest width present), values float32 (F, N) (on-disk fields in code
    units, derived ones in yt's default units, both in meta["source"]["units"]),
    origin_world = the domain left edge and spacing_world = the finest cell width, both
    in code_length.  Raises ExabricksError naming `source`.
    """
    with _reading(ds, source) as source:
        return _read(ds, source, fields)


def field_names(ds, *, also: Iterable[str] = ()) -> list[str]:
    """The names of the dataset's on-disk fields (what `cells_from_dataset` reads by
    default), then those of `also` that name another field yt knows ("TYPE:NAME")."""
    with _reading(ds, None):
        names = list(_on_disk(ds))
        return names + [f for f in dict.fromkeys(also) if f not in names and _derived_key(ds, f)]


@contextlib.contextmanager
def _reading(ds, source: str | None):
    """Quiet yt while the body reads `ds` (its index is built on first use), and turn
    its failures into ExabricksError naming `source` (default: the dataset's file)."""
    source = source or str(getattr(ds, "filename", None) or ds)
    with _quiet_yt():
        try:
            yield source
        except ExabricksError:
            raise
        except Exception as e:  # damaged grid files surface while yt reads the data
            raise ExabricksError(f"{source}: yt failed to read the data ({type(e).__name__}: {e})") from e


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


def _on_disk(ds) -> dict[str, tuple[str, str]]:
    """On-disk field name -> its (TYPE, NAME) key; the first fluid type wins a shared name."""
    by_name: dict[str, tuple[str, str]] = {}
    for key in native_fields(ds):
        by_name.setdefault(key[1], key)
    return by_name


def _derived_key(ds, request) -> tuple[str, str] | None:
    """The (TYPE, NAME) key of a "TYPE:NAME" string or (TYPE, NAME) tuple that yt knows."""
    if isinstance(request, str):
        ftype, sep, name = request.partition(":")
        if not sep:
            return None
        key = (ftype, name)
    elif isinstance(request, tuple) and len(request) == 2 and all(isinstance(p, str) for p in request):
        key = request
    else:
        return None
    return key if key in ds.derived_field_list or key in ds.field_list else None


def _chosen(ds, source: str, fields: Sequence[FieldRequest] | None) -> list[tuple[tuple[str, str], str]]:
    """((TYPE, NAME) key, exabricks field name) of every field to read."""
    by_name = _on_disk(ds)
    if fields is None:
        return [(key, name) for name, key in by_name.items()]
    fields = [tuple(f) if isinstance(f, list) else f for f in fields]
    keys = []
    for f in fields:
        key = by_name.get(f) if isinstance(f, str) else None
        key = key or _derived_key(ds, f)
        if key is None:
            raise ExabricksError(
                f"{source}: no field {f!r} on disk or derived by yt "
                f"(on disk: {', '.join(by_name) or 'none'}; a field yt derives is TYPE:NAME, "
                "e.g. gas:velocity_magnitude)"
            )
        keys.append(key)
    if len(set(keys)) != len(keys):
        raise ExabricksError(f"{source}: field listed twice in {list(fields)}")
    strings = {f for f in fields if isinstance(f, str)}
    short = [k[1] for f, k in zip(fields, keys) if not isinstance(f, str)]
    names = [f if isinstance(f, str)
             else k[1] if short.count(k[1]) == 1 and k[1] not in strings else f"{k[0]}:{k[1]}"
             for f, k in zip(fields, keys)]
    if len(set(names)) != len(names):
        raise ExabricksError(f"{source}: two fields would both be named "
                             f"{next(n for n in names if names.count(n) > 1)!r} in {list(fields)}")
    return list(zip(keys, names))


def _read(ds, source: str, fields: Sequence[FieldRequest] | None) -> schema.Cells:
    if ds.dimensionality != 3:
        raise ExabricksError(f"{source}: a {ds.dimensionality}D dataset; exabricks reads 3D data only")
    if str(getattr(ds, "geometry", "cartesian")).split(".")[-1].lower() != "cartesian":
        raise ExabricksError(f"{source}: {ds.geometry} geometry; only Cartesian data is supported")
    chosen = _chosen(ds, source, fields)
    if not chosen:
        raise ExabricksError(f"{source}: yt finds no on-disk mesh fields")

    ad = ds.all_data()
    left = ds.domain_left_edge.to("code_length").d.astype(np.float64)
    centre = np.stack([ad["index", a].to("code_length").d for a in "xyz"], axis=1)
    size = np.stack([ad["index", "d" + a].to("code_length").d for a in "xyz"], axis=1)
    if centre.shape[0] == 0:
        raise ExabricksError(f"{source}: the dataset has no cells")
    fine = size.min(axis=0)                                                  # (3,)
    _checks.check_cell_size(source, fine, "finest cell width")
    ratio = size / fine                                                      # (N, 3)
    width = np.rint(ratio).astype(np.int64)
    if np.any(np.abs(ratio - width) > 1e-6 * width) or np.any(width & (width - 1)) \
            or np.any(width != width[:, :1]):
        i = int(np.flatnonzero(np.any(np.abs(ratio - width) > 1e-6 * width, axis=1)
                               | np.any(width & (width - 1), axis=1)
                               | np.any(width != width[:, :1], axis=1))[0])
        raise ExabricksError(
            f"{source}: cell {i} has widths {size[i].tolist()}, not the same power of two times "
            f"the finest widths {fine.tolist()} on every axis"
        )
    width = width[:, 0]
    level = np.log2(width).astype(np.int64)
    if level.max() > MAX_LEVEL:
        raise ExabricksError(f"{source}: more than {MAX_LEVEL + 1} levels of cell widths")
    lower = (centre - 0.5 * size - left) / fine                             # (N, 3) lattice
    lattice = np.rint(lower).astype(np.int64)
    # yt computes centres as left + (i + 1/2) dx in float64: far below 1e-3 finest cells.
    off = np.abs(lower - lattice) > 1e-3
    misaligned = np.any(lattice % width[:, None], axis=1)
    if np.any(off) or np.any(misaligned) or np.any(lattice < 0) or lattice.max() >= 2**31:
        i = int(np.flatnonzero(np.any(off, axis=1) | misaligned | np.any(lattice < 0, axis=1)
                               | np.any(lattice >= 2**31, axis=1))[0])
        raise ExabricksError(
            f"{source}: cell {i} at {(centre[i] - 0.5 * size[i]).tolist()} does not sit on the "
            f"lattice of its width {int(width[i])} x the finest width {fine.tolist()}"
        )
    _checks.check_frame(source, left, fine, lattice.max(axis=0) + width.max())
    values = np.empty((len(chosen), centre.shape[0]), dtype=VALUE_DTYPE)
    units = {}
    for i, (key, name) in enumerate(chosen):
        data = ad[key]
        if np.shape(data) != (centre.shape[0],):
            raise ExabricksError(
                f"{source}: field {name!r}: yt gives {np.shape(data)} values for "
                f"{centre.shape[0]} cells, not one per cell (a particle field?)"
            )
        with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond float32: inf
            values[i] = np.asarray(getattr(data, "d", data))
        units[name] = str(getattr(data, "units", ""))
    return schema.Cells(
        fields=tuple(name for _, name in chosen),
        origin_world=left.astype(WORLD_DTYPE),
        spacing_world=fine.astype(WORLD_DTYPE),
        meta={"source": {"format": "yt", "frontend": type(ds).__name__,
                         "time": float(ds.current_time.d), "units": units}},
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
