"""Reorganise leaf cells into same-level, completely filled bricks (paper §3.1).

A top-down k-d partition of the cells: a node becomes a brick when all its cells
share one level, fill their bounding box and the box is at most
`max_brick_width` cells wide on every axis; otherwise it is split across the
longest axis of its bounding box at the middle, rounded to a multiple of the
node's coarsest cell width so that no cell is cut (paper §3.1.2).  The cells
are partitioned in place (like quicksort), so every brick ends up as one
contiguous run of the partitioned cell array; the bricks are those runs in
order, and because a brick is full its offset into the value array is simply
the start of its run.  A whole build then joins bricks of one level that fill a
box together (`merge_bricks`: the midpoint planes cut octree-like layouts into
many more bricks than their cells need).

The partition itself (its cell and node rows, splitting, the breadth-first top
and the depth-first subtrees) is exabricks.builders.cell_tree.
"""

from __future__ import annotations

import numba
import numpy as np

from .. import schema
from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_BRICK_WIDTH, OFFSET_DTYPE, VALUE_DTYPE
from ..util.errors import ExabricksError
from .cells import neighbour_overlap_keys, spread3, find_overlap
from .radix_sort import sort_keys
from ..formats.pieces import WHOLE, Piece, share_meta, task_range
from .cell_tree import END, ID, LEVEL, START, build_subtree, build_subtrees, build_top, pack, run_nodes, take_columns
from .piece_order import share_runs

# Below this many cells the build runs on one thread: the partition is already fast.
_PARALLEL_MIN_CELLS = 200_000
# Subtrees per thread for the depth-first parallel phase (more: better balance).
_TASKS_PER_THREAD = 16
# Subtrees per piece when a build is cut into pieces (exabricks.formats.pieces).
_TASKS_PER_PIECE = 16


@numba.njit(cache=True, parallel=True)
def _place(rec, starts, ends, lower, level, dims, source, clash):
    """Describe every brick and find where each cell's value goes.

    starts, ends: int64 (B,), run of each brick in `rec`.
    lower, dims:  int32 (B, 3) out, lattice corner and cells per axis.
    level:        int8 (B,) out.
    source:       int32 (N,) in: all -1; out: input index of the cell stored at each
                  value slot.
    clash:        int32 (B, 2) in: all -1; out, where two cells of brick b fall on
                  one slot: their input indices (the first such pair of the brick).

    A brick is a k-d leaf of one level whose cell count equals its box's volume, so
    its cells fill the box exactly unless two of them are the same cell (then one
    slot is hit twice and another is left empty).  That is the only overlap the
    partition can miss (cells of different levels that overlap are never separated
    by a plane, split_node's OVERLAP, and leaves are disjoint), so with this check the
    build refuses every overlap in one pass, at memory speed.
    """
    for b in numba.prange(starts.shape[0]):
        s = starts[b]
        e = ends[b]
        lvl = rec[s, LEVEL]
        lo0 = rec[s, 0]
        lo1 = rec[s, 1]
        lo2 = rec[s, 2]
        hi0 = lo0
        hi1 = lo1
        hi2 = lo2
        for p in range(s + 1, e):
            lo0 = min(lo0, rec[p, 0])
            lo1 = min(lo1, rec[p, 1])
            lo2 = min(lo2, rec[p, 2])
            hi0 = max(hi0, rec[p, 0])
            hi1 = max(hi1, rec[p, 1])
            hi2 = max(hi2, rec[p, 2])
        d0 = ((np.int64(hi0) - lo0) >> lvl) + 1
        d1 = ((np.int64(hi1) - lo1) >> lvl) + 1
        d2 = ((np.int64(hi2) - lo2) >> lvl) + 1
        lower[b, 0] = lo0
        lower[b, 1] = lo1
        lower[b, 2] = lo2
        level[b] = lvl
        dims[b, 0] = d0
        dims[b, 1] = d1
        dims[b, 2] = d2
        for p in range(s, e):
            i = (np.int64(rec[p, 0]) - lo0) >> lvl
            j = (np.int64(rec[p, 1]) - lo1) >> lvl
            k = (np.int64(rec[p, 2]) - lo2) >> lvl
            # x fastest, then y, then z (schema.Bricks).
            slot = s + i + d0 * (j + d1 * k)
            if source[slot] >= 0 and clash[b, 0] < 0:
                clash[b, 0] = source[slot]
                clash[b, 1] = rec[p, ID]
            source[slot] = rec[p, ID]


