"""The k-d partition of leaf cells that `brick` builds (paper §3.1.2) and that
`ingest` orders its cells by (exabricks.builders.piece_order).

A node is split across the longest axis of its bounding box at the middle,
rounded to a multiple of the node's coarsest cell width so that no cell is
cut; it becomes a leaf (a brick) when all its cells share one level, fill their
bounding box and the box is at most `max_width` cells wide on every axis.  A
node's split depends on its cells alone, so the leaves do not depend on the
order of the cells, nor on where a build stops splitting breadth first and
goes on depth first.

Each cell is one row of an int32 (N, 5) array `rec`: lower corner x, y, z
(lattice units), level, and the cell's index in the input.  A node is one
int64 row of 10: start and end of its run in `rec`, the lower and upper corner
of its bounding box (lattice units, upper exclusive), and its finest and
coarsest level.  The cells are partitioned in place (like quicksort), so every
node is one contiguous run of `rec`; partitioning a node computes both
children's rows in the same pass, so each tree level reads every cell once.
"""

from __future__ import annotations

import numba
import numpy as np

from ..formats.memory import discard, mapping

# Columns of a cell row in `rec` and fields of a node row.
LEVEL, ID = 3, 4
START, END = 0, 1
NODE_SIZE = 10
# Outcomes of split_node.
LEAF, SPLIT, OVERLAP = 0, 1, -1
# Rows per step of `pack` (48 MiB of corners).
PACK_STEP = 1 << 22


@numba.njit(cache=True, inline="always")
def _grow(st, x, y, z, level):
    """Add one cell to node statistics (lo xyz, hi xyz, finest, coarsest level)."""
    w = np.int64(1) << level
    return (min(st[0], x), min(st[1], y), min(st[2], z),
            max(st[3], x + w), max(st[4], y + w), max(st[5], z + w),
            min(st[6], level), max(st[7], level))


@numba.njit(cache=True, inline="always")
def _empty_stats():
    big = np.int64(1) << 62
    return (big, big, big, -big, -big, -big, np.int64(127), np.int64(-1))


@numba.njit(cache=True, inline="always")
def _store(nodes, t, start, end, st):
    nodes[t, 0] = start
    nodes[t, 1] = end
    for a in range(8):
        nodes[t, 2 + a] = st[a]


def pack(lower, level, chunks, discard_input=False):
    """Cell rows and the root node row, in steps of PACK_STEP rows (each in
    `chunks` parallel parts).

    lower: int32 (N, 3); level: int8 (N,).  Returns rec, int32 (N, 5) (x, y, z,
    level, input index), and the root node row, int64 (1, 10).  After each step
    the input's pages are handed back when it is mapped, and with
    `discard_input` also when it is in memory (its contents are then gone,
    schema.discard): so that the rows and the whole input are never resident
    together."""
    n = level.shape[0]
    rec = np.empty((n, 5), np.int32)
    parts = []
    for a in range(0, max(n, 1), PACK_STEP):
        lo, lv = lower[a:a + PACK_STEP], level[a:a + PACK_STEP]
        parts.append(_pack_rows(lo, lv, rec[a:a + PACK_STEP], a, chunks))
        for part in (lo, lv):
            if discard_input or mapping(part) is not None:
                discard(part)
    part = np.concatenate(parts)
    root = np.empty((1, NODE_SIZE), np.int64)
    root[0, START], root[0, END] = 0, n
    # lower corner and finest level are minima, the rest maxima
    root[0, 2:] = [part[:, a].min() if a < 3 or a == 6 else part[:, a].max() for a in range(8)]
    return rec, root


