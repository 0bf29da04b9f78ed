"""Active Brick Regions put together after the k-d partition (paper §3.2.3): boxes
that touch face to face with the same active bricks are merged (`coalesce`), and
each region's value range and finest level are taken from the cells whose
supports overlap it (`leaf_ranges`, paper §4.1-4.2). Geometry in doubled lattice
units."""

from __future__ import annotations


import numba
import numpy as np


def coalesce(lo2, hi2, start, ids):
    """Merge face-adjacent regions with the same brick list into one box.

    The k-d partition (paper §3.2.3) cuts every region crossing a split plane,
    also where the active bricks do not change, so one ABR ends up in
    several boxes.  Two boxes with the same brick list that share a whole face
    form a box in which that list is still exactly the set of active bricks
    (each listed support covers both halves, no other support reaches
    either), so they are merged.  Sweeps along x, y, z repeat while they still
    remove at least 5% of the regions (the first round does nearly all).
    Arguments and result: doubled bounds int32 (R, 3) and the CSR brick lists;
    `hi2` and `ids` are updated in place (the result's ids are a view of `ids`).
    """
    alive = np.ones(lo2.shape[0], np.bool_)
    set_hash = _list_hashes(start, ids)
    n_alive = lo2.shape[0]
    for _ in range(8):
        merged = 0
        for axis in range(3):
            merged += _merge_axis(lo2, hi2, start, ids, set_hash, alive, axis)
        n_alive -= merged
        if merged < 0.05 * n_alive:
            break
    keep = np.flatnonzero(alive)
    counts = np.diff(start)[keep]
    new_start = np.zeros(keep.shape[0] + 1, np.int64)
    np.cumsum(counts, out=new_start[1:])
    return lo2[keep], hi2[keep], new_start, _compact_lists(keep, start, ids, new_start)


@numba.njit(cache=True)
def _list_hashes(start, ids):
    """FNV-1a hash of every region's brick list: int64 (R,)."""
    r_count = start.shape[0] - 1
    h = np.empty(r_count, np.int64)
    for r in range(r_count):
        x = np.uint64(1469598103934665603)
        for k in range(start[r], start[r + 1]):
            x = (x ^ np.uint64(ids[k])) * np.uint64(1099511628211)
        h[r] = np.int64(x >> np.uint64(1))
    return h


@numba.njit(cache=True, inline="always")
def _face_key(r, lo2, hi2, set_hash, axis, at):
    """Hash of (brick list, bounds on the two other axes, coordinate `at` on `axis`)."""
    x = np.uint64(set_hash[r])
    for ax in range(3):
        if ax != axis:
            x = (x ^ np.uint64(lo2[r, ax])) * np.uint64(1099511628211)
            x = (x ^ np.uint64(hi2[r, ax])) * np.uint64(1099511628211)
    x = (x ^ np.uint64(at)) * np.uint64(1099511628211)
    # splitmix64 finaliser: the table index takes the low bits, which FNV leaves
    # poorly mixed when the coordinates are multiples of large powers of two.
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@numba.njit(cache=True)
def _mergeable(a, q, lo2, hi2, start, ids, axis):
    """Whether region q continues region a along `axis` with the same brick list."""
    if lo2[q, axis] != hi2[a, axis]:
        return False
    for ax in range(3):
        if ax != axis and (lo2[q, ax] != lo2[a, ax] or hi2[q, ax] != hi2[a, ax]):
            return False
    n = start[a + 1] - start[a]
    if start[q + 1] - start[q] != n:
        return False
    for k in range(n):
        if ids[start[a] + k] != ids[start[q] + k]:
            return False
    return True