@numba.njit(cache=True, inline="always")
def _mix(h, v):
    """One step of a polynomial hash modulo 2**31 - 1 (no overflow in int64)."""
    return (h * 1000003 + (np.int64(v) & 0xFFFFFFFF)) % 2147483647


@numba.njit(cache=True, inline="always")
def _face_key(level, a, b, da, db, at):
    """Hash of a brick face: the level, the lower corner and dims on the two
    other axes, and the position along the merge axis."""
    return _mix(_mix(_mix(_mix(_mix(np.int64(level) + 1, a), b), da), db), at)


@numba.njit(cache=True, inline="always")
def _slot(key, mask):
    """Table slot of a face key (< 2**31): Fibonacci hashing, so that faces one cell
    apart, whose keys differ by one, do not fill neighbouring slots (linear probing
    on the raw key made 4.9 probes per lookup on the thin shells, this 1.9)."""
    return ((key * 2654435761) >> 24) & mask


@numba.njit(cache=True, parallel=True)
def _merge_runs(lower, level, dims, max_width):
    """The joins of `merge_bricks`: along x, then y, then z, bricks of one level with
    the same extent on the two other axes that touch face to face are joined, front
    to back, into runs of at most `max_width` cells.  Each pass finds every brick's
    successor through a hash table of the faces bricks start at.

    lower, dims: int32 (B, 3); level: int8 (B,).  Returns (owner, pos, lower, level,
    dims, m): for each input brick the joined brick holding it and its first
    cell's position there (cells, int32 (B,) and (B, 3)), and the m joined bricks
    (in the order of their runs' first bricks, not yet sorted)."""
    n = level.shape[0]
    size = 1
    while 3 * size < 4 * n:  # load factor at most 3/4
        size *= 2
    table = np.empty(size, np.int32)
    succ = np.empty(n, np.int32)
    has_pred = np.empty(n, np.bool_)
    new_id = np.empty(n, np.int32)
    shift = np.empty(n, np.int32)
    owner = np.arange(n).astype(np.int32)
    pos = np.zeros((n, 3), np.int32)
    cur = (lower.copy(), level.copy(), dims.copy())
    out = (np.empty_like(lower), np.empty_like(level), np.empty_like(dims))
    m = n
    for ax in range(3):
        lo, lv, d = cur
        o0 = (ax + 1) % 3
        o1 = (ax + 2) % 3
        used = 1
        while 3 * used < 4 * m:
            used *= 2
        mask = used - 1
        table[:used] = -1
        for b in range(m):  # every brick by the face it starts at (open addressing)
            h = _slot(_face_key(lv[b], lo[b, o0], lo[b, o1], d[b, o0], d[b, o1], lo[b, ax]), mask)
            while table[h] >= 0:
                h = (h + 1) & mask
            table[h] = b
        for b in numba.prange(m):  # the brick starting where b ends, if any
            succ[b] = -1
            has_pred[b] = False
            end = np.int64(lo[b, ax]) + (np.int64(d[b, ax]) << lv[b])
            h = _slot(_face_key(lv[b], lo[b, o0], lo[b, o1], d[b, o0], d[b, o1], end), mask)
            while table[h] >= 0:
                c = table[h]
                if (lv[c] == lv[b] and lo[c, ax] == end and lo[c, o0] == lo[b, o0]
                        and lo[c, o1] == lo[b, o1] and d[c, o0] == d[b, o0]
                        and d[c, o1] == d[b, o1]):
                    succ[b] = c
                    break
                h = (h + 1) & mask
        for b in range(m):
            if succ[b] >= 0:
                has_pred[succ[b]] = True
        olo, olv, od = out
        k = 0
        for b in range(m):  # runs from the bricks with no predecessor (chains never loop)
            if has_pred[b]:
                continue
            c = np.int64(b)
            while c >= 0:  # a run from c
                for a in range(3):
                    olo[k, a] = lo[c, a]
                    od[k, a] = d[c, a]
                olv[k] = lv[c]
                new_id[c] = k
                shift[c] = 0
                width = np.int64(d[c, ax])
                c = succ[c]
                while c >= 0 and width + d[c, ax] <= max_width:
                    new_id[c] = k
                    shift[c] = width
                    width += d[c, ax]
                    c = succ[c]
                od[k, ax] = width
                k += 1
        if k < m:
            for i in numba.prange(n):
                o = owner[i]
                pos[i, ax] += shift[o]
                owner[i] = new_id[o]
            cur, out = out, cur
            m = k
    lo, lv, d = cur
    return owner, pos, lo[:m].copy(), lv[:m].copy(), d[:m].copy(), m


