"""The cell contract (DESIGN.md "Cells and coordinates"), checked: at least one
cell, levels in 0..MAX_LEVEL, lower corners that are multiples of the cell
width, no two cells covering the same space (found in O(N log N) by Morton
order), and a chosen treatment of non-finite values; and the statistics of a
cells file's meta."""

from __future__ import annotations

import numba
import numpy as np

from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, NAN_POLICIES, VALUE_DTYPE
from ..util.errors import ExabricksError
from ..schema import Cells, check_field_names, first_misaligned
from .radix_sort import sort_keys


def validate_cells(cells: Cells, *, source: str, nan_policy: str = "error") -> Cells:
    """Check `cells` against the cell contract; return them (with non-finite values handled).

    cells.lower_lattice: int32 (N, 3), lower corners in finest-cell units.
    cells.level:         int8 (N,), 0 finest; width 2**level lattice units.
    cells.values:        float32 (F, N).
    source: the input's name, used in every message.
    nan_policy: one of NAN_POLICIES (see there).

    Raises ExabricksError naming `source`, the first offending cell index and its
    coordinates.  Overlap is found in O(N log N): aligned cells are octree nodes,
    so two overlap only if one contains the other; sorted by the Morton code of
    their lower corners, every cell occupies the code interval
    [code, code + 8**level), these intervals nest or are disjoint, and an
    overlap therefore shows up between two neighbours in that order.
    """
    if nan_policy not in NAN_POLICIES:
        raise ExabricksError(
            f"unknown NaN policy {nan_policy!r} (choose from {', '.join(NAN_POLICIES)})"
        )
    check_field_names(cells.fields, source)  # a reader's, --name's, a derived field's
    n = cells.n_cells
    if n == 0:
        raise ExabricksError(f"{source}: no cells (empty input)")
    lower = cells.lower_lattice
    level = cells.level
    if lower.dtype != LATTICE_DTYPE or lower.shape != (n, 3):
        raise ExabricksError(f"{source}: cell corners must be int32 (N, 3), got {lower.dtype} {lower.shape}")
    if level.dtype != LEVEL_DTYPE:
        raise ExabricksError(f"{source}: cell levels must be int8, got {level.dtype}")

    i = _first_bad_level(level, MAX_LEVEL)
    if i >= 0:
        raise ExabricksError(
            f"{source}: cell {i} at {lower[i].tolist()} has level {int(level[i])}, "
            f"outside 0..{MAX_LEVEL}"
        )
    i = first_misaligned(lower, level)
    if i >= 0:
        w = 1 << int(level[i])
        raise ExabricksError(
            f"{source}: cell {i} at {lower[i].tolist()} (level {int(level[i])}) is misaligned: "
            f"its corner must be a multiple of its width {w}"
        )

    cells = _handle_nonfinite(cells, source, nan_policy)
    if cells.n_cells == 0:
        raise ExabricksError(f"{source}: no cells left after dropping non-finite values")

    pair = find_overlap(cells.lower_lattice, cells.level)
    if pair is not None:
        a, b = pair
        lo, lv = cells.lower_lattice, cells.level
        what = "duplicates" if lv[a] == lv[b] else "overlaps"
        raise ExabricksError(
            f"{source}: cell {b} at {lo[b].tolist()} (level {int(lv[b])}) {what} "
            f"cell {a} at {lo[a].tolist()} (level {int(lv[a])})"
        )
    return cells


def _handle_nonfinite(cells: Cells, source: str, policy: str) -> Cells:
    values = cells.values
    if policy == "keep" or values.size == 0:
        return cells
    finite = np.isfinite(values)
    if finite.all():
        return cells
    if policy == "error":
        f = int(np.flatnonzero(~finite.all(axis=1))[0])
        i = int(np.flatnonzero(~finite[f])[0])
        raise ExabricksError(
            f"{source}: field {cells.fields[f]!r} is {values[f, i]} at cell {i} "
            f"(at {cells.lower_lattice[i].tolist()}, level {int(cells.level[i])}); "
            f"choose --nan zero, drop or keep to accept non-finite values"
        )
    if policy == "zero":
        return cells.replace(values=np.where(finite, values, np.float32(0)).astype(VALUE_DTYPE))
    keep = finite.all(axis=0)
    return cells.replace(
        lower_lattice=np.ascontiguousarray(cells.lower_lattice[keep]),
        level=np.ascontiguousarray(cells.level[keep]),
        values=np.ascontiguousarray(cells.values[:, keep]),
    )


@numba.njit(cache=True)
def _first_bad_level(level, max_level):
    for i in range(level.shape[0]):
        if level[i] < 0 or level[i] > max_level:
            return i
    return -1


def find_overlap(lower: np.ndarray, level: np.ndarray) -> tuple[int, int] | None:
    """A pair (a, b), a < b, of overlapping cells, or None if all cells are disjoint.

    lower: int32 (N, 3) lower corners, aligned to their level (checked before).
    level: int8 (N,) levels >= 0.
    Among the overlaps found between Morton-order neighbours, the one with the
    smallest b is returned, so a cell that repeats an earlier one is named.
    """
    n = level.shape[0]
    if n < 2:
        return None
    lmin = int(level.min())
    lmax = int(level.max())
    cmin, cmax = _corner_range(lower)
    # Corners relative to a base that is a multiple of the coarsest width, so that every
    # cell stays aligned to its own level (the Morton intervals then nest), in units
    # of the finest width present (exact: every corner is a multiple of 2**lmin).
    cmin = (cmin >> lmax) << lmax
    bits = max(int(((cmax - cmin) >> lmin).max()).bit_length(), 1)
    index_bits = max(int(n - 1).bit_length(), 1)
    if 3 * bits + index_bits <= 64:
        # Morton code and cell index packed in one uint64: sorting plain keys is
        # several times faster than np.argsort, and ties stay in index order.
        keys = sort_keys(_packed_morton(lower, cmin, lmin, np.uint64(index_bits)), 3 * bits + index_bits)
        a, b = neighbour_overlap_keys(keys, np.uint64(index_bits), level, lmin)
    else:
        hi, lo = _morton96(lower, cmin, lmin)
        order = np.lexsort((np.arange(n), lo, hi))
        a, b = _neighbour_overlap(order, lower, level)
    return None if a < 0 else (int(a), int(b))


