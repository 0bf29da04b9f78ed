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
    MAX_TREE_DEPTH,
    OFFSET_DTYPE,
    VALUE_DTYPE,
    WORLD_DTYPE,
)
from .errors import ExabricksError
from .output import write_output

FORMAT = "exabricks"
HEADER_KEYS = ("format", "kind", "version", "meta")
# The header entries are short strings; meta (provenance, statistics) stays far below this.
MAX_HEADER_BYTES = 64 << 20


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
class Kind:
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

    def replace(self, **changes) -> "Kind":
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, eq=False)
class Cells(Kind):
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
class Bricks(Kind):
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
class Regions(Kind):
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
class Bvh(Kind):
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


KINDS: dict[str, type[Kind]] = {k.KIND: k for k in (Cells, Bricks, Regions, Bvh)}


# ---------------------------------------------------------------------------
# validation


def _check_shapes(obj: Kind, where: str) -> None:
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


def _check_semantics(obj: Kind, where: str) -> None:
    """Cheap whole-array checks (O(N), vectorised) that catch inconsistent files,
    including everything a kernel follows: no file can make one read out of
    bounds or loop.  Per-item arrays are checked in steps of about CHUNK elements
    (`rows`): temporaries stay small, and a mapped file's pages are handed back."""
    spacing = obj.spacing_world
    if not (np.all(np.isfinite(obj.origin_world)) and np.all(np.isfinite(spacing))
            and np.all(spacing >= np.finfo(np.float64).tiny)):
        raise ExabricksError(f"{where}: origin must be finite and spacing finite, positive and "
                             f"normal (origin {obj.origin_world.tolist()}, spacing {spacing.tolist()})")
    if len(set(obj.fields)) != len(obj.fields):
        raise ExabricksError(f"{where}: duplicate field names {list(obj.fields)}")
    if isinstance(obj, (Cells, Bricks)):
        _check_levels(obj.level, where, obj.KIND[:-1])
        i = first_misaligned(obj.lower_lattice, obj.level)
        if i >= 0:
            raise ExabricksError(
                f"{where}: {obj.KIND[:-1]} {i} at {obj.lower_lattice[i].tolist()} is not "
                f"aligned to its level-{int(obj.level[i])} width {1 << int(obj.level[i])}"
            )
    if isinstance(obj, Bricks):
        _check_bricks(obj, where)
    if isinstance(obj, Regions):
        _check_lists(obj, where)
        _check_boxes(obj.lower_lattice, obj.upper_lattice, where, "region")
        _check_levels(obj.finest_level, where, "region")
    if isinstance(obj, Bvh):
        _check_bvh(obj, where)


def first_misaligned(lower: np.ndarray, level: np.ndarray) -> int:
    """Index of the first row whose corner (int32 (N, 3)) is not a multiple of
    2**level (int8 (N,), already checked to lie in 0..MAX_LEVEL), else -1.  In
    steps at memory speed (about 4 ns a row): this runs on every read and write
    of tens of millions of cells, and NumPy spares the commands that build
    nothing (render, probe, info) numba's start-up."""
    for start, (lo, lv) in rows(lower, level):
        corner = np.bitwise_or(lo[:, 0], lo[:, 1])
        corner |= lo[:, 2]
        corner &= np.left_shift(1, lv, dtype=np.int32) - 1
        bad = np.flatnonzero(corner)
        if bad.size:
            return start + int(bad[0])
    return -1


def _check_levels(level: np.ndarray, where: str, item: str) -> None:
    for start, (part,) in rows(level):
        if part.size and (int(part.min()) < 0 or int(part.max()) > MAX_LEVEL):
            i = start + int(np.flatnonzero((part < 0) | (part > MAX_LEVEL))[0])
            raise ExabricksError(f"{where}: {item} {i} has level {int(level[i])}, "
                                 f"outside 0..{MAX_LEVEL}")