@numba.njit(cache=True)
def _first_members(owner, m):
    """For each of m bricks, the least index of the bricks joined into it."""
    first = np.full(m, owner.shape[0], np.int64)
    for b in range(owner.shape[0] - 1, -1, -1):
        first[owner[b]] = b
    return first


@numba.njit(cache=True, parallel=True)
def _move_slots(dims, offset, owner, pos, new_dims, new_offset, payload, source, out):
    """out[:, new slot] = payload[:, source[old slot]] (no source: old slot) for bricks
    joined by `merge_bricks`."""
    for b in numba.prange(dims.shape[0]):
        f = owner[b]
        nx = np.int64(new_dims[f, 0])
        ny = np.int64(new_dims[f, 1])
        for z in range(dims[b, 2]):
            for y in range(dims[b, 1]):
                k = offset[b] + (np.int64(z) * dims[b, 1] + y) * dims[b, 0]
                row = new_offset[f] + ((pos[b, 2] + z) * ny + pos[b, 1] + y) * nx + pos[b, 0]
                for x in range(dims[b, 0]):
                    i = k + x if source is None else np.int64(source[k + x])
                    for c in range(payload.shape[0]):
                        out[c, row + x] = payload[c, i]


def merge_bricks(lower: np.ndarray, level: np.ndarray, dims: np.ndarray, offset: np.ndarray,
                 payload: np.ndarray, max_width: int, source: np.ndarray | None = None):
    """Join bricks of one level that together fill a box, at most `max_width`
    cells per axis: runs along x, then runs of those along y, then along z.

    The k-d partition (§3.1.2) only cuts at the middle of a node, so on octree-like
    layouts a block of same-level cells split by a plane that the other levels
    needed ends up in many small bricks; joining them again halves the bricks a
    sample sums there (docs/design-structures.md "Larger bricks").  A deterministic function
    of the bricks in order, so the joined shares of a build by pieces give what
    one build gives.  payload: (C, V) values; the value of a brick's slot s is
    payload[:, s], or payload[:, source[s]] when `source` (int32 (V,)) is given.
    Returns (lower, level, dims, offset, values): the joined bricks in the order
    of their first member, their values gathered.
    """
    owner, pos, *cur, m = _merge_runs(lower, level, dims, max_width)
    order = np.argsort(_first_members(owner, m), kind="stable")
    rank = np.empty(m, np.int32)
    rank[order] = np.arange(m, dtype=np.int32)
    new_lower, new_level, new_dims = (a[order] for a in cur)
    cells = new_dims.astype(np.int64).prod(axis=1)
    new_offset = np.zeros(m, OFFSET_DTYPE)
    np.cumsum(cells[:-1], out=new_offset[1:])
    out = np.empty((payload.shape[0], int(cells.sum())), payload.dtype)
    _move_slots(dims, offset, rank[owner], pos, new_dims, new_offset, payload, source, out)
    return new_lower, new_level, new_dims, new_offset, out


def _build_tasks(rec, tasks, width, brick_end) -> tuple[int, int]:
    """Build the subtrees below the node rows `tasks` in parallel, largest first,
    one at a time to whichever thread is free; (start, end) of a node whose cells
    overlap, or (-1, -1)."""
    if not tasks.shape[0]:
        return -1, -1
    order = np.argsort(tasks[:, START] - tasks[:, END], kind="stable")
    with numba.parallel_chunksize(1):
        overlap = build_subtrees(rec, np.ascontiguousarray(tasks[order]), width, brick_end)
    found = np.flatnonzero(overlap[:, 0] >= 0)
    return (int(overlap[found[0], 0]), int(overlap[found[0], 1])) if found.size else (-1, -1)


