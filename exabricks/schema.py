"""The one module that owns the `.npz` file kinds: cells, bricks, regions, bvh.

Every file holds plain numeric arrays (loaded with ``allow_pickle=False``) plus
four header entries: ``format`` (the string ``"exabricks"``), ``kind``,
``version`` (an integer bumped on incompatible change) and ``meta`` (a JSON
string: command line, sha256 of the inputs, parameters, statistics, field
names).  Writing validates and goes through a temporary file in the target
directory that is renamed into place; reading validates and refuses a wrong
kind, a future version, a missing array or a wrong dtype with a message that
names the file.  `docs/file-formats.md` documents every array.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shlex
import sys
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from . import __version__
from .constants import (
    BOUNDS_DTYPE,
    INDEX_DTYPE,
    LATTICE_DTYPE,
    LEVEL_DTYPE,
    MAX_LEVEL,
    OFFSET_DTYPE,
    VALUE_DTYPE,
    WORLD_DTYPE,
)
from .errors import ExabricksError

FORMAT = "exabricks"
HEADER_KEYS = ("format", "kind", "version", "meta")


@dataclass(frozen=True)
class ArraySpec:
    """dtype and shape of one stored array; shape entries are ints or symbol names."""

    dtype: np.dtype
    shape: tuple


def _common_specs() -> dict[str, ArraySpec]:
    return {
        "origin_world": ArraySpec(WORLD_DTYPE, (3,)),
        "spacing_world": ArraySpec(WORLD_DTYPE, (3,)),
    }


@dataclass(frozen=True, eq=False)
class _Kind:
    """Fields shared by every kind: field names, world frame and free-form meta."""

    fields: tuple[str, ...]
    origin_world: np.ndarray
    spacing_world: np.ndarray
    meta: dict = field(default_factory=dict, repr=False)

    KIND: ClassVar[str] = ""
    VERSION: ClassVar[int] = 0
    SPECS: ClassVar[dict[str, ArraySpec]] = {}

    @property
    def n_fields(self) -> int:
        return len(self.fields)

    def field_index(self, name: str | None) -> int:
        """Index of field `name` (None: the first field); ExabricksError if absent."""
        if name is None:
            return 0
        if name not in self.fields:
            raise ExabricksError(
                f"no field {name!r} (fields: {', '.join(self.fields) or 'none'})"
            )
        return self.fields.index(name)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self.SPECS}

    def replace(self, **changes) -> "_Kind":
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, eq=False)
class Cells(_Kind):
    """Leaf cells of an AMR dataset.

    lower_lattice: int32 (N, 3), lower corner in finest-cell units, a multiple of 2**level.
    level:         int8 (N,), 0 is the finest; a cell is 2**level lattice units wide.
    values:        float32 (F, N), one row per field in `fields`.
    """

    lower_lattice: np.ndarray = None
    level: np.ndarray = None
    values: np.ndarray = None

    KIND: ClassVar[str] = "cells"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(LATTICE_DTYPE, ("N", 3)),
        "level": ArraySpec(LEVEL_DTYPE, ("N",)),
        "values": ArraySpec(VALUE_DTYPE, ("F", "N")),
        **_common_specs(),
    }

    @property
    def n_cells(self) -> int:
        return int(self.level.shape[0])


@dataclass(frozen=True, eq=False)
class Bricks(_Kind):
    """Same-level, fully filled bricks of cells (paper §3.1).

    lower_lattice: int32 (B, 3), lower corner in finest-cell units.
    level:         int8 (B,), level of every cell of the brick.
    dims:          int32 (B, 3), cells per axis.
    offset:        int64 (B,), index of the brick's first value in `values`.
    values:        float32 (F, V), per field, brick after brick, x fastest then y then z.
    """

    lower_lattice: np.ndarray = None
    level: np.ndarray = None
    dims: np.ndarray = None
    offset: np.ndarray = None
    values: np.ndarray = None

    KIND: ClassVar[str] = "bricks"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(LATTICE_DTYPE, ("B", 3)),
        "level": ArraySpec(LEVEL_DTYPE, ("B",)),
        "dims": ArraySpec(LATTICE_DTYPE, ("B", 3)),
        "offset": ArraySpec(OFFSET_DTYPE, ("B",)),
        "values": ArraySpec(VALUE_DTYPE, ("F", "V")),
        **_common_specs(),
    }

    @property
    def n_bricks(self) -> int:
        return int(self.level.shape[0])


@dataclass(frozen=True, eq=False)
class Regions(_Kind):
    """Active Brick Regions (paper §3.2.3): disjoint boxes with the bricks active in each.

    lower_lattice, upper_lattice: float32 (R, 3), box bounds in finest-cell units.
    brick_start:  int64 (R + 1,), CSR row pointers into `brick_ids`.
    brick_ids:    int32 (K,), ids of the bricks whose support overlaps each region.
    value_range:  float32 (R, F, 2), min and max of every cell whose support overlaps.
    finest_level: int8 (R,), level of the finest cell influencing the region.
    """

    lower_lattice: np.ndarray = None
    upper_lattice: np.ndarray = None
    brick_start: np.ndarray = None
    brick_ids: np.ndarray = None
    value_range: np.ndarray = None
    finest_level: np.ndarray = None

    KIND: ClassVar[str] = "regions"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(BOUNDS_DTYPE, ("R", 3)),
        "upper_lattice": ArraySpec(BOUNDS_DTYPE, ("R", 3)),
        "brick_start": ArraySpec(OFFSET_DTYPE, ("R+1",)),
        "brick_ids": ArraySpec(INDEX_DTYPE, ("K",)),
        "value_range": ArraySpec(VALUE_DTYPE, ("R", "F", 2)),
        "finest_level": ArraySpec(LEVEL_DTYPE, ("R",)),
        **_common_specs(),
    }

    @property
    def n_regions(self) -> int:
        return int(self.finest_level.shape[0])


@dataclass(frozen=True, eq=False)
class Bvh(_Kind):
    """Bounding-volume hierarchy over the regions (flat node array, node 0 the root).

    lower_lattice, upper_lattice: float32 (M, 3), node bounds in finest-cell units.
    first:        int32 (M,), inner node: index of its left child (the right one is
                  first + 1); leaf: index of its first entry in `region_index`.
    count:        int32 (M,), 0 for an inner node, else the number of regions of the leaf.
    region_index: int32 (R,), region ids in leaf order.
    value_range:  float32 (M, F, 2), min and max over the node's regions.
    finest_level: int8 (M,), finest level influencing the node.
    """

    lower_lattice: np.ndarray = None
    upper_lattice: np.ndarray = None
    first: np.ndarray = None
    count: np.ndarray = None
    region_index: np.ndarray = None
    value_range: np.ndarray = None
    finest_level: np.ndarray = None

    KIND: ClassVar[str] = "bvh"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(BOUNDS_DTYPE, ("M", 3)),
        "upper_lattice": ArraySpec(BOUNDS_DTYPE, ("M", 3)),
        "first": ArraySpec(INDEX_DTYPE, ("M",)),
        "count": ArraySpec(INDEX_DTYPE, ("M",)),
        "region_index": ArraySpec(INDEX_DTYPE, ("R",)),
        "value_range": ArraySpec(VALUE_DTYPE, ("M", "F", 2)),
        "finest_level": ArraySpec(LEVEL_DTYPE, ("M",)),
        **_common_specs(),
    }

    @property
    def n_nodes(self) -> int:
        return int(self.count.shape[0])


KINDS: dict[str, type[_Kind]] = {k.KIND: k for k in (Cells, Bricks, Regions, Bvh)}


# ---------------------------------------------------------------------------
# validation


def _check_shapes(obj: _Kind, where: str) -> None:
    """Check dtypes and symbolic shapes of every array of `obj`."""
    sizes: dict[str, int] = {"F": obj.n_fields}
    for name, spec in obj.SPECS.items():
        arr = getattr(obj, name)
        if not isinstance(arr, np.ndarray):
            raise ExabricksError(f"{where}: array {name!r} is missing")
        if arr.dtype != spec.dtype:
            raise ExabricksError(
                f"{where}: array {name!r} has dtype {arr.dtype}, expected {spec.dtype}"
            )
        if arr.ndim != len(spec.shape):
            raise ExabricksError(
                f"{where}: array {name!r} has shape {arr.shape}, expected {len(spec.shape)} dimensions"
            )
        for axis, (want, got) in enumerate(zip(spec.shape, arr.shape)):
            if isinstance(want, int):
                ok = got == want
            else:
                plus_one = want.endswith("+1")
                sym = want[:-2] if plus_one else want
                value = got - 1 if plus_one else got
                ok = sizes.setdefault(sym, value) == value
            if not ok:
                raise ExabricksError(
                    f"{where}: array {name!r} has shape {arr.shape}, inconsistent in axis {axis} "
                    f"with the other arrays (expected {spec.shape})"
                )


def _check_semantics(obj: _Kind, where: str) -> None:
    """Cheap whole-array checks that catch inconsistent files (O(N), vectorised)."""
    if not (np.all(np.isfinite(obj.origin_world)) and np.all(obj.spacing_world > 0)):
        raise ExabricksError(f"{where}: origin must be finite and spacing positive")
    if len(set(obj.fields)) != len(obj.fields):
        raise ExabricksError(f"{where}: duplicate field names {list(obj.fields)}")
    if isinstance(obj, (Cells, Bricks)):
        if obj.level.size and (obj.level.min() < 0 or obj.level.max() > MAX_LEVEL):
            raise ExabricksError(f"{where}: levels must lie in 0..{MAX_LEVEL}")
        # int32 throughout: this runs on every read and write of tens of millions of cells.
        mask = (np.int32(1) << obj.level.astype(np.int32)) - np.int32(1)
        lo = obj.lower_lattice
        bad = np.flatnonzero((lo[:, 0] | lo[:, 1] | lo[:, 2]) & mask)
        if bad.size:
            i = int(bad[0])
            raise ExabricksError(
                f"{where}: {obj.KIND[:-1]} {i} at {obj.lower_lattice[i].tolist()} is not "
                f"aligned to its level-{int(obj.level[i])} width {1 << int(obj.level[i])}"
            )
    if isinstance(obj, Bricks):
        if obj.dims.size and obj.dims.min() < 1:
            raise ExabricksError(f"{where}: brick dims must be at least 1")
        n = obj.dims.astype(np.int64).prod(axis=1)
        expected = np.concatenate([[0], np.cumsum(n)[:-1]]) if n.size else n
        if not np.array_equal(obj.offset, expected) or int(n.sum()) != obj.values.shape[1]:
            raise ExabricksError(f"{where}: brick offsets do not match brick dims and values")
    if isinstance(obj, Regions):
        s = obj.brick_start
        if s[0] != 0 or s[-1] != obj.brick_ids.shape[0] or np.any(np.diff(s) < 0):
            raise ExabricksError(f"{where}: region brick lists (brick_start) are inconsistent")
        if np.any(obj.upper_lattice < obj.lower_lattice):
            raise ExabricksError(f"{where}: a region has upper < lower bounds")
    if isinstance(obj, Bvh):
        m = obj.n_nodes
        inner = obj.count == 0
        if m and (np.any(obj.first < 0) or np.any(obj.first[inner] + 1 >= m)):
            raise ExabricksError(f"{where}: BVH child indices out of range")
        leaf_end = obj.first[~inner].astype(np.int64) + obj.count[~inner]
        if leaf_end.size and leaf_end.max() > obj.region_index.shape[0]:
            raise ExabricksError(f"{where}: BVH leaf ranges exceed the region index")


def validate(obj: _Kind, where: str = "<memory>") -> None:
    """Raise ExabricksError naming `where` if `obj` breaks its kind's schema."""
    _check_shapes(obj, where)
    _check_semantics(obj, where)


