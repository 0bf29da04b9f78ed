"""Active Brick Regions (paper §3.2.3): split space where brick supports begin or end.

A brick's *support* is its box grown by half its cell width on every side (the
region where the hat functions of its cells are non-zero, paper §3.2.2).  The
superposition of all supports partitions space into parts in which the set of
active bricks is constant; a top-down partition along support faces cuts those
parts into disjoint boxes; boxes that touch face to face with the same active
bricks are then merged again (the k-d cuts run through whole regions, also
where nothing changes), within each of the top subtrees that the partition
builds independently (so that builds by pieces, exabricks.pieces, give
the same regions), giving the Active Brick Regions.  Each region records the
bricks whose support overlaps it, the value range of every cell whose support
overlaps it (space skipping, paper §4.1) and the finest level among its bricks
(adaptive sampling, paper §4.2).

All geometry here is in *doubled* lattice units (int64 for supports, int32 for
region bounds, which are checked to stay within 2**24): a support bound sits on
a half-integer lattice position, so twice it is an exact integer.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numba
import numpy as np

from .. import schema
from ..constants import BOUNDS_DTYPE, INDEX_DTYPE, OFFSET_DTYPE
from ..errors import ExabricksError
from .brick import require_disjoint
from ..pieces import WHOLE, Piece, share_meta, task_range

# float32 holds every half-integer exactly up to 2**23, i.e. doubled coordinates up to 2**24.
_MAX_DOUBLED = 1 << 24


@dataclass(frozen=True)
class Merge:
    """When the partition keeps a box of the k-d split whole (docs/design.md, "Active
    Brick Regions and merged regions").

    visit_cost: the cost of entering a region, in units of a sample's cost apart
        from its bricks (`merged_region_cost`); 0 turns merging off: every region
        is then an exact ABR, one set of active bricks (paper §3.2.3).
    brick_cost: the cost of one listed brick per sample, same units.
    max_bricks: a box with more bricks than this is always split.
    max_brick_cells: a box with a brick of more cells than this is always split:
        a large brick already makes long region visits (block-structured data), so
        merging pays only among small ones (octree-like data, thin refinement).
    The defaults were chosen on the thin-shell layout and the four shared
    datasets (docs/benchmarks.md): regions + BVH within 3x the scalar bytes of
    octree-like data, no slower render anywhere.
    """

    visit_cost: float = 20.0
    brick_cost: float = 0.3
    max_bricks: int = 64
    max_brick_cells: int = 512

    def __post_init__(self):
        for name in ("visit_cost", "brick_cost"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0 <= v <= 1e6):
                raise ExabricksError(f"the merge {name.replace('_', ' ')} must lie in "
                                     f"0..1e6, got {v}")
        for name, what in (("max_bricks", "bricks of a merged region"),
                           ("max_brick_cells", "cells of a merged brick")):
            v = getattr(self, name)
            if not 0 <= v <= 1 << 31:
                raise ExabricksError(f"the most {what} must lie in 0..{1 << 31}, got {v}")

    @property
    def enabled(self) -> bool:
        return self.visit_cost > 0 and self.max_bricks > 0

    def as_dict(self) -> dict:
        return asdict(self)


EXACT = Merge(visit_cost=0.0, brick_cost=0.0, max_bricks=0, max_brick_cells=0)
"""Merging off: the paper's exact Active Brick Regions."""


def build_regions(bricks: schema.Bricks, merge: Merge = Merge(),
                  piece: Piece = WHOLE) -> schema.Regions:
    """Active Brick Regions of `bricks`; statistics (paper Table 1) in meta["statistics"].

    merge: with EXACT every region is an exact ABR (one set of active bricks);
    by default a box of the k-d split with up to `merge.max_bricks` bricks stays
    whole where the cost model (`merged_region_cost`) says its halves would cost
    rays more, with the union of their bricks.  Either way a region lists exactly
    the bricks whose support overlaps it, so every brick that can influence a
    point is in the list of the region that holds it; a merged region may also
    hold space where no support reaches (a sample there has no weight: empty).

    Returns a `schema.Regions` whose regions are disjoint, cover the union of
    brick supports (exactly, with EXACT), and list (ascending) exactly the bricks
    whose support overlaps them.  Bounds are float32 lattice units (half-integers).
    value_range (R, F, 2) float32 is the min/max over every cell whose support
    overlaps the region (NaN values ignored; NaN if no cell has a number).
    """
    n = bricks.n_bricks
    if n == 0:
        raise ExabricksError("the bricks contain no cells; there is nothing to build regions for")
    # Each step's temporaries are handed back to the system before the next
    # (schema.trim_heap): glibc would keep them for the next allocations, and
    # the builders' peaks are those of the steps, not of their sum.
    if piece.whole:
        require_disjoint(bricks)
        schema.trim_heap()
    sup_lo, sup_hi = support_boxes_doubled(bricks)
    tasks, lv, small = _tasks(sup_lo, sup_hi, bricks.level,
                              bricks.dims.astype(np.int64).prod(axis=1), merge)
    t0, t1 = task_range([t[2].size for t in tasks], piece)
    if not piece.whole and t1 > t0:
        # Two bricks that share a cell both overlap the task that holds that cell:
        # a piece checks the bricks of its own tasks, and the N pieces check all.
        require_disjoint(bricks, np.unique(np.concatenate([t[2] for t in tasks[t0:t1]])))
        schema.trim_heap()
    parts = _run(sup_lo, sup_hi, tasks[t0:t1], lv, small, merge)
    del sup_lo, sup_hi, tasks, lv, small
    schema.trim_heap()
    n_partition = sum(p[0].shape[0] for p in parts)
    # Each task's leaves are coalesced on their own: the regions of a task are
    # those of the piece that builds it, whatever the piece count.
    for k, p in enumerate(parts):
        parts[k] = list(_coalesce(*p))
    lo2, hi2, brick_start, brick_ids = _join(parts)
    schema.trim_heap()
    value_range, finest = leaf_ranges(
        lo2, hi2, brick_start, brick_ids, bricks.lower_lattice, bricks.dims,
        bricks.offset, bricks.values, bricks.level,
    )
    schema.release(bricks)
    regions = schema.Regions(
        fields=bricks.fields,
        origin_world=bricks.origin_world.copy(),
        spacing_world=bricks.spacing_world.copy(),
        lower_lattice=(lo2 * 0.5).astype(BOUNDS_DTYPE),
        upper_lattice=(hi2 * 0.5).astype(BOUNDS_DTYPE),
        brick_start=brick_start.astype(OFFSET_DTYPE, copy=False),
        brick_ids=brick_ids.astype(INDEX_DTYPE, copy=False),
        value_range=value_range,
        finest_level=finest,
    )
    stats = region_statistics(regions, lo2, hi2)
    stats["n_bricks"] = n
    stats["n_partition_leaves"] = n_partition
    return regions.replace(meta={"statistics": stats, "parameters": {"merge": merge.as_dict()},
                                 **share_meta(piece)})


def partition(sup_lo, sup_hi, *, threads: int | None = None, level=None, cells=None,
              merge: Merge = EXACT):
    """The k-d partition of the supports (paper §3.2.3), subtrees built on threads.

    sup_lo, sup_hi: int64 (B, 3) support boxes, doubled lattice units.
    Returns leaf bounds lo, hi int32 (R, 3) (doubled), CSR start int64 (R + 1,)
    and ids int32 (K,), the leaves of `_tasks` in task order (`_join`), so the
    result does not depend on the number of threads.  level, cells: int (B,)
    brick levels and cell counts, which `merge` needs (when enabled).
    """
    tasks, lv, small = _tasks(sup_lo, sup_hi, level, cells, merge)
    return _join(_run(sup_lo, sup_hi, tasks, lv, small, merge, threads))


def _tasks(sup_lo, sup_hi, level, cells, merge):
    """The top of the partition, split breadth first here until there are enough
    subtrees: their (lo, hi, ids) in order, and the level and merge flags per brick
    that `_partition` takes.  The task count depends only on the input size,
    never on the thread count; pieces (exabricks.pieces) are runs of tasks."""
    n = sup_lo.shape[0]
    lv = np.zeros(n, np.int64) if level is None else np.ascontiguousarray(level, np.int64)
    # Bricks a merged box may hold (Merge.max_brick_cells).
    small = np.ones(n, np.bool_) if cells is None else np.asarray(cells) <= merge.max_brick_cells
    want = 1 if n < 20_000 else 64
    queue = [(sup_lo.min(axis=0).astype(np.int64), sup_hi.max(axis=0).astype(np.int64),
              np.arange(n, dtype=np.int32))]
    tasks = []  # regions the top phase finds to be leaves stay tasks: _partition emits them
    visit = float(merge.visit_cost) if merge.enabled else 0.0
    while queue and len(queue) + len(tasks) < want:
        lo, hi, ids = queue.pop(0)
        axis, plane = _split_plane(sup_lo, sup_hi, ids, lo, hi)
        if axis >= 0 and visit > 0 and ids.size <= merge.max_bricks and _keep_whole(
                sup_lo, sup_hi, ids, 0, ids.size, lo, hi, axis, plane, lv, small, visit,
                float(merge.brick_cost)):
            axis = -1  # kept whole: _partition, deciding the same, emits it as it is
        if axis < 0:
            tasks.append((lo, hi, ids))
            continue
        right = ids[sup_hi[ids, axis] > plane]
        left = ids[sup_lo[ids, axis] < plane]
        if right.size:  # children with no fragment lie outside every support: dropped
            rlo = lo.copy()
            rlo[axis] = plane
            queue.append((rlo, hi, right))
        if left.size:
            lhi = hi.copy()
            lhi[axis] = plane
            queue.append((lo, lhi, left))
    return tasks + queue, lv, small


def _run(sup_lo, sup_hi, tasks, lv, small, merge, threads=None):
    """The leaves of every task, [lo, hi, start, ids] each, in task order."""
    threads = numba.get_num_threads() if threads is None else threads
    visit = float(merge.visit_cost) if merge.enabled else 0.0

    def run(task):
        # copies: the results are views of buffers grown by doubling
        return [a.copy() for a in _partition(sup_lo, sup_hi, *task, lv, small, visit,
                                             float(merge.brick_cost), int(merge.max_bricks))]

    if threads > 1 and len(tasks) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=threads) as pool:
            # biggest first for load balance; results are put back in task order
            order = sorted(range(len(tasks)), key=lambda t: -tasks[t][2].size)
            futures = {t: pool.submit(run, tasks[t]) for t in order}
            return [futures[t].result() for t in range(len(tasks))]
    return [run(t) for t in tasks]