def build_bricks(cells: schema.Cells, *, max_brick_width: int = MAX_BRICK_WIDTH,
                 piece: Piece = WHOLE) -> schema.Bricks:
    """Bricks of same-level cells that completely fill their box (paper §3.1).

    cells: schema.Cells with N >= 1 non-overlapping cells.
    max_brick_width: most cells per axis of a brick (the paper uses 32).
    piece: build only this share (exabricks.formats.pieces): the bricks of one
        run of the partitioned cells, offsets from 0, values of those cells only;
        meta["piece"]["cells"] is the run, [a, b) of N.
    Returns schema.Bricks in k-d leaf order (whole builds: joined by `merge_bricks`,
    in the order of their first k-d leaf), with the same fields and world
    frame; its values hold every cell's values once (V == N).  meta holds
    "statistics" (see `statistics`), for the command to merge into its meta.
    Raises ExabricksError for no cells, a width below 1, or overlapping cells.
    """
    if max_brick_width < 1:
        raise ExabricksError(f"max brick width must be at least 1, got {max_brick_width}")
    n = cells.n_cells
    if n == 0:
        raise ExabricksError("no cells")
    if n >= np.iinfo(np.int32).max:
        raise ExabricksError(f"{n} cells: at most {np.iinfo(np.int32).max - 1} are supported")
    threads = numba.get_num_threads()
    width = np.int64(max_brick_width)
    runs = share_runs(cells, piece, max_brick_width)
    if runs is not None:
        # Cells in piece order (exabricks.builders.piece_order): read and check the
        # share's cells only, and build the subtrees of its runs.
        a, b = int(runs[0]), int(runs[-1])
        cells = cells.replace(lower_lattice=cells.lower_lattice[a:b], level=cells.level[a:b],
                              values=cells.values[:, a:b])
        schema.validate(cells, f"the cells from {a} (piece {piece.index}/{piece.count})")
        base, lo, hi = a, 0, b - a  # cell ids in rec count from a; the share is rec[lo:hi]
        rec, _ = pack(cells.lower_lattice, cells.level, 4 * threads)
        brick_end = np.full(hi, -1, np.int32)
        s, e = _build_tasks(rec, run_nodes(rec, runs - a), width, brick_end)
    else:
        rec, root = pack(cells.lower_lattice, cells.level, 4 * threads)  # mapped pages handed back
        brick_end = np.full(n, -1, np.int32)
        base, lo, hi = 0, 0, n
        a, b = 0, n  # the run of cells this share holds
        if not piece.whole or (threads > 1 and n >= _PARALLEL_MIN_CELLS):
            # Split the top of the tree level by level, then build the subtrees in parallel.
            # Pieces cut the same top whatever their thread counts (the bricks do not
            # depend on where the top ends: a node's split depends on its cells alone).
            target = threads * _TASKS_PER_THREAD if piece.whole else _TASKS_PER_PIECE * piece.count
            pending, s, e = build_top(rec, root, width, brick_end, target)
            if not piece.whole and s < 0:
                # Tasks are in cell order: task t owns the cells from its start to the
                # next task's (with the bricks the top finished in between).
                bounds = np.concatenate([[0], pending[1:, START], [n]])
                t0, t1 = task_range(np.diff(bounds), piece)
                a, b = lo, hi = int(bounds[t0]), int(bounds[t1])
                pending = pending[t0:t1]
            if s < 0:
                s, e = _build_tasks(rec, pending, width, brick_end)
        else:
            s, e = build_subtree(rec, root[0], width, brick_end)
    if s >= 0:
        raise ExabricksError(_overlap_message(rec[s:e], base))

    starts = np.flatnonzero(brick_end[lo:hi] >= 0)
    ends = brick_end[lo:hi][starts].astype(np.int64) - lo
    nb = starts.shape[0]
    lower = np.empty((nb, 3), LATTICE_DTYPE)
    level = np.empty(nb, LEVEL_DTYPE)
    dims = np.empty((nb, 3), LATTICE_DTYPE)
    source = np.full(hi - lo, -1, np.int32)
    clash = np.full((nb, 2), -1, np.int32)
    # Checked at ingest too, but a cells file can be edited after it.
    _place(rec[lo:hi], starts.astype(np.int64), ends, lower, level, dims, source, clash)
    del rec, brick_end
    schema.trim_heap()
    bad = np.flatnonzero(clash[:, 0] >= 0)
    if bad.size:
        i, j = (int(k) for k in clash[bad[0]])
        low, lv = cells.lower_lattice, cells.level
        raise ExabricksError(f"cells overlap: cell {base + j} at {low[j].tolist()} level "
                             f"{int(lv[j])} and cell {base + i} at {low[i].tolist()} level {int(lv[i])}")
    offset = starts.astype(OFFSET_DTYPE)
    values = np.ascontiguousarray(cells.values, dtype=VALUE_DTYPE)
    if piece.whole:  # shares are joined by `exabricks join` (exabricks.builders.join)
        lower, level, dims, offset, values = merge_bricks(lower, level, dims, offset, values,
                                                          max_brick_width, source)
    else:
        values = take_columns(values, source)
    schema.release_arrays(cells.values)
    return schema.Bricks(
        fields=cells.fields, origin_world=cells.origin_world, spacing_world=cells.spacing_world,
        meta={"statistics": statistics(level, dims),
              **share_meta(piece, cells=[a, b], n_cells=n, max_brick_width=max_brick_width)},
        lower_lattice=lower, level=level, dims=dims, offset=offset, values=values,
    )