# ---------------------------------------------------------------------------
# meta


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def make_meta(
    inputs: list[str | os.PathLike] = (),
    parameters: dict[str, Any] | None = None,
    statistics: dict[str, Any] | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The provenance every output carries: software, command line, input hashes."""
    return {
        "software": f"exabricks {__version__}",
        "command": shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "inputs": [
            {"path": str(p), "sha256": sha256_file(p) if Path(p).is_file() else None}
            for p in inputs
        ],
        "parameters": parameters or {},
        "statistics": statistics or {},
        **extra,
    }


# ---------------------------------------------------------------------------
# file I/O


def save(path: str | os.PathLike, obj: _Kind) -> None:
    """Validate `obj` and write it atomically to `path` (temporary file, then rename)."""
    path = Path(path)
    validate(obj, str(path))
    meta = dict(obj.meta)
    meta["fields"] = list(obj.fields)
    header = {
        "format": np.array(FORMAT),
        "kind": np.array(obj.KIND),
        "version": np.array(obj.VERSION, dtype=np.int32),
        "meta": np.array(json.dumps(meta, sort_keys=True, default=_json_default)),
    }
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise ExabricksError(f"{path}: directory {directory} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **header, **obj.arrays())
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def peek(path: str | os.PathLike) -> tuple[str, int, dict]:
    """(kind, version, meta) of an exabricks file, without checking the arrays."""
    with _open(path) as z:
        return _header(z, str(path))


def load(path: str | os.PathLike, kind: str | None = None) -> _Kind:
    """Read and validate an exabricks file; with `kind`, refuse any other kind."""
    where = str(path)
    with _open(path) as z:
        found, version, meta = _header(z, where)
        if kind is not None and found != kind:
            raise ExabricksError(f"{where}: expected a {kind} file, found a {found} file")
        cls = KINDS[found]
        if version != cls.VERSION:
            newer = "newer" if version > cls.VERSION else "older"
            raise ExabricksError(
                f"{where}: {found} file version {version} is {newer} than this exabricks "
                f"reads (version {cls.VERSION}); rebuild it with exabricks {__version__}"
            )
        arrays = {}
        for name in cls.SPECS:
            if name not in z.files:
                raise ExabricksError(f"{where}: array {name!r} is missing")
            try:
                arrays[name] = z[name]
            except Exception as e:  # truncated member, bad header: numpy/zipfile raise many types
                raise ExabricksError(f"{where}: array {name!r} cannot be read ({e})") from e
    fields = meta.pop("fields", None)
    if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
        raise ExabricksError(f"{where}: meta has no list of field names")
    obj = cls(fields=tuple(fields), meta=meta, **arrays)
    validate(obj, where)
    return obj


class _open:
    """np.load as a context manager that turns every failure into ExabricksError."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        p = Path(self.path)
        if not p.exists():
            raise ExabricksError(f"{p}: no such file")
        if not p.is_file():
            raise ExabricksError(f"{p}: not a file")
        with open(p, "rb") as f:
            head = f.read(6)
        if not head:
            raise ExabricksError(f"{p}: empty file, not an exabricks .npz file")
        if not head.startswith(b"PK") and not head.startswith(b"\x93NUMPY"):
            raise ExabricksError(f"{p}: not an exabricks .npz file (not a zip archive; "
                                 "an image, a raw data file or text?)")
        try:
            self.z = np.load(p, allow_pickle=False)
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as e:
            raise ExabricksError(
                f"{p}: not a readable exabricks .npz file (truncated or another format: {e})"
            ) from e
        if not hasattr(self.z, "files"):
            raise ExabricksError(f"{p}: a plain .npy array, not an exabricks .npz file")
        return self.z

    def __exit__(self, *exc):
        self.z.close()
        return False


def _header(z, where: str) -> tuple[str, int, dict]:
    for key in HEADER_KEYS:
        if key not in z.files:
            raise ExabricksError(f"{where}: not an exabricks file (no {key!r} entry)")
    try:
        fmt = str(z["format"])
        kind = str(z["kind"])
        version = int(z["version"])
        meta = json.loads(str(z["meta"]))
    except Exception as e:
        raise ExabricksError(f"{where}: unreadable header ({e})") from e
    if fmt != FORMAT:
        raise ExabricksError(f"{where}: format is {fmt!r}, expected {FORMAT!r}")
    if kind not in KINDS:
        raise ExabricksError(
            f"{where}: unknown kind {kind!r} (known: {', '.join(KINDS)})"
        )
    if not isinstance(meta, dict):
        raise ExabricksError(f"{where}: meta is not a JSON object")
    return kind, version, meta


# ---------------------------------------------------------------------------
# summaries (for `exabricks info`; the keys are documented in docs/file-formats.md)


def world_bounds(obj: _Kind) -> tuple[list[float], list[float]]:
    """World-space bounding box of the data (cells/bricks) or the structure (regions/bvh)."""
    if isinstance(obj, Cells):
        lo, hi = _cell_box(obj.lower_lattice, obj.level, np.ones_like(obj.lower_lattice))
    elif isinstance(obj, Bricks):
        lo, hi = _cell_box(obj.lower_lattice, obj.level, obj.dims)
    elif isinstance(obj, Bvh):
        lo, hi = (obj.lower_lattice[:1], obj.upper_lattice[:1])
        lo, hi = (lo.min(axis=0), hi.max(axis=0)) if lo.size else (lo, hi)
    else:
        lo, hi = obj.lower_lattice, obj.upper_lattice
        lo, hi = (lo.min(axis=0), hi.max(axis=0)) if lo.size else (lo, hi)
    if np.size(lo) == 0:
        return [], []
    to_world = lambda x: (obj.origin_world + obj.spacing_world * np.asarray(x, float)).tolist()
    return to_world(lo), to_world(hi)


def _cell_box(lower, level, dims):
    if lower.size == 0:
        return lower[:0], lower[:0]
    width = (1 << level.astype(np.int64))[:, None]
    return lower.min(axis=0), (lower.astype(np.int64) + dims * width).max(axis=0)


def summary(obj: _Kind) -> dict[str, Any]:
    """A JSON-ready description: kind, version, counts, fields with ranges, frame, meta."""
    counts: dict[str, Any] = {}
    ranges: dict[str, list[float | None]] = {}
    if isinstance(obj, (Cells, Bricks)):
        if isinstance(obj, Cells):
            per_level = np.bincount(obj.level.astype(np.int64), minlength=1)
            counts["cells"] = obj.n_cells
        else:
            n = obj.dims.astype(np.int64).prod(axis=1)
            per_level = np.bincount(obj.level.astype(np.int64), weights=n, minlength=1)
            counts["cells"] = int(n.sum())
            counts["bricks"] = obj.n_bricks
            counts["bricks_per_level"] = {
                str(l): int(c) for l, c in enumerate(np.bincount(obj.level.astype(np.int64)))
                if c
            }
        counts["cells_per_level"] = {str(l): int(c) for l, c in enumerate(per_level) if c}
        for i, name in enumerate(obj.fields):
            v = obj.values[i]
            finite = v[np.isfinite(v)]
            ranges[name] = [float(finite.min()), float(finite.max())] if finite.size else [None, None]
    else:
        vr = obj.value_range
        for i, name in enumerate(obj.fields):
            ranges[name] = (
                [float(vr[:, i, 0].min()), float(vr[:, i, 1].max())] if vr.shape[0] else [None, None]
            )
        if isinstance(obj, Regions):
            counts["regions"] = obj.n_regions
            counts["region_brick_refs"] = int(obj.brick_ids.shape[0])
        else:
            counts["nodes"] = obj.n_nodes
            counts["leaves"] = int(np.count_nonzero(obj.count))
            counts["regions"] = int(obj.region_index.shape[0])
    lo, hi = world_bounds(obj)
    return {
        "kind": obj.KIND,
        "version": obj.VERSION,
        "counts": counts,
        "fields": [{"name": n, "min": ranges[n][0], "max": ranges[n][1]} for n in obj.fields],
        "world_bounds": {"lower": lo, "upper": hi},
        "origin": obj.origin_world.tolist(),
        "spacing": obj.spacing_world.tolist(),
        "bytes": {k: int(a.nbytes) for k, a in obj.arrays().items()},
        "meta": obj.meta,
    }