def _join(parts):
    """The parts' leaves one after the other: lo, hi, CSR start (from 0), ids.
    Each part's arrays are dropped as they are copied."""
    if not parts:
        return (np.empty((0, 3), np.int32), np.empty((0, 3), np.int32), np.zeros(1, np.int64),
                np.empty(0, np.int32))
    if len(parts) == 1:
        return tuple(parts[0])
    shift = 0
    for p in parts:  # each part's list ends, shifted to follow the previous parts' lists
        p[2] = p[2][1:] + shift
        shift = int(p[2][-1]) if p[2].size else shift
    start = _concatenate(parts, 2, head=np.zeros(1, np.int64))
    return _concatenate(parts, 0), _concatenate(parts, 1), start, _concatenate(parts, 3)


def _concatenate(parts, column, head=None):
    """The arrays `parts[k][column]` one after the other (after `head`), each part's
    dropped as soon as it is copied: the result is the only full copy held."""
    head = parts[0][column][:0] if head is None else head
    last = parts[-1][column]
    out = np.empty((head.shape[0] + sum(p[column].shape[0] for p in parts),) + last.shape[1:],
                   last.dtype)
    out[:head.shape[0]] = head
    at = head.shape[0]
    for p in parts:
        n = p[column].shape[0]
        out[at:at + n] = p[column]
        p[column] = None
        at += n
    return out