@numba.njit(cache=True, parallel=True)
def _pack_rows(lower, level, rec, first, chunks):
    """Fill `rec` (int32 (n, 5)) with the rows of cells first.. from lower (int32 (n, 3))
    and level (int8 (n,)); returns each part's statistics, int64 (chunks, 8)."""
    n = level.shape[0]
    part = np.empty((chunks, 8), np.int64)
    for c in numba.prange(chunks):
        st = _empty_stats()
        for p in range(c * n // chunks, (c + 1) * n // chunks):
            rec[p, 0] = lower[p, 0]
            rec[p, 1] = lower[p, 1]
            rec[p, 2] = lower[p, 2]
            rec[p, 3] = level[p]
            rec[p, 4] = first + p
            st = _grow(st, np.int64(lower[p, 0]), np.int64(lower[p, 1]),
                       np.int64(lower[p, 2]), np.int64(level[p]))
        for a in range(8):
            part[c, a] = st[a]
    return part


@numba.njit(cache=True)
def split_node(rec, nodes, t, max_width, brick_end):
    """Make node `nodes[t]` a brick or split it into `nodes[t]` and `nodes[t + 1]`.

    rec:       int32 (N, 5) cell rows, partitioned in place over the node's run.
    nodes:     int64 (M, 10) node rows; row t + 1 must exist.
    brick_end: int32 (N,), set to the run's end at a leaf's start.
    Returns LEAF, SPLIT, or OVERLAP when no plane separates the cells, which
    only happens when cells overlap (the node's box is then its coarsest cell).
    """
    s = nodes[t, 0]
    e = nodes[t, 1]
    lmin = nodes[t, 8]
    lmax = nodes[t, 9]
    n = e - s
    if lmin == lmax:
        # Leaf test of §3.1.2: one level, full box, at most max_width cells per axis.
        d0 = (nodes[t, 5] - nodes[t, 2]) >> lmin
        d1 = (nodes[t, 6] - nodes[t, 3]) >> lmin
        d2 = (nodes[t, 7] - nodes[t, 4]) >> lmin
        if d0 <= max_width and d1 <= max_width and d2 <= max_width:
            # d0 * d1 <= n first, so that the triple product cannot overflow.
            if d0 * d1 <= n and d0 * d1 * d2 == n:
                brick_end[s] = e
                return LEAF
    # Split the longest axis at its middle rounded to a multiple of the coarsest
    # width W: every cell is W-aligned at that plane, so none is cut (§3.1.2).
    # A plane strictly inside the box always has cells on both sides.
    big_w = np.int64(1) << lmax
    ext0 = nodes[t, 5] - nodes[t, 2]
    ext1 = nodes[t, 6] - nodes[t, 3]
    ext2 = nodes[t, 7] - nodes[t, 4]
    axis = -1
    pos = np.int64(0)
    first = _first_axis(ext0, ext1, ext2)
    second = _second_axis(ext0, ext1, ext2)
    for attempt in range(3):
        # Axes in order of decreasing extent (ties: x before y before z).  For
        # cells that do not overlap the longest axis always has a plane.
        a = first if attempt == 0 else (second if attempt == 1 else 3 - first - second)
        lo = nodes[t, 2 + a]
        hi = nodes[t, 5 + a]
        mid = (lo + hi) >> 1
        # Nearest multiple of W (ties up); at a box edge, one W further inside.
        p = ((mid + (big_w >> 1)) >> lmax) << lmax
        if p <= lo:
            p += big_w
        if p >= hi:
            p -= big_w
        if lo < p < hi:
            axis = a
            pos = p
            break
    if axis < 0:
        return OVERLAP
    # Hoare partition on rec[:, axis] < pos, accumulating both children's rows.
    left = _empty_stats()
    right = _empty_stats()
    i = s
    j = e - 1
    while True:
        while i <= j and rec[i, axis] < pos:
            left = _grow(left, np.int64(rec[i, 0]), np.int64(rec[i, 1]),
                         np.int64(rec[i, 2]), np.int64(rec[i, 3]))
            i += 1
        while i <= j and rec[j, axis] >= pos:
            right = _grow(right, np.int64(rec[j, 0]), np.int64(rec[j, 1]),
                          np.int64(rec[j, 2]), np.int64(rec[j, 3]))
            j -= 1
        if i > j:
            break
        for c in range(5):
            tmp = rec[i, c]
            rec[i, c] = rec[j, c]
            rec[j, c] = tmp
        left = _grow(left, np.int64(rec[i, 0]), np.int64(rec[i, 1]),
                     np.int64(rec[i, 2]), np.int64(rec[i, 3]))
        right = _grow(right, np.int64(rec[j, 0]), np.int64(rec[j, 1]),
                      np.int64(rec[j, 2]), np.int64(rec[j, 3]))
        i += 1
        j -= 1
    _store(nodes, t, s, i, left)
    _store(nodes, t + 1, i, e, right)
    return SPLIT


@numba.njit(cache=True, inline="always")
def _first_axis(e0, e1, e2):
    if e0 >= e1 and e0 >= e2:
        return 0
    return 1 if e1 >= e2 else 2


@numba.njit(cache=True, inline="always")
def _second_axis(e0, e1, e2):
    first = _first_axis(e0, e1, e2)
    if first == 0:
        return 1 if e1 >= e2 else 2
    if first == 1:
        return 0 if e0 >= e2 else 2
    return 0 if e0 >= e1 else 1


@numba.njit(cache=True)
def build_subtree(rec, node, max_width, brick_end):
    """Build every brick below one node, depth first with an explicit stack.

    node: int64 (10,) node row.  Returns (start, end) of a node whose cells
    overlap, or (-1, -1).
    """
    stack = np.empty((256, NODE_SIZE), np.int64)
    stack[0] = node
    top = 1
    while top > 0:
        top -= 1
        if top + 2 > stack.shape[0]:
            bigger = np.empty((2 * stack.shape[0], NODE_SIZE), np.int64)
            bigger[: stack.shape[0]] = stack
            stack = bigger
        outcome = split_node(rec, stack, top, max_width, brick_end)
        if outcome == SPLIT:
            top += 2
        elif outcome == OVERLAP:
            return stack[top, 0], stack[top, 1]
    return np.int64(-1), np.int64(-1)


@numba.njit(cache=True, parallel=True)
def build_top(rec, root, max_width, brick_end, target):
    """Split breadth first, the nodes of each tree level in parallel, until at
    least `target` nodes are unfinished.

    root: int64 (1, 10).  Returns the unfinished nodes, int64 (K, 10), and the
    (start, end) of a node whose cells overlap, or (-1, -1).
    """
    current = root.copy()
    while 0 < current.shape[0] < target:
        k_nodes = current.shape[0]
        following = np.empty((2 * k_nodes, NODE_SIZE), np.int64)
        outcome = np.empty(k_nodes, np.int64)
        for k in numba.prange(k_nodes):
            for a in range(NODE_SIZE):
                following[2 * k, a] = current[k, a]
            outcome[k] = split_node(rec, following, 2 * k, max_width, brick_end)
        m = 0
        for k in range(k_nodes):
            if outcome[k] == OVERLAP:
                return current, current[k, 0], current[k, 1]
            if outcome[k] == SPLIT:
                m += 2
        current = np.empty((m, NODE_SIZE), np.int64)
        m = 0
        for k in range(k_nodes):
            if outcome[k] == SPLIT:
                current[m] = following[2 * k]
                current[m + 1] = following[2 * k + 1]
                m += 2
    return current, np.int64(-1), np.int64(-1)


@numba.njit(cache=True, parallel=True)
def build_subtrees(rec, tasks, max_width, brick_end):
    """Build the subtrees below the node rows `tasks` (int64 (K, 10)) in parallel.

    Returns int64 (K, 2): per task, (start, end) of an overlapping node or -1.
    """
    overlap = np.empty((tasks.shape[0], 2), np.int64)
    for k in numba.prange(tasks.shape[0]):
        s, e = build_subtree(rec, tasks[k], max_width, brick_end)
        overlap[k, 0] = s
        overlap[k, 1] = e
    return overlap


@numba.njit(cache=True, parallel=True)
def run_nodes(rec, bounds):
    """The node rows, int64 (K, 10), of the runs [bounds[k], bounds[k + 1]) of
    `rec` (bounds: int64 (K + 1,), increasing), each run's box and levels
    computed from its own cells."""
    nodes = np.empty((bounds.shape[0] - 1, NODE_SIZE), np.int64)
    for k in numba.prange(bounds.shape[0] - 1):
        st = _empty_stats()
        for p in range(bounds[k], bounds[k + 1]):
            st = _grow(st, np.int64(rec[p, 0]), np.int64(rec[p, 1]), np.int64(rec[p, 2]),
                       np.int64(rec[p, 3]))
        _store(nodes, k, bounds[k], bounds[k + 1], st)
    return nodes


@numba.njit(cache=True, parallel=True)
def take_columns(values, source):
    """values[:, source]: float32 (F, M) from float32 (F, N) and int32 (M,)."""
    out = np.empty((values.shape[0], source.shape[0]), values.dtype)
    for f in range(values.shape[0]):
        row = values[f]
        dest = out[f]
        for p in numba.prange(source.shape[0]):
            dest[p] = row[source[p]]
    return out
