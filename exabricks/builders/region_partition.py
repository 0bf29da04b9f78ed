"""The top-down k-d partition of the Active Brick Regions (paper §3.2.3; its driver
is exabricks.builders.regions): a split plane chosen among the support faces of a
box's bricks, the cost model that keeps a box whole instead
(`merged_region_cost`, docs/design-structures.md "Active Brick Regions"), and the numba
kernel that splits one top subtree. Geometry in doubled lattice units."""

from __future__ import annotations


import numba
import numpy as np


@numba.njit(cache=True)
def _grow(a, need):
    """`a` with capacity at least `need` rows (doubling), contents kept."""
    if need <= a.shape[0]:
        return a
    cap = max(need, 2 * a.shape[0])
    out = np.empty((cap,) + a.shape[1:], a.dtype)
    out[: a.shape[0]] = a
    return out


@numba.njit(cache=True, inline="always")
def _choose_plane(sup_lo, sup_hi, buf, a, b, lo, hi, best, best_d, order):
    """(axis, plane) to split region [lo, hi) with fragments buf[a:b]; axis -1: a leaf.

    Candidates are the support faces strictly inside the region; per axis the
    one closest to the centre (ties: the lower), and the widest axis that has
    one, then the next widest (paper §3.2.3; ties by axis index).  Doubled
    lattice units, distances doubled again to stay integer.  best, best_d,
    order: int64 (3,) scratch arrays (no allocation per region).
    """
    for ax in range(3):
        best_d[ax] = -1
        order[ax] = ax
    for k in range(a, b):
        i = buf[k]
        for ax in range(3):
            c2 = lo[ax] + hi[ax]
            for p in (sup_lo[i, ax], sup_hi[i, ax]):
                if lo[ax] < p < hi[ax]:
                    d = abs(2 * p - c2)
                    if best_d[ax] < 0 or d < best_d[ax] or (d == best_d[ax] and p < best[ax]):
                        best_d[ax] = d
                        best[ax] = p
    for s in range(3):
        for t in range(2 - s):
            if hi[order[t + 1]] - lo[order[t + 1]] > hi[order[t]] - lo[order[t]]:
                tmp = order[t]
                order[t] = order[t + 1]
                order[t + 1] = tmp
    for s in range(3):
        if best_d[order[s]] >= 0:
            return order[s], best[order[s]]
    return -1, 0


@numba.njit(cache=True)
def split_plane(sup_lo, sup_hi, ids, lo, hi):
    """_choose_plane for one region with fragment list `ids` (int32): (axis, plane)."""
    scratch = np.empty((3, 3), np.int64)
    return _choose_plane(sup_lo, sup_hi, ids, 0, ids.shape[0], lo, hi,
                         scratch[0], scratch[1], scratch[2])


@numba.njit(cache=True, inline="always")
def _split_fragments(sup_lo, sup_hi, buf, a, b, axis, plane):
    """Split the fragment list buf[a:b] at `plane` on `axis`: the right ids
    compacted in place at [a, a + nr), the left ids collected above b, then moved
    down to follow the right ones. Returns (buf, possibly grown, nr, nl)."""
    buf = _grow(buf, b + (b - a))
    nr = 0
    nl = 0
    for k in range(a, b):
        i = buf[k]
        if sup_lo[i, axis] < plane:
            buf[b + nl] = i
            nl += 1
        if sup_hi[i, axis] > plane:
            buf[a + nr] = i
            nr += 1
    for k in range(nl):
        buf[a + nr + k] = buf[b + k]
    return buf, nr, nl