def require_disjoint(bricks: schema.Bricks, ids: np.ndarray | None = None) -> None:
    """ExabricksError naming two bricks that share a cell, if any (O(N log N) in the
    cells, through the Morton-order check of exabricks.stages.ingest); with `ids`
    (int (K,)), among those bricks only.

    Each cell is one uint64 key, its Morton code above its brick's id, sorted in
    place: 8 bytes a cell and no per-cell corner or level arrays (bricks may be
    mapped, schema.load(mapped=True)).  Lattices too wide for one key take the
    per-cell path."""
    lower, level, dims = bricks.lower_lattice, bricks.level, bricks.dims
    if ids is not None:
        lower, level, dims = lower[ids], level[ids], dims[ids]
    n = level.shape[0]
    if n < 2:
        return
    sizes = dims.astype(np.int64).prod(axis=1)
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])  # the values' order, as validated
    n_cells = int(sizes.sum())
    lmin, lmax = int(level.min()), int(level.max())
    cmin, cmax = _brick_corner_range(lower, level, dims)
    cmin = (cmin >> lmax) << lmax  # as in find_overlap: every cell stays aligned
    bits = max(int(((cmax - cmin) >> lmin).max()).bit_length(), 1)
    id_bits = max(int(n - 1).bit_length(), 1)
    if 3 * bits + id_bits <= 64:
        keys = sort_keys(_brick_keys(lower, level, dims, offset, n_cells, cmin, lmin, np.uint64(id_bits)),
                         3 * bits + id_bits)
        a, b = neighbour_overlap_keys(keys, np.uint64(id_bits), level, lmin)
        pair = None if a < 0 else (int(a), int(b))
    else:
        cell_lower, cell_level = brick_cells(lower, level, dims, offset, n_cells)
        pair = find_overlap(cell_lower, cell_level)
        if pair is not None:
            pair = tuple(int(np.searchsorted(offset, i, side="right")) - 1 for i in pair)
    if pair is not None:
        a, b = pair if ids is None else (int(ids[pair[0]]), int(ids[pair[1]]))
        raise ExabricksError(f"bricks overlap: brick {b} at {bricks.lower_lattice[b].tolist()} "
                             f"and brick {a} at {bricks.lower_lattice[a].tolist()} share a cell")