def _check_boxes(lower: np.ndarray, upper: np.ndarray, where: str, item: str) -> None:
    """Finite bounds with lower <= upper on every axis."""
    for start, (lo, hi) in rows(lower, upper):
        bad = ~(np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1) & (lo <= hi).all(axis=1))
        if bad.any():
            i = start + int(np.flatnonzero(bad)[0])
            raise ExabricksError(f"{where}: {item} {i} has bounds {lower[i].tolist()} .. "
                                 f"{upper[i].tolist()} (must be finite, lower <= upper)")


def _check_bricks(obj: "Bricks", where: str) -> None:
    """Dims of at least one cell (fewer than 2**31 per brick), offsets that are the
    running sum of the brick sizes and end at the values, boxes in the int32 lattice
    (levels checked before)."""
    expected = 0
    for start, (dims, offset, lower, level) in rows(obj.dims, obj.offset, obj.lower_lattice,
                                                    obj.level):
        d = dims.astype(np.int64)
        if d.size and d.min() < 1:
            i = start + int(np.flatnonzero(d.min(axis=1) < 1)[0])
            raise ExabricksError(f"{where}: brick {i} has dims {obj.dims[i].tolist()} "
                                 "(at least 1 each)")
        n = d.prod(axis=1)
        # The kernels index a brick's values with 32-bit integers.
        if n.size and n.max() >= 2**31:
            i = start + int(np.argmax(n))
            raise ExabricksError(f"{where}: brick {i} has {int(n[i - start])} cells, more "
                                 "than 2**31 - 1")
        ends = np.cumsum(n) + expected
        if n.size and not (offset[0] == expected and np.array_equal(offset[1:], ends[:-1])):
            raise ExabricksError(f"{where}: brick offsets do not match brick dims and values")
        expected = int(ends[-1]) if n.size else expected
        upper = lower.astype(np.int64) + d * (np.int64(1) << level.astype(np.int64))[:, None]
        if upper.size and upper.max() > np.iinfo(LATTICE_DTYPE).max:
            i = int(np.argmax(upper.max(axis=1)))
            raise ExabricksError(f"{where}: brick {start + i} reaches lattice "
                                 f"{upper[i].tolist()}, beyond the int32 lattice")
    if expected != obj.values.shape[1]:
        raise ExabricksError(f"{where}: brick offsets do not match brick dims and values")


def _check_lists(obj: "Regions", where: str) -> None:
    """CSR row pointers from 0, ascending, to the end of the brick lists; no
    negative brick id (those beyond the bricks are checked against them)."""
    s = obj.brick_start
    if s[0] != 0 or s[-1] != obj.brick_ids.shape[0]:
        raise ExabricksError(f"{where}: region brick lists (brick_start) are inconsistent")
    last = 0
    for _, (part,) in rows(s):
        if part.size and (part[0] < last or np.any(part[1:] < part[:-1])):
            raise ExabricksError(f"{where}: region brick lists (brick_start) are inconsistent")
        last = part[-1] if part.size else last
    for start, (ids,) in rows(obj.brick_ids):
        if ids.size and int(ids.min()) < 0:
            i = start + int(np.argmin(ids))
            raise ExabricksError(f"{where}: region brick list entry {i} is a negative brick "
                                 f"id ({int(ids[i - start])})")