def _coalesce(lo2, hi2, start, ids):
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


def support_boxes_doubled(bricks: schema.Bricks) -> tuple[np.ndarray, np.ndarray]:
    """Support box of every brick in doubled lattice units.

    Returns (lo, hi), each int32 (B, 3): lo = 2*lower - w, hi = 2*(lower + dims*w) + w
    with w = 2**level, i.e. the brick box grown by w/2 on every side.  Computed in
    steps (bricks may be mapped); ExabricksError where a support reaches beyond
    2**24 doubled units, where float32 region bounds stop being exact.
    """
    lo = np.empty((bricks.n_bricks, 3), np.int32)
    hi = np.empty((bricks.n_bricks, 3), np.int32)
    for start, (lower, level, dims) in schema.rows(bricks.lower_lattice, bricks.level,
                                                    bricks.dims):
        w = np.left_shift(np.int64(1), level.astype(np.int64))[:, None]
        l2 = 2 * lower.astype(np.int64) - w
        h2 = 2 * (lower + dims.astype(np.int64) * w) + w
        reach = max(-int(l2.min()), int(h2.max()))
        if reach > _MAX_DOUBLED:
            raise ExabricksError(
                f"brick supports reach lattice coordinate {reach / 2}, beyond "
                f"{_MAX_DOUBLED // 2}, where float32 region bounds stop being exact")
        lo[start:start + len(l2)] = l2
        hi[start:start + len(h2)] = h2
    return lo, hi


