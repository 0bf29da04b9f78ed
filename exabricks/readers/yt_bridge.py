"""Leaf cells of anything yt loads (Enzo, FLASH, Chombo, GAMER, …), through yt.

yt is an optional dependency (`pip install 'exabricks[yt]'`), imported only here.
The leaves are the cells of `ds.all_data()`; each one's centre and width
(("index", "x"/"dx") etc., in code_length) give its lower corner, which is turned
into lattice units relative to the domain's left edge and the finest cell width.
Fields are read raw on the dataset's own fluid type (e.g. ("enzo", "Density")), so
their values are the file's, in code units.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..errors import ExabricksError

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
    values = np.empty((len(chosen), centre.shape[0]), dtype=VALUE_DTYPE)
    for i, key in enumerate(chosen):
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
