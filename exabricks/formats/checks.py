"""The checks of the file kinds: `validate` (dtypes and shapes, then every index
a kernel follows, in `rows` steps), and the checks `load` makes of the .npy
headers before any array is read (`check_declared`, `check_implied_sizes`).
"""

from __future__ import annotations

import numpy as np

from ..util.constants import LATTICE_DTYPE, MAX_LEVEL, MAX_TREE_DEPTH
from ..util.errors import ExabricksError, one_line, quoted
from .kinds import Bricks, Bvh, Cells, Kind, Regions
from .memory import reduce_chunks, rows


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
    check_field_names(obj.fields, where)
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


def field_names_problem(names) -> str | None:
    """What is wrong with a list of field names, or None: the one rule for a field
    name wherever one is given (a reader's, --name, --field, --derive NAME=...,
    a file's). A name is a non-empty string without control characters: a newline
    in one forged a line of `info`'s output, and an empty one names no field. No
    name may be given twice."""
    seen = set()
    for name in names:
        if not isinstance(name, str):
            return f"field name {quoted(name)} is not a string"
        if not name:
            return "a field name is empty"
        if one_line(name) != name:  # what an error line would escape
            return f"field name {quoted(name)} holds a control character"
        if name in seen:
            return f"field {quoted(name)} is given twice"
        seen.add(name)
    return None


def check_field_names(names, where: str) -> None:
    """ExabricksError `WHERE: problem` unless `field_names_problem` finds none."""
    problem = field_names_problem(names)
    if problem is not None:
        raise ExabricksError(f"{where}: {problem}")


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
    """A tree over the region index (check_tree), finite bounds, levels in range."""
    check_tree(obj.first, obj.count, obj.region_index.shape[0], where, "BVH", "region")
    _check_boxes(obj.lower_lattice, obj.upper_lattice, where, "BVH node")
    _check_levels(obj.finest_level, where, "BVH node")


def check_tree(first: np.ndarray, count: np.ndarray, n_items: int, where: str, tree: str,
               item: str) -> None:
    """A flat binary tree that a kernel may walk (the regions' BVH, a mesh BVH):
    children at larger indices than their parent, each node the child of exactly
    one parent (a tree: every walk ends), leaf ranges inside the `n_items` items
    and a depth the kernels' stacks hold. ExabricksError naming `where`."""
    m = first.shape[0]
    first = first.astype(np.int64)
    count = count.astype(np.int64)
    if count.size and count.min() < 0:
        i = int(np.argmin(count))
        raise ExabricksError(f"{where}: {tree} node {i} has a negative {item} count ({int(count[i])})")
    inner = np.flatnonzero(count == 0)
    leaf = np.flatnonzero(count > 0)
    if inner.size and (np.any(first[inner] <= inner) or np.any(first[inner] + 1 >= m)):
        i = int(inner[(first[inner] <= inner) | (first[inner] + 1 >= m)][0])
        raise ExabricksError(f"{where}: {tree} node {i} has children {int(first[i])}, "
                             f"{int(first[i]) + 1}: they must follow it and lie below {m}")
    if m:
        parents = np.bincount(np.concatenate([first[inner], first[inner] + 1]), minlength=m)
        bad = np.flatnonzero(parents[1:] != 1)
        if bad.size:
            i = int(bad[0]) + 1
            raise ExabricksError(f"{where}: {tree} node {i} is the child of {int(parents[i])} "
                                 "nodes (a tree has exactly one parent per node)")
    if leaf.size and (first[leaf].min() < 0 or (first[leaf] + count[leaf]).max() > n_items):
        raise ExabricksError(f"{where}: {tree} leaf ranges exceed the {n_items:,} {item}s")
    depth = tree_depth(first, count)
    if depth > MAX_TREE_DEPTH:
        raise ExabricksError(f"{where}: the {tree} is {depth} levels deep, more than the "
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


def check_declared(cls, headers: dict, n_fields: int, where: str) -> None:
    """Dtypes and shapes from the .npy headers against the schema, before reading."""
    stub = cls.__new__(cls)
    object.__setattr__(stub, "fields", tuple(f"f{i}" for i in range(n_fields)))
    for name, (shape, dtype) in headers.items():
        object.__setattr__(stub, name, np.lib.stride_tricks.as_strided(
            np.zeros(1, dtype), shape=shape, strides=(0,) * len(shape)))
    _check_shapes(stub, where)


def check_implied_sizes(cls, arrays: dict, headers: dict, where: str) -> None:
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
