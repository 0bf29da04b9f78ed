"""Active Brick Regions (paper §3.2.3): split space where brick supports begin or end.

A brick's *support* is its box grown by half its cell width on every side (the
region where the hat functions of its cells are non-zero, paper §3.2.2).  The
superposition of all supports partitions space into parts in which the set of
active bricks is constant; a top-down partition along support faces cuts those
parts into disjoint boxes; boxes that touch face to face with the same active
bricks are then merged again (the k-d cuts run through whole regions, also
where nothing changes), within each of the top subtrees that the partition
builds independently (so that builds by pieces, exabricks.formats.pieces, give
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
from ..util.constants import BOUNDS_DTYPE, INDEX_DTYPE, OFFSET_DTYPE
from ..util.errors import ExabricksError
from .bricks import require_disjoint
from ..formats.pieces import WHOLE, Piece, share_meta, task_range
from .region_merge import coalesce, leaf_ranges
from .region_partition import keep_whole, partition_subtree, split_plane

# float32 holds every half-integer exactly up to 2**23, i.e. doubled coordinates up to 2**24.
_MAX_DOUBLED = 1 << 24


@dataclass(frozen=True)
class Merge:
    """When the partition keeps a box of the k-d split whole (docs/design-structures.md, "Active
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
        parts[k] = list(coalesce(*p))
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
    that `partition_subtree` takes.  The task count depends only on the input size,
    never on the thread count; pieces (exabricks.formats.pieces) are runs of tasks."""
    n = sup_lo.shape[0]
    lv = np.zeros(n, np.int64) if level is None else np.ascontiguousarray(level, np.int64)
    # Bricks a merged box may hold (Merge.max_brick_cells).
    small = np.ones(n, np.bool_) if cells is None else np.asarray(cells) <= merge.max_brick_cells
    want = 1 if n < 20_000 else 64
    queue = [(sup_lo.min(axis=0).astype(np.int64), sup_hi.max(axis=0).astype(np.int64),
              np.arange(n, dtype=np.int32))]
    tasks = []  # regions the top phase finds to be leaves stay tasks: partition_subtree emits them
    visit = float(merge.visit_cost) if merge.enabled else 0.0
    while queue and len(queue) + len(tasks) < want:
        lo, hi, ids = queue.pop(0)
        axis, plane = split_plane(sup_lo, sup_hi, ids, lo, hi)
        if axis >= 0 and visit > 0 and ids.size <= merge.max_bricks and keep_whole(
                sup_lo, sup_hi, ids, 0, ids.size, lo, hi, axis, plane, lv, small, visit,
                float(merge.brick_cost)):
            axis = -1  # kept whole: partition_subtree, deciding the same, emits it as it is
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
        return [a.copy() for a in partition_subtree(sup_lo, sup_hi, *task, lv, small, visit,
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