def _check_bvh(obj: "Bvh", where: str) -> None:
    """Children at larger indices than their parent, each node the child of exactly
    one parent (a tree: every walk ends), leaf ranges inside the region index,
    finite nested bounds and a depth the kernels' stacks hold."""
    m = obj.n_nodes
    first = obj.first.astype(np.int64)
    count = obj.count.astype(np.int64)
    if count.size and count.min() < 0:
        i = int(np.argmin(count))
        raise ExabricksError(f"{where}: BVH node {i} has a negative region count ({int(count[i])})")
    inner = np.flatnonzero(count == 0)
    leaf = np.flatnonzero(count > 0)
    if inner.size and (np.any(first[inner] <= inner) or np.any(first[inner] + 1 >= m)):
        i = int(inner[(first[inner] <= inner) | (first[inner] + 1 >= m)][0])
        raise ExabricksError(f"{where}: BVH node {i} has children {int(first[i])}, "
                             f"{int(first[i]) + 1}: they must follow it and lie below {m}")
    if m:
        parents = np.bincount(np.concatenate([first[inner], first[inner] + 1]), minlength=m)
        bad = np.flatnonzero(parents[1:] != 1)
        if bad.size:
            i = int(bad[0]) + 1
            raise ExabricksError(f"{where}: BVH node {i} is the child of {int(parents[i])} "
                                 "nodes (a tree has exactly one parent per node)")
    if leaf.size and (first[leaf].min() < 0 or (first[leaf] + count[leaf]).max()
                      > obj.region_index.shape[0]):
        raise ExabricksError(f"{where}: BVH leaf ranges exceed the region index")
    _check_boxes(obj.lower_lattice, obj.upper_lattice, where, "BVH node")
    _check_levels(obj.finest_level, where, "BVH node")
    depth = tree_depth(first, count)
    if depth > MAX_TREE_DEPTH:
        raise ExabricksError(f"{where}: the BVH is {depth} levels deep, more than the "
                             f"{MAX_TREE_DEPTH} the kernels' traversal stacks hold")


def tree_depth(first: np.ndarray, count: np.ndarray) -> int:
    """Levels of a flat binary tree (node 0 the root; inner nodes, count 0, have
    children first and first + 1): one vectorised step per level. The tree
    must be valid (children after parents, one parent each); 0 for no nodes."""
    if first.shape[0] == 0:
        return 0
    frontier = np.zeros(1, np.int64)
    depth = 0
    while frontier.size:
        depth += 1
        if depth > MAX_TREE_DEPTH:
            return depth
        inner = frontier[count[frontier] == 0]
        frontier = np.concatenate([first[inner], first[inner] + 1]).astype(np.int64)
    return depth


def validate(obj: Kind, where: str = "<memory>") -> None:
    """Raise ExabricksError naming `where` if `obj` breaks its kind's schema."""
    _check_shapes(obj, where)
    _check_semantics(obj, where)


# ---------------------------------------------------------------------------
# meta


def sha256_file(path: str | os.PathLike) -> str | None:
    """The sha256 (hex) of input `path`: of the bytes read through the descriptor
    its data came from, when it was opened by `load(digest=True)` or
    `prefetch_sha256`, else of the file now; None for what is not a regular file
    (an AMReX plotfile directory)."""
    pending = _DIGESTS.get(os.fspath(path))
    if pending is not None:
        return pending.result()
    from .jsonfile import open_regular

    try:
        with open_regular(path, "an input") as f:
            return _sha256_fd(f.fileno())
    except ExabricksError:
        return None


def prefetch_sha256(paths) -> None:
    """Start hashing the regular files among `paths` on background threads, each
    from the file as opened now, so that `make_meta` at the end of a command finds
    their digests ready instead of reading the inputs once more (hashlib and
    file reads release the GIL; a daemon thread never holds up an interrupted
    command's exit)."""
    from .jsonfile import open_regular

    for p in paths:
        try:
            with open_regular(p, "an input") as f:
                _hash_in_background(p, f.fileno())
        except ExabricksError:
            continue


# The inputs being hashed: path as given -> Future of the sha256 of the file
# that was opened under that path (the bytes read, even if a rename has since
# put another file there).
_DIGESTS: dict = {}


def _hash_in_background(path, fd: int) -> None:
    """Hash the file open on `fd` (through a duplicate of it) on a daemon thread,
    as `path`'s digest."""
    import threading
    from concurrent.futures import Future

    own = os.dup(fd)
    future = Future()

    def run():
        try:
            future.set_result(_sha256_fd(own))
        except BaseException as e:  # re-raised by sha256_file in the main thread
            future.set_exception(e)
        finally:
            os.close(own)

    _DIGESTS[os.fspath(path)] = future
    threading.Thread(target=run, name="sha256", daemon=True).start()