@numba.njit(cache=True)
def _brick_corner_range(lower, level, dims):
    """Per-axis min and max over the bricks' cell corners, int64 (3,) each."""
    lo = np.full(3, np.int64(1) << 62)
    hi = np.full(3, -(np.int64(1) << 62))
    for b in range(level.shape[0]):
        w = np.int64(1) << np.int64(level[b])
        for a in range(3):
            lo[a] = min(lo[a], np.int64(lower[b, a]))
            hi[a] = max(hi[a], np.int64(lower[b, a]) + (np.int64(dims[b, a]) - 1) * w)
    return lo, hi


@numba.njit(cache=True, parallel=True)
def _brick_keys(lower, level, dims, offset, n_cells, cmin, lmin, id_bits):
    """(Morton code of each cell's corner relative to cmin, in units of 2**lmin)
    << id_bits | its brick's id: uint64 (n_cells,), in value order."""
    out = np.empty(n_cells, np.uint64)
    for b in numba.prange(level.shape[0]):
        w = np.int64(1) << np.int64(level[b])
        i = offset[b]
        for z in range(dims[b, 2]):
            mz = spread3(np.uint64((np.int64(lower[b, 2]) + z * w - cmin[2]) >> lmin))
            for y in range(dims[b, 1]):
                my = spread3(np.uint64((np.int64(lower[b, 1]) + y * w - cmin[1]) >> lmin))
                for x in range(dims[b, 0]):
                    mx = spread3(np.uint64((np.int64(lower[b, 0]) + x * w - cmin[0]) >> lmin))
                    m = mx | (my << np.uint64(1)) | (mz << np.uint64(2))
                    out[i] = (m << id_bits) | np.uint64(b)
                    i += 1
    return out


@numba.njit(cache=True, parallel=True)
def brick_cells(lower, level, dims, offset, n_cells):
    """The cells of every brick, in value order: lower corners int32 (N, 3), levels int8 (N,)."""
    out_lower = np.empty((n_cells, 3), np.int32)
    out_level = np.empty(n_cells, np.int8)
    for b in numba.prange(lower.shape[0]):
        w = np.int32(1) << np.int32(level[b])
        i = offset[b]
        for z in range(dims[b, 2]):
            for y in range(dims[b, 1]):
                for x in range(dims[b, 0]):
                    out_lower[i, 0] = lower[b, 0] + x * w
                    out_lower[i, 1] = lower[b, 1] + y * w
                    out_lower[i, 2] = lower[b, 2] + z * w
                    out_level[i] = level[b]
                    i += 1
    return out_lower, out_level


def statistics(level: np.ndarray, dims: np.ndarray) -> dict:
    """Brick counts for meta: bricks, bricks per level, cells per brick.

    level: int8 (B,); dims: int32 (B, 3).  `cells_per_brick_histogram` lists
    [k, count] pairs for the powers of two k: count bricks hold k <= cells < 2k
    (a list, so that it stays in order in sorted JSON).
    """
    cells = dims.astype(np.int64).prod(axis=1)
    per_level = np.bincount(level.astype(np.int64))
    bins = np.bincount(np.floor(np.log2(np.maximum(cells, 1))).astype(np.int64))
    return {
        "bricks": int(level.shape[0]),
        "cells": int(cells.sum()),
        "bricks_per_level": {str(l): int(c) for l, c in enumerate(per_level) if c},
        "cells_per_brick_histogram": [[1 << k, int(c)] for k, c in enumerate(bins) if c],
        "mean_cells_per_brick": float(cells.mean()) if cells.size else 0.0,
        "max_cells_per_brick": int(cells.max()) if cells.size else 0,
    }


def _overlap_message(run: np.ndarray, base: int = 0) -> str:
    """Name two overlapping cells of a node that no plane can split (int32 (n, 5) rows
    whose cell ids count from `base`)."""
    coarse = int(np.argmax(run[:, LEVEL]))
    other = 1 if coarse == 0 else 0
    a, b = run[coarse], run[other]
    return (
        f"cells overlap: cell {base + int(a[ID])} at {a[:3].tolist()} level {int(a[LEVEL])} and "
        f"cell {base + int(b[ID])} at {b[:3].tolist()} level {int(b[LEVEL])}"
    )