@numba.njit(cache=True, parallel=True)
def _merge_axis(lo2, hi2, start, ids, set_hash, alive, axis):
    """One sweep along `axis`: every chain of mergeable regions becomes its first region.

    The successor of region a is the live region whose lower face is a's upper
    face (same cross-section, same list; regions are disjoint, so there is at
    most one), found through an open-addressing hash table of lower-face keys.
    A table slot holds (key, region) side by side, so a probe touches one cache
    line and a key mismatch needs no look at the region itself.  Returns the
    number of regions merged away (marked dead in `alive`).
    """
    r_count = lo2.shape[0]
    key_lo = np.empty(r_count, np.uint64)
    key_hi = np.empty(r_count, np.uint64)
    for r in numba.prange(r_count):
        key_lo[r] = _face_key(r, lo2, hi2, set_hash, axis, lo2[r, axis])
        key_hi[r] = _face_key(r, lo2, hi2, set_hash, axis, hi2[r, axis])
    size = 1
    while size < 2 * r_count:
        size *= 2
    mask = np.uint64(size - 1)
    table = np.full((size, 2), -1, np.int64)
    for r in range(r_count):
        if alive[r]:
            h = key_lo[r] & mask
            while table[h, 1] >= 0:
                h = (h + np.uint64(1)) & mask
            table[h, 0] = np.int64(key_lo[r])
            table[h, 1] = r
    succ = np.full(r_count, -1, np.int64)
    has_pred = np.zeros(r_count, np.bool_)
    for a in numba.prange(r_count):
        if alive[a]:
            k = np.int64(key_hi[a])
            h = key_hi[a] & mask
            while table[h, 1] >= 0:
                q = table[h, 1]
                if table[h, 0] == k and _mergeable(a, q, lo2, hi2, start, ids, axis):
                    succ[a] = q
                    # at most one predecessor per region (disjointness): no race
                    has_pred[q] = True
                    break
                h = (h + np.uint64(1)) & mask
    merged = 0
    for a in range(r_count):
        if alive[a] and not has_pred[a] and succ[a] >= 0:
            q = succ[a]
            while q >= 0:
                hi2[a, axis] = hi2[q, axis]
                alive[q] = False
                merged += 1
                q = succ[q]
    return merged


@numba.njit(cache=True)
def _compact_lists(keep, start, ids, new_start):
    """Brick lists of the regions `keep` (ascending), moved to the front of `ids` one
    after the other (in place: a list never moves up); a view of ids[:new_start[-1]]."""
    for r in range(keep.shape[0]):
        s = start[keep[r]]
        for k in range(new_start[r + 1] - new_start[r]):
            ids[new_start[r] + k] = ids[s + k]
    return ids[:new_start[-1]]


@numba.njit(cache=True)
def _floor_div(a, b):
    """Floor of a / b for b > 0 (explicit, independent of the integer division semantics)."""
    q = a // b
    if q * b > a:
        q -= 1
    return q


@numba.njit(cache=True, parallel=True)
def leaf_ranges(lo2, hi2, start, ids, lower, dims, offset, values, level):
    """Per-region value range and finest level.

    lo2, hi2: int32 (R, 3) doubled region bounds; start/ids: CSR brick lists;
    lower, dims: int32 (B, 3); offset: int64 (B,); values: float32 (F, V);
    level: int8 (B,).
    Returns value_range float32 (R, F, 2) and finest_level int8 (R,).

    Only the cells of a brick whose support (cell box grown by w/2) overlaps the
    region count, not the whole brick (paper §3.2.2): along an axis, cell i of a
    brick at lower L has doubled support (2L + (2i-1)w, 2L + (2i+3)w).
    """
    r_count = lo2.shape[0]
    n_fields = values.shape[0]
    vr = np.empty((r_count, n_fields, 2), np.float32)
    finest = np.empty(r_count, np.int8)
    for r in numba.prange(r_count):
        mn = np.full(n_fields, np.inf, np.float32)
        mx = np.full(n_fields, -np.inf, np.float32)
        any_number = np.zeros(n_fields, np.bool_)
        fl = 127
        i0 = np.empty(3, np.int64)
        i1 = np.empty(3, np.int64)
        for k in range(start[r], start[r + 1]):
            b = ids[k]
            if level[b] < fl:
                fl = level[b]
            w = np.int64(1) << np.int64(level[b])
            for ax in range(3):
                base = 2 * np.int64(lower[b, ax])
                # first i with 2L + (2i+3)w > lo  and  last i with 2L + (2i-1)w < hi
                i0[ax] = max(0, _floor_div(lo2[r, ax] - base - 3 * w, 2 * w) + 1)
                i1[ax] = min(np.int64(dims[b, ax]), -_floor_div(-(hi2[r, ax] - base + w), 2 * w))
            dx = np.int64(dims[b, 0])
            dxy = dx * np.int64(dims[b, 1])
            o = offset[b]
            for f in range(n_fields):
                lo_f = mn[f]
                hi_f = mx[f]
                seen = any_number[f]
                for z in range(i0[2], i1[2]):
                    for y in range(i0[1], i1[1]):
                        row = o + z * dxy + y * dx
                        for x in range(i0[0], i1[0]):
                            v = values[f, row + x]
                            if v == v:
                                seen = True
                                if v < lo_f:
                                    lo_f = v
                                if v > hi_f:
                                    hi_f = v
                mn[f] = lo_f
                mx[f] = hi_f
                any_number[f] = seen
        for f in range(n_fields):
            if any_number[f]:
                vr[r, f, 0] = mn[f]
                vr[r, f, 1] = mx[f]
            else:
                vr[r, f, 0] = np.nan
                vr[r, f, 1] = np.nan
        finest[r] = fl
    return vr, finest