@numba.njit(cache=True)
def _corner_range(lower):
    """Per-axis min and max of the corners, int64 (3,) each."""
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for a in range(3):
        lo[a] = lower[0, a]
        hi[a] = lower[0, a]
    for i in range(lower.shape[0]):
        for a in range(3):
            v = np.int64(lower[i, a])
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
    return lo, hi


@numba.njit(cache=True, inline="always")
def spread3(v):
    """Bits 0..20 of v moved to positions 0, 3, 6, ... (uint64)."""
    x = v & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@numba.njit(cache=True, inline="always")
def _rel(lower, i, a, cmin, lmin):
    return np.uint64((np.int64(lower[i, a]) - cmin[a]) >> lmin)


@numba.njit(cache=True)
def _packed_morton(lower, cmin, lmin, index_bits):
    """(Morton code of the relative corner << index_bits) | cell index, uint64 (N,)."""
    n = lower.shape[0]
    out = np.empty(n, np.uint64)
    for i in range(n):
        m = (spread3(_rel(lower, i, 0, cmin, lmin))
             | (spread3(_rel(lower, i, 1, cmin, lmin)) << np.uint64(1))
             | (spread3(_rel(lower, i, 2, cmin, lmin)) << np.uint64(2)))
        out[i] = (m << index_bits) | np.uint64(i)
    return out


@numba.njit(cache=True)
def _morton96(lower, cmin, lmin):
    """Morton codes of up to 32-bit relative corners as (high 33 bits, low 63 bits)."""
    n = lower.shape[0]
    hi = np.empty(n, np.uint64)
    lo = np.empty(n, np.uint64)
    s = np.uint64(21)
    for i in range(n):
        x = _rel(lower, i, 0, cmin, lmin)
        y = _rel(lower, i, 1, cmin, lmin)
        z = _rel(lower, i, 2, cmin, lmin)
        lo[i] = spread3(x) | (spread3(y) << np.uint64(1)) | (spread3(z) << np.uint64(2))
        hi[i] = (spread3(x >> s) | (spread3(y >> s) << np.uint64(1))
                 | (spread3(z >> s) << np.uint64(2)))
    return hi, lo


@numba.njit(cache=True)
def neighbour_overlap_keys(keys, index_bits, level, lmin):
    """`_neighbour_overlap` on sorted packed keys: a cell of level l spans 8**(l - lmin) codes."""
    best_a, best_b = -1, -1
    mask = (np.uint64(1) << index_bits) - np.uint64(1)
    for t in range(keys.shape[0] - 1):
        p = np.int64(keys[t] & mask)
        q = np.int64(keys[t + 1] & mask)
        span = np.uint64(1) << np.uint64(3 * (level[p] - lmin))
        if (keys[t + 1] >> index_bits) - (keys[t] >> index_bits) < span:
            a, b = min(p, q), max(p, q)
            if best_b < 0 or b < best_b or (b == best_b and a < best_a):
                best_a, best_b = a, b
    return best_a, best_b


@numba.njit(cache=True)
def _neighbour_overlap(order, lower, level):
    """(a, b) with a < b: the Morton neighbours whose boxes intersect, smallest b first."""
    best_a, best_b = -1, -1
    for t in range(order.shape[0] - 1):
        p, q = order[t], order[t + 1]
        # p comes first in Morton order, so it either contains q's corner or they are
        # disjoint (a container never sorts after a cell it contains, except at an
        # equal corner, where q's corner is p's corner).
        w = np.int64(1) << np.int64(level[p])
        inside = True
        for ax in range(3):
            d = np.int64(lower[q, ax]) - np.int64(lower[p, ax])
            if d < 0 or d >= w:
                inside = False
                break
        if inside:
            a, b = min(p, q), max(p, q)
            if best_b < 0 or b < best_b or (b == best_b and a < best_a):
                best_a, best_b = a, b
    return best_a, best_b


def cell_statistics(cells: Cells) -> dict:
    """Counts for the provenance record: cells, cells per level, levels, lattice bounds.

    One pass over the cells (vectorised NumPy with int64 temporaries takes seconds
    at 2e7 cells).  bounds_lattice: [[x, y, z] lower, [x, y, z] upper], upper exclusive.
    """
    counts, lo, hi = _level_counts_bounds(cells.lower_lattice, cells.level, MAX_LEVEL)
    return {
        "cells": cells.n_cells,
        "cells_per_level": {str(l): int(c) for l, c in enumerate(counts) if c},
        "levels": int(np.count_nonzero(counts)),
        "bounds_lattice": [lo.tolist(), hi.tolist()] if cells.n_cells else [],
    }


@numba.njit(cache=True)
def _level_counts_bounds(lower, level, max_level):
    counts = np.zeros(max_level + 1, np.int64)
    lo = np.full(3, np.iinfo(np.int64).max, np.int64)
    hi = np.full(3, np.iinfo(np.int64).min, np.int64)
    for i in range(level.shape[0]):
        counts[level[i]] += 1
        w = np.int64(1) << np.int64(level[i])
        for a in range(3):
            c = np.int64(lower[i, a])
            lo[a] = min(lo[a], c)
            hi[a] = max(hi[a], c + w)
    return counts, lo, hi