@numba.njit(cache=True, nogil=True)
def partition_subtree(sup_lo, sup_hi, root_lo, root_hi, root_ids, level, small, visit_cost,
               brick_cost, max_merged):
    """Top-down partition of one region into leaf regions (paper §3.2.3).

    sup_lo, sup_hi: int64 (B, 3) support boxes in doubled lattice units;
    root_lo, root_hi: int64 (3,) the region; root_ids: int32 the bricks whose
    support overlaps it.  Releases the GIL, so subtrees build on threads.
    Returns lo, hi int32 (R, 3) doubled region bounds, start int64 (R + 1,) and
    ids int32 (K,) (CSR, ascending brick ids per region), all views of
    over-allocated buffers.

    A fragment is the part of a support inside the current region, so it is
    kept as just the brick id: its faces strictly inside the region are the
    support's own.  Fragment lists live in one buffer used as a stack: the
    region popped last always owns the top of the buffer, and its children are
    written back in its place (right list below, left list above), so the
    buffer never holds more than the lists of the regions still pending.

    Merging (visit_cost > 0, `merged_region_cost`): a region with at most
    `max_merged` bricks, all of them `small`, that still has a support face
    inside is kept whole when that costs a ray no more than its two halves would,
    with the union of the bricks (level: int (B,) brick levels; small: bool (B,)).
    """
    n = root_ids.shape[0]
    buf = np.empty(2 * n + 16, np.int32)
    buf[:n] = root_ids
    st_lo = np.empty((64, 3), np.int64)
    st_hi = np.empty((64, 3), np.int64)
    st_ab = np.empty((64, 2), np.int64)
    st_lo[0] = root_lo
    st_hi[0] = root_hi
    st_ab[0, 0], st_ab[0, 1] = 0, n
    depth = 1

    # int32 suffices: build_regions checks that doubled coordinates stay within 2**24
    out_lo = np.empty((max(16, n), 3), np.int32)
    out_hi = np.empty((max(16, n), 3), np.int32)
    out_start = np.zeros(max(16, n) + 1, np.int64)
    out_ids = np.empty(max(16, 4 * n), np.int32)
    n_out = n_ids = 0

    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    best = np.empty(3, np.int64)
    best_d = np.empty(3, np.int64)
    order = np.empty(3, np.int64)
    while depth > 0:
        depth -= 1
        for ax in range(3):
            lo[ax] = st_lo[depth, ax]
            hi[ax] = st_hi[depth, ax]
        a = st_ab[depth, 0]
        b = st_ab[depth, 1]

        axis, plane = _choose_plane(sup_lo, sup_hi, buf, a, b, lo, hi, best, best_d, order)
        if axis >= 0 and visit_cost > 0 and b - a <= max_merged and keep_whole(
                sup_lo, sup_hi, buf, a, b, lo, hi, axis, plane, level, small, visit_cost,
                brick_cost):
            axis = -1

        if axis < 0:
            # No support boundary inside (every listed support covers the whole
            # region), or kept whole by the merge rule (every listed support meets it).
            out_lo = _grow(out_lo, n_out + 1)
            out_hi = _grow(out_hi, n_out + 1)
            out_start = _grow(out_start, n_out + 2)
            out_ids = _grow(out_ids, n_ids + (b - a))
            for ax in range(3):
                out_lo[n_out, ax] = lo[ax]
                out_hi[n_out, ax] = hi[ax]
            ids = np.sort(buf[a:b])
            out_ids[n_ids : n_ids + (b - a)] = ids
            n_ids += b - a
            n_out += 1
            out_start[n_out] = n_ids
            continue

        buf, nr, nl = _split_fragments(sup_lo, sup_hi, buf, a, b, axis, plane)

        # Children with no fragment lie outside every support: dropped.
        st_lo = _grow(st_lo, depth + 2)
        st_hi = _grow(st_hi, depth + 2)
        st_ab = _grow(st_ab, depth + 2)
        if nr > 0:
            for ax in range(3):
                st_lo[depth, ax] = lo[ax]
                st_hi[depth, ax] = hi[ax]
            st_lo[depth, axis] = plane
            st_ab[depth, 0] = a
            st_ab[depth, 1] = a + nr
            depth += 1
        if nl > 0:
            for ax in range(3):
                st_lo[depth, ax] = lo[ax]
                st_hi[depth, ax] = hi[ax]
            st_hi[depth, axis] = plane
            st_ab[depth, 0] = a + nr
            st_ab[depth, 1] = a + nr + nl
            depth += 1
    return out_lo[:n_out], out_hi[:n_out], out_start[: n_out + 1], out_ids[:n_ids]


@numba.njit(cache=True, inline="always")
def merged_region_cost(dx, dy, dz, n_bricks, finest, visit_cost, brick_cost):
    """Expected cost of the rays through one region box (doubled lattice extents
    dx, dy, dz), up to a common factor: a ray hits a box with probability
    proportional to its surface area S and then crosses it over a mean chord of
    4 V / S (Cauchy), sampled at 2 samples per cell of its finest level.  So the
    cost is S * visit_cost + (4 V / w) * (1 + brick_cost * n_bricks), w the doubled
    width 2 * 2**finest: visit_cost is a region visit (walk, interval set-up, the
    extra sample a boundary adds) and brick_cost one listed brick per sample, both
    in units of the rest of a sample's cost."""
    area = 2.0 * (dx * dy + dy * dz + dz * dx)
    volume = dx * dy * dz
    w = 2.0 * (1 << finest)
    return area * visit_cost + 4.0 * volume / w * (1.0 + brick_cost * n_bricks)


@numba.njit(cache=True)
def keep_whole(sup_lo, sup_hi, buf, a, b, lo, hi, axis, plane, level, small, visit_cost,
                brick_cost):
    """Whether region [lo, hi) with fragments buf[a:b] costs no more whole than
    split at `plane` on `axis` into its two children (each a region; a child
    without a fragment is empty and costs nothing); never with a brick not `small`."""
    n_left = 0
    n_right = 0
    fin = 127
    fin_left = 127
    fin_right = 127
    for k in range(a, b):
        i = buf[k]
        if not small[i]:
            return False
        lv = level[i]
        fin = min(fin, lv)
        if sup_lo[i, axis] < plane:
            n_left += 1
            fin_left = min(fin_left, lv)
        if sup_hi[i, axis] > plane:
            n_right += 1
            fin_right = min(fin_right, lv)
    d = np.empty(3, np.float64)
    for ax in range(3):
        d[ax] = hi[ax] - lo[ax]
    whole = merged_region_cost(d[0], d[1], d[2], b - a, fin, visit_cost, brick_cost)
    split = 0.0
    if n_left > 0:
        d[axis] = plane - lo[axis]
        split += merged_region_cost(d[0], d[1], d[2], n_left, fin_left, visit_cost, brick_cost)
    if n_right > 0:
        d[axis] = hi[axis] - plane
        split += merged_region_cost(d[0], d[1], d[2], n_right, fin_right, visit_cost,
                                    brick_cost)
    return whole <= split