def region_statistics(regions: schema.Regions, lo2=None, hi2=None) -> dict:
    """Paper Table 1: region count, bricks per region (by count, by volume, max), bytes.
    lo2, hi2: the bounds doubled, when at hand (else taken from the regions);
    computed in steps (the regions may be mapped)."""
    lo2 = regions.lower_lattice if lo2 is None else lo2
    hi2 = regions.upper_lattice if hi2 is None else hi2
    scale = 1.0 if lo2 is regions.lower_lattice else 0.125  # doubled: volumes 8 times larger
    total = weighted = 0.0
    biggest = 0
    start = regions.brick_start
    for at, (lo, hi) in schema.rows(lo2, hi2):
        counts = np.diff(start[at:at + lo.shape[0] + 1])
        vol = np.prod((hi.astype(np.float64) - lo.astype(np.float64)), axis=1) * scale
        total += float(vol.sum())
        weighted += float((counts * vol).sum())
        biggest = max(biggest, int(counts.max()) if counts.size else 0)
    n = regions.n_regions
    return {
        "n_regions": n,
        "avg_bricks_per_region_by_count": float(start[-1]) / n if n else 0.0,
        "avg_bricks_per_region_by_volume": weighted / total if total else 0.0,
        "max_bricks_per_region": biggest,
        "region_brick_refs": int(regions.brick_ids.shape[0]),
        "bytes": int(sum(a.nbytes for a in regions.arrays().values())),
    }


# ---------------------------------------------------------------------------
# kernels


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
def _split_plane(sup_lo, sup_hi, ids, lo, hi):
    """_choose_plane for one region with fragment list `ids` (int32): (axis, plane)."""
    scratch = np.empty((3, 3), np.int64)
    return _choose_plane(sup_lo, sup_hi, ids, 0, ids.shape[0], lo, hi,
                         scratch[0], scratch[1], scratch[2])


@numba.njit(cache=True, nogil=True)
def _partition(sup_lo, sup_hi, root_lo, root_hi, root_ids, level, small, visit_cost,
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
    st_ab[0, 0] = 0
    st_ab[0, 1] = n
    depth = 1

    # int32 suffices: build_regions checks that doubled coordinates stay within 2**24
    out_lo = np.empty((max(16, n), 3), np.int32)
    out_hi = np.empty((max(16, n), 3), np.int32)
    out_start = np.zeros(max(16, n) + 1, np.int64)
    out_ids = np.empty(max(16, 4 * n), np.int32)
    n_out = 0
    n_ids = 0

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
        if axis >= 0 and visit_cost > 0 and b - a <= max_merged and _keep_whole(
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

        # Split at `plane`: right ids compacted in place at [a, a + nr), left ids
        # collected above b, then moved down to follow the right ones.
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
def _keep_whole(sup_lo, sup_hi, buf, a, b, lo, hi, axis, plane, level, small, visit_cost,
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