def _sha256_fd(fd: int, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    offset = 0
    while block := os.pread(fd, chunk, offset):
        h.update(block)
        offset += len(block)
    return h.hexdigest()


def make_meta(
    inputs: list[str | os.PathLike] = (),
    parameters: dict[str, Any] | None = None,
    statistics: dict[str, Any] | None = None,
    upstream: Kind | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The provenance every output carries: software, command line, input hashes,
    and what it was built from (`upstream`, the loaded input: `built_from`)."""
    if upstream is not None:
        extra["built_from"] = built_from(upstream)
    return {
        "software": f"exabricks {__version__}",
        "command": shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "inputs": [
            {"path": str(p), "sha256": sha256_file(p)}
            for p in inputs
        ],
        "parameters": parameters or {},
        "statistics": statistics or {},
        **extra,
    }


# ---------------------------------------------------------------------------
# file I/O


def save(path: str | os.PathLike, obj: Kind, *, inputs=()) -> None:
    """Validate `obj` and write it to `path` through exabricks.output (atomic
    for files, direct for devices; refused if `path` names one of `inputs`)."""
    validate(obj, str(path))
    meta = dict(obj.meta)
    meta["fields"] = list(obj.fields)
    meta["content_sha256"] = content_sha256(obj)
    header = {
        "format": np.array(FORMAT),
        "kind": np.array(obj.KIND),
        "version": np.array(obj.VERSION, dtype=np.int32),
        "meta": np.array(json.dumps(meta, sort_keys=True, default=_json_default)),
    }

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, **header, **obj.arrays())
            f.flush()
            os.fsync(f.fileno())

    write_output(path, write, inputs=inputs)


def content_sha256(obj: Kind) -> str:
    """The sha256 (hex) of what `obj` holds: its kind, field names and every array
    (name, dtype, shape, bytes). `save` stores it in the file's meta; the files
    built from it record it as `meta.built_from` (`built_from`, `check_built_from`),
    so that a consumer checks a chain of files by comparing stored digests."""
    h = hashlib.sha256(json.dumps([obj.KIND, list(obj.fields)]).encode())
    for name in sorted(obj.SPECS):
        a = np.ascontiguousarray(getattr(obj, name))
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        flat = a.reshape(-1).view(np.uint8)
        for start in range(0, flat.size, 1 << 26):
            h.update(flat[start:start + (1 << 26)])
    return h.hexdigest()


def built_from(source: Kind) -> dict:
    """What a file built from `source` records of it (meta key `built_from`)."""
    return {"kind": source.KIND, "content_sha256": source.meta.get("content_sha256")}


def check_built_from(obj: Kind, where, source: Kind, source_where) -> None:
    """ExabricksError (one line naming both files) unless `obj` (read from `where`)
    records that it was built from `source` (read from `source_where`): the
    regions from the bricks, the BVH from the regions. Files that predate the
    record, or objects built in memory, carry none and are checked by their
    counts and frames only (exabricks.render.device_data.check_inputs)."""
    recorded = obj.meta.get("built_from")
    recorded = recorded.get("content_sha256") if isinstance(recorded, dict) else None
    actual = source.meta.get("content_sha256")
    if recorded is None or actual is None or recorded == actual:
        return
    raise ExabricksError(
        f"{where}: was built from another {source.KIND} file than {source_where} (it records "
        f"{source.KIND} content sha256 {str(recorded)[:12]}..., {source_where} holds "
        f"{str(actual)[:12]}...): rebuild it from {source_where}")


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def peek(path: str | os.PathLike) -> tuple[str, int, dict]:
    """(kind, version, meta) of an exabricks file, without reading the arrays."""
    with NpzArchive(path) as z:
        return _header(z, str(path))


def load(path: str | os.PathLike, kind: str | None = None, *, mapped: bool = False,
         checked: bool | None = None, digest: bool = False) -> Kind:
    """Read and validate an exabricks file; with `kind`, refuse any other kind.

    The arrays' dtypes and shapes are read from their .npy headers and checked
    against the schema (and against the sizes the zip directory records)
    before any array is decompressed, so a crafted file cannot make the
    loader allocate more than the file claims consistently.

    `mapped`: the large stored arrays are mapped read-only from the file instead
    of read (pages come in as they are used).  `checked` (default: not `mapped`)
    validates the whole file; a mapped file is then checked in steps, its CRCs
    too, handing its pages back as it goes, so that a builder holds only what it
    uses.  Mapped and unchecked, only dtypes and shapes are checked: for a caller
    that uses a part of the data and validates that part itself
    (exabricks.render.partition.domain_data, whose output goes through `validate`
    like any file).

    `digest`: hash the file on a background thread, from the descriptor its
    arrays are read and mapped through, for the `inputs` of the `make_meta` of
    what is built from it (`sha256_file`)."""
    where = str(path)
    with NpzArchive(path, digest=digest) as z:
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
        fields = meta.pop("fields", None)
        if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
            raise ExabricksError(f"{where}: meta has no list of field names")
        headers = {}
        for name in cls.SPECS:
            if name not in z.files:
                raise ExabricksError(f"{where}: array {name!r} is missing")
            headers[name] = z.header(name)
        _check_declared(cls, headers, len(fields), where)
        sizes = {name: int(np.prod(shape)) * dtype.itemsize for name, (shape, dtype) in headers.items()}
        _check_memory(sum(sizes.values()), where)
        # Smallest first: the sizes the small arrays imply are checked against the
        # large ones' headers before those are decompressed.
        arrays = {}
        for name in sorted(cls.SPECS, key=sizes.get):
            _check_implied_sizes(cls, arrays, headers, where)
            arrays[name] = z.array(name, mapped=mapped)
            if mapped and checked:
                z.check_crc(name, arrays[name])
    obj = cls(fields=tuple(fields), meta=meta, **arrays)
    if checked or (checked is None and not mapped):
        validate(obj, where)
    return obj


# Elements per step of `reduce_chunks` (4 MiB of float32).
CHUNK = 1 << 20


def _mapping(array: np.ndarray):
    """The mmap behind a mapped array (load(mapped=True)), else None."""
    return getattr(array, "_mmap", None) if isinstance(array, np.memmap) else None


def _hand_back(base, start: int = 0, length: int = 0) -> None:
    """Drop the resident pages of mmap `base` from byte `start` for `length` bytes
    (0: to the end): clean copies of the file, read again if used again."""
    import mmap

    if not hasattr(mmap, "MADV_DONTNEED"):
        return
    if not length:
        base.madvise(mmap.MADV_DONTNEED)
        return
    lo = start // mmap.PAGESIZE * mmap.PAGESIZE
    base.madvise(mmap.MADV_DONTNEED, lo, start + length - lo)


def release(obj: "Kind") -> None:
    """Hand back the resident pages of `obj`'s mapped arrays."""
    release_arrays(*obj.arrays().values())


def release_arrays(*arrays: np.ndarray) -> None:
    """Hand back the resident pages of those `arrays` that are mapped."""
    for array in arrays:
        base = _mapping(array)
        if base is not None:
            _hand_back(base)


def trim_heap() -> None:
    """Give the C heap's free memory back to the system (glibc keeps what the
    piece's temporaries used, a few hundred MB on large data); a no-op elsewhere."""
    import ctypes
    import ctypes.util

    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def rows(*arrays: np.ndarray):
    """Steps of about CHUNK elements (whole rows) along the first axis, which
    `arrays` share: yields (start, [views of rows start.. of each array]).  The pages
    of mapped arrays are handed back after each step, so that a pass over large
    mapped arrays does not keep them resident."""
    n = arrays[0].shape[0]
    width = max(max(1, int(np.prod(a.shape[1:]))) for a in arrays)
    step = max(1, CHUNK // width)
    for start in range(0, n, step):
        parts = [a[start:start + step] for a in arrays]
        yield start, parts
        for a, part in zip(arrays, parts):
            base = _mapping(a)
            if base is not None and part.size:
                _hand_back(base, part.ctypes.data - np.frombuffer(base, np.uint8).ctypes.data,
                           part.nbytes)


def reduce_chunks(array: np.ndarray, fn, combine):
    """combine() over fn(chunk) of the `rows` steps of `array` (fn(array[:0]) if it
    has no rows)."""
    result = None
    for _, (part,) in rows(array):
        value = fn(part)
        result = value if result is None else combine(result, value)
    return fn(array[:0]) if result is None else result


def _check_declared(cls, headers: dict, n_fields: int, where: str) -> None:
    """Dtypes and shapes from the .npy headers against the schema, before reading."""
    stub = cls.__new__(cls)
    object.__setattr__(stub, "fields", tuple(f"f{i}" for i in range(n_fields)))
    for name, (shape, dtype) in headers.items():
        object.__setattr__(stub, name, np.lib.stride_tricks.as_strided(
            np.zeros(1, dtype), shape=shape, strides=(0,) * len(shape)))
    _check_shapes(stub, where)


def _check_implied_sizes(cls, arrays: dict, headers: dict, where: str) -> None:
    """Sizes that arrays read so far imply for the free axes of the others (brick
    values from brick dims, region brick lists from brick_start)."""
    implied = {}
    if cls is Bricks and "dims" in arrays:
        implied["values"] = (1, reduce_chunks(
            arrays["dims"], lambda d: int(d.astype(np.int64).prod(axis=1).sum()), int.__add__))
    if cls is Regions and "brick_start" in arrays and arrays["brick_start"].size:
        implied["brick_ids"] = (0, int(arrays["brick_start"][-1]))
    for name, (axis, size) in implied.items():
        shape = headers[name][0]
        if name not in arrays and len(shape) > axis and shape[axis] != size:
            raise ExabricksError(f"{where}: array {name!r} has shape {shape}, inconsistent "
                                 f"with the {size} entries the other arrays imply")


def _check_memory(nbytes: int, where: str) -> None:
    """Refuse arrays that cannot fit this machine's memory (or the process's limit)."""
    limit = memory_limit()
    if limit is not None and nbytes > limit:
        raise ExabricksError(f"{where}: its arrays need {nbytes / 2**30:.1f} GiB, more than the "
                             f"{limit / 2**30:.1f} GiB of memory available")


def memory_limit() -> int | None:
    """Bytes this process can hold: physical memory, or a lower RLIMIT_AS; None if unknown."""
    limits = []
    try:
        limits.append(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        pass
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            limits.append(soft)
    except (ImportError, ValueError, OSError):
        pass
    return min(limits) if limits else None


class NpzArchive:
    """A .npz file read member by member, with every failure an ExabricksError.

    `files` lists the member names (without ".npy"); `header(name)` is the
    (shape, dtype) of a member's .npy header, checked against the size the zip
    directory records; `array(name)` reads it (never with pickles)."""

    # Stored (uncompressed, as exabricks writes them) members this large are read
    # straight into their array: one copy from the file, no chunked copies.
    DIRECT_BYTES = 1 << 20

    def __init__(self, path, *, digest: bool = False):
        self.path = Path(path)
        self.digest = digest
        self.file = None
        self.zip = None
        self._headers = {}  # name -> (shape, dtype, bytes of the .npy header)

    def __enter__(self):
        from .jsonfile import open_regular

        self.file = open_regular(self.path, "an exabricks file")
        try:
            return self._open_zip()
        except BaseException:
            self.file.close()
            raise

    def _open_zip(self):
        p = self.path
        try:
            head = os.pread(self.file.fileno(), 4, 0)
        except OSError as e:
            raise ExabricksError(f"{p}: cannot read ({e.strerror or e})") from None
        if not head:
            raise ExabricksError(f"{p}: empty file, not an exabricks .npz file")
        if head.startswith(b"\x93NUM"):
            raise ExabricksError(f"{p}: a plain .npy array, not an exabricks .npz file")
        if head != b"PK\x03\x04":
            raise ExabricksError(f"{p}: not an exabricks .npz file (not a zip archive; "
                                 "an image, a raw data file or text?)")
        if self.digest:
            _hash_in_background(p, self.file.fileno())
        try:
            self.zip = zipfile.ZipFile(self.file)
            self.members = {i.filename[:-4]: i for i in self.zip.infolist()
                            if i.filename.endswith(".npy")}
        except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError,
                NotImplementedError, RuntimeError) as e:
            raise ExabricksError(f"{p}: not a readable exabricks .npz file "
                                 f"(truncated or another format: {e})") from None
        return self

    def __exit__(self, *exc):
        if self.zip is not None:
            self.zip.close()
        if self.file is not None:
            self.file.close()
        return False

    def _pread(self, n: int, offset: int) -> bytes:
        """`n` bytes of the archive at `offset` (fewer at its end), through the one
        descriptor every read of this archive goes through."""
        return os.pread(self.file.fileno(), n, offset)

    @property
    def files(self) -> list[str]:
        return list(self.members)

    def _fail(self, name, problem):
        return ExabricksError(f"{self.path}: array {name!r} {problem}")

    def _open_member(self, name):
        try:
            return self.zip.open(self.members[name])
        except (zipfile.BadZipFile, NotImplementedError, RuntimeError, ValueError, OSError) as e:
            raise self._fail(name, f"cannot be read ({e})") from None

    def header(self, name) -> tuple[tuple[int, ...], np.dtype]:
        if name not in self._headers:
            self._headers[name] = self._read_header(name)
        return self._headers[name][:2]

    def _read_header(self, name) -> tuple[tuple[int, ...], np.dtype, int]:
        fmt = np.lib.format
        info = self.members[name]
        try:
            with self._open_member(name) as f:
                version = fmt.read_magic(f)
                if version == (1, 0):
                    shape, fortran, dtype = fmt.read_array_header_1_0(f)
                elif version == (2, 0):
                    shape, fortran, dtype = fmt.read_array_header_2_0(f)
                else:
                    raise ValueError(f"unsupported .npy version {version}")
                header_bytes = f.tell()
        except ExabricksError:
            raise
        except Exception as e:  # zlib, zipfile and numpy raise many types for bad bytes
            raise self._fail(name, f"has no readable .npy header ({e})") from None
        if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
            raise self._fail(name, f"has dtype {dtype}, not a plain numeric array")
        if fortran and len(shape) > 1:
            raise self._fail(name, "is stored in Fortran order (exabricks writes C order)")
        size = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if header_bytes + size != info.file_size:
            raise self._fail(name, f"claims shape {shape} of {dtype} ({size} bytes) but the "
                                   f"archive holds {info.file_size - header_bytes} bytes for it")
        return tuple(int(x) for x in shape), dtype, header_bytes

    def array(self, name, mapped: bool = False) -> np.ndarray:
        """The member's array: read (stored members checked against the CRC), or
        with `mapped` a large stored member mapped read-only from the file."""
        info = self.members[name]
        if info.compress_type == zipfile.ZIP_STORED and info.file_size >= self.DIRECT_BYTES:
            if mapped:
                return self._map_stored(name, info)
            return self._read_stored(name, info)
        try:
            with self._open_member(name) as f:
                return np.lib.format.read_array(f, allow_pickle=False)
        except ExabricksError:
            raise
        except MemoryError:
            raise
        except Exception as e:  # truncated member, CRC error, ...
            raise self._fail(name, f"cannot be read ({e})") from None

    def _data_offset(self, info) -> int:
        """Where a stored member's bytes (its .npy header first) start in the file."""
        local = self._pread(30, info.header_offset)
        if len(local) != 30 or local[:4] != b"PK\x03\x04":
            raise ValueError("bad local file header")
        name_len = int.from_bytes(local[26:28], "little")
        extra_len = int.from_bytes(local[28:30], "little")
        return info.header_offset + 30 + name_len + extra_len

    def _map_stored(self, name, info) -> np.ndarray:
        """A stored member's array mapped read-only (no CRC: its pages are not read)."""
        shape, dtype = self.header(name)
        skip = self._headers[name][2]
        try:
            offset = self._data_offset(info) + skip
            if offset + info.file_size - skip > os.fstat(self.file.fileno()).st_size:
                raise ValueError("truncated")
            return np.memmap(self.file, dtype=dtype, mode="r", offset=offset, shape=shape)
        except OSError as e:
            raise self._fail(name, f"cannot be read ({e.strerror or e})") from None
        except ValueError as e:
            raise self._fail(name, f"cannot be read ({e})") from None

    def check_crc(self, name, array: np.ndarray) -> None:
        """Check a mapped member against the archive's CRC, in `rows` steps (a
        member read whole is checked as it is read)."""
        import zlib

        info = self.members[name]
        if _mapping(array) is None:
            return
        try:
            crc = zlib.crc32(self._pread(self._headers[name][2], self._data_offset(info)))
        except (OSError, ValueError) as e:
            raise self._fail(name, f"cannot be read ({e})") from None
        for _, (part,) in rows(array.reshape(-1)):
            crc = zlib.crc32(part, crc)
        if crc != info.CRC:
            raise self._fail(name, "cannot be read (bad CRC: the file is damaged)")

    def _read_stored(self, name, info) -> np.ndarray:
        """A stored member's array, read with one readinto and checked against the
        archive's CRC (zlib.crc32 runs at several GB/s)."""
        import zlib

        shape, dtype = self.header(name)
        skip = self._headers[name][2]
        out = np.empty(shape, dtype)
        view = memoryview(out.reshape(-1).view(np.uint8))
        try:
            start = self._data_offset(info)
            head = self._pread(skip, start)
            done = 0
            while done < len(view):
                n = os.preadv(self.file.fileno(), [view[done:]], start + skip + done)
                if n <= 0:
                    break
                done += n
            if done != len(view) or len(head) != skip:
                raise ValueError("truncated")
        except OSError as e:
            raise self._fail(name, f"cannot be read ({e.strerror or e})") from None
        except ValueError as e:
            raise self._fail(name, f"cannot be read ({e})") from None
        if zlib.crc32(view, zlib.crc32(head)) != info.CRC:
            raise self._fail(name, "cannot be read (bad CRC: the file is damaged)")
        return out

    def __getitem__(self, name) -> np.ndarray:
        return self.array(name)


def _header(z: NpzArchive, where: str) -> tuple[str, int, dict]:
    for key in HEADER_KEYS:
        if key not in z.files:
            raise ExabricksError(f"{where}: not an exabricks file (no {key!r} entry)")
        shape, dtype = z.header(key)
        if shape != () or dtype.itemsize > MAX_HEADER_BYTES or dtype.kind not in "Uiu":
            raise ExabricksError(f"{where}: not an exabricks file (its {key!r} entry is a "
                                 f"{dtype} array of shape {shape})")
    try:
        fmt = str(z["format"])
        kind = str(z["kind"])
        version = int(z["version"])
        meta = json.loads(str(z["meta"]))
    except ExabricksError:
        raise
    except RecursionError:
        raise ExabricksError(f"{where}: unreadable header (meta is nested too deeply)") from None
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


def world_bounds(obj: Kind) -> tuple[list[float], list[float]]:
    """World-space bounding box of the data (cells/bricks) or the structure (regions/bvh)."""
    if isinstance(obj, Cells):
        lo, hi = _cell_box(obj.lower_lattice, obj.level)
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


def _cell_box(lower, level, dims=None):
    """Lattice bounds of boxes of `dims` cells (one cell each without), in `rows` steps
    (the pages of mapped arrays handed back as it goes)."""
    if lower.size == 0:
        return lower[:0], lower[:0]
    lo, hi = [], []
    ones = np.ones((1, 3), np.int64)
    for _, (low, lv, *d) in rows(lower, level, *([] if dims is None else [dims])):
        width = (1 << lv.astype(np.int64))[:, None]
        lo.append(low.min(axis=0))
        hi.append((low.astype(np.int64) + (d[0] if d else ones) * width).max(axis=0))
    return np.min(lo, axis=0), np.max(hi, axis=0)


def summary(obj: Kind) -> dict[str, Any]:
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
