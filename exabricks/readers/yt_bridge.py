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

The other way, leaf cells as yt's nested grids, is exabricks.readers.yt_grids.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError
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
