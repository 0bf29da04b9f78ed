"""Bounding-volume hierarchy over the Active Brick Regions (paper §3.3).

The paper hands the regions to RTX as user geometry and rebuilds the BVH
whenever the transfer function changes, dropping fully transparent regions
(§4.1).  We build one BVH, offline, with binned SAH over region centroids and
store per node the union of its regions' value ranges and their finest level,
so the renderer can skip a transparent subtree (maximum opacity of the
transfer function over the node's range is 0) without any rebuild.

Layout (schema.Bvh): flat node array, node 0 the root; an inner node has
count 0 and its children at `first` and `first + 1`; a leaf lists `count`
regions from `region_index[first]` on.
"""

from __future__ import annotations

import numba
import numpy as np

from .. import schema
from ..util.constants import INDEX_DTYPE
from ..util.errors import ExabricksError
from ..formats.pieces import WHOLE, Piece, share_meta, task_range


def build_bvh(regions: schema.Regions, *, leaf_size: int = 4, bins: int = 16,
              piece: Piece = WHOLE) -> schema.Bvh:
    """Binned-SAH BVH over `regions`; statistics in meta["statistics"].

    leaf_size: most regions per leaf (a node with more is always split).
    bins: SAH bins per axis.
    Node bounds are float32 lattice units, exactly the union of the regions'
    bounds; value_range (M, F, 2) float32 is the min of the regions' minima and
    the max of their maxima per field (NaN where no region has a number);
    finest_level (M,) int8 is the finest level over the node's regions.
    piece: build only this share (exabricks.formats.pieces): a BVH over every
    region whose subtrees of other pieces are single leaves; meta["piece"] says
    which subtrees are its own.
    """
    lo = np.ascontiguousarray(regions.lower_lattice)
    hi = np.ascontiguousarray(regions.upper_lattice)
    first, count, order, share = build_tree(lo, hi, leaf_size=leaf_size, bins=bins,
                                            item="region", piece=piece)
    node_lo, node_hi, vr, finest = refit(
        first, count, order, lo, hi, np.ascontiguousarray(regions.value_range), regions.finest_level
    )
    bvh = schema.Bvh(
        fields=regions.fields,
        origin_world=regions.origin_world.copy(),
        spacing_world=regions.spacing_world.copy(),
        lower_lattice=node_lo,
        upper_lattice=node_hi,
        first=first.astype(INDEX_DTYPE),
        count=count.astype(INDEX_DTYPE),
        region_index=order.astype(INDEX_DTYPE),
        value_range=vr,
        finest_level=finest,
    )
    return bvh.replace(meta={"statistics": bvh_statistics(bvh), **share_meta(piece, **share)})


def build_tree(lower: np.ndarray, upper: np.ndarray, *, leaf_size: int = 4, bins: int = 16,
               item: str = "box", piece: Piece = WHOLE
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Binned-SAH tree over boxes (the layout of schema.Bvh, without per-node data).

    lower, upper: float32 (N, 3) box bounds, finite and with volume; `item`
    names a box in error messages. Returns first, count (int64 (M,): an inner
    node has count 0 and its children at first, first + 1; a leaf lists
    `count` boxes from order[first] on), order (int64 (N,)) and, for a
    `piece`, where its share lies (`_build`).
    """
    if leaf_size < 1:
        raise ExabricksError(f"leaf size must be at least 1, got {leaf_size}")
    if bins < 2:
        raise ExabricksError(f"SAH needs at least 2 bins, got {bins}")
    if lower.shape[0] == 0:
        raise ExabricksError(f"there are no {item}s to build a tree over")
    lo = np.ascontiguousarray(lower, np.float32)
    hi = np.ascontiguousarray(upper, np.float32)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ExabricksError(f"{item} bounds must be finite")
    if np.any(hi <= lo):
        r = int(np.flatnonzero(np.any(hi <= lo, axis=1))[0])
        raise ExabricksError(
            f"{item} {r} is empty ({lo[r].tolist()} .. {hi[r].tolist()}); {item}s must have volume"
        )
    return _build(lo, hi, int(leaf_size), int(bins), numba.get_num_threads(), piece)


def tree_bounds(first, count, order, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """Node boxes of a `build_tree` tree: float32 (M, 3) lower and upper, the union of
    the node's boxes."""
    n = lower.shape[0]
    lo, hi, _, _ = refit(first, count, order, np.ascontiguousarray(lower, np.float32),
                          np.ascontiguousarray(upper, np.float32),
                          np.empty((n, 0, 2), np.float32), np.zeros(n, np.int8))
    return lo, hi


def bvh_statistics(bvh: schema.Bvh) -> dict:
    """Node, leaf and region counts, depth, mean leaf size, SAH cost, bytes."""
    depth = tree_depths(bvh.first, bvh.count)
    leaves = bvh.count > 0
    ext = (bvh.upper_lattice - bvh.lower_lattice).astype(np.float64)
    area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
    # SAH cost relative to the root: expected inner nodes visited + regions tested.
    rel = area / area[0] if area[0] > 0 else np.zeros_like(area)
    return {
        "n_regions": int(bvh.region_index.shape[0]),
        "n_nodes": bvh.n_nodes,
        "n_leaves": int(leaves.sum()),
        "depth": int(depth.max()) + 1,
        "mean_leaf_depth": float(depth[leaves].mean()),
        "mean_regions_per_leaf": float(bvh.count[leaves].mean()),
        "sah_cost": float(rel[~leaves].sum() + (rel[leaves] * bvh.count[leaves]).sum()),
        "bytes": int(sum(a.nbytes for a in bvh.arrays().values())),
    }


# ---------------------------------------------------------------------------
# kernels


@numba.njit(cache=True)
def tree_depths(first, count):
    """Depth of every node (root 0); parents always precede their children."""
    d = np.zeros(first.shape[0], np.int64)
    for i in range(first.shape[0]):
        if count[i] == 0:
            d[first[i]] = d[i] + 1
            d[first[i] + 1] = d[i] + 1
    return d


@numba.njit(cache=True)
def _half_area(lo0, lo1, lo2, hi0, hi1, hi2):
    e0 = hi0 - lo0
    e1 = hi1 - lo1
    e2 = hi2 - lo2
    return e0 * e1 + e1 * e2 + e2 * e0


def _build(lo, hi, leaf_size, bins, threads, piece=WHOLE):
    """Binned SAH over box centroids, top down; subtrees on threads.

    lo, hi: float32 (R, 3) box bounds (regions, or brick supports).  Returns first, count (int64 (M,))
    and the region order (int64 (R,)).  The top levels are split breadth first
    here until there are 64 subtrees (fewer for small inputs); each subtree is
    built by _build_subtree (which releases the GIL) into its own node block,
    appended in subtree order, so the result does not depend on the number of
    threads.  Children are consecutive pairs after their parent, so a parent
    always has a smaller index than its children.

    piece (exabricks.formats.pieces): build only a run of the subtrees; the others
    stay leaves listing all their boxes (in the top's order), so the share is
    still a tree over every box.  Then also returns where the share lies:
    {"top": top node count, "subtrees": [[node, start, end], ...] (all of them),
    "own": [t0, t1] (the share's run), "blocks": node count of each own subtree
    below its root, whose nodes follow the top in subtree order}; else {}.
    """
    n = lo.shape[0]
    # Centroids and boxes are kept in the current order of `order` and swapped
    # with it, so every pass over a node reads memory sequentially.
    cen = (0.5 * (lo.astype(np.float64) + hi.astype(np.float64)))
    lo = lo.copy()
    hi = hi.copy()
    order = np.arange(n, dtype=np.int64)
    first, count, subtrees = _split_top(cen, lo, hi, order, leaf_size, bins, threads)
    t0, t1 = task_range([e - s for _, s, e in subtrees], piece)
    for node, s, e in subtrees[:t0] + subtrees[t1:]:
        first[node], count[node] = s, e - s
    share = {} if piece.whole else {"top": len(first), "subtrees": [list(t) for t in subtrees],
                                    "own": [t0, t1]}
    subtrees = subtrees[t0:t1]

    def run(task):
        return _build_subtree(cen, lo, hi, order, task[1], task[2], leaf_size, bins)

    if threads > 1 and len(subtrees) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=threads) as pool:
            by_size = sorted(range(len(subtrees)), key=lambda t: subtrees[t][1] - subtrees[t][2])
            futures = {t: pool.submit(run, subtrees[t]) for t in by_size}
            parts = [futures[t].result() for t in range(len(subtrees))]
    else:
        parts = [run(t) for t in subtrees]
    first = np.array(first, np.int64)
    count = np.array(count, np.int64)
    blocks_first, blocks_count = [first], [count]
    base = first.shape[0]
    for (node, _, _), (f, c, m) in zip(subtrees, parts):
        # local node 0 is `node`; local node j >= 1 goes to base + j - 1
        first[node], count[node] = (base + f[0] - 1, 0) if c[0] == 0 else (f[0], c[0])
        f, c = f[1:m], c[1:m]
        blocks_first.append(np.where(c == 0, base + f - 1, f))
        blocks_count.append(c)
        base += m - 1
    if share:
        share["blocks"] = [int(m) - 1 for _, _, m in parts]
    return np.concatenate(blocks_first), np.concatenate(blocks_count), order, share


def _split_top(cen, lo, hi, order, leaf_size, bins, threads):
    """The top levels of `_build`'s tree, split breadth first (on threads) until
    there are 64 subtrees (one for fewer than 50,000 boxes): (first, count, the
    subtrees as [node, start, end])."""
    n = lo.shape[0]
    first = [0]
    count = [0]
    want = 1 if n < 50_000 else 64
    queue = [(0, 0, n)]  # node, start, end
    subtrees = []
    pool = None
    if threads > 1 and n >= 50_000:
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor(max_workers=threads)
    try:
        while queue and len(queue) + len(subtrees) < want:
            # One level, breadth first: the nodes split before the queue holds `want`
            # are known in advance, and their splits (disjoint ranges) run at once.
            level, queue, size = queue, [], len(queue) + len(subtrees)
            taken = 0
            for _, s, e in level:
                if size >= want:
                    break
                size += -1 if e - s <= leaf_size else 1
                taken += 1
            inner = [(s, e) for _, s, e in level[:taken] if e - s > leaf_size]
            split = lambda r: _split_node(cen, lo, hi, order, r[0], r[1], bins)  # noqa: E731
            if pool and len(inner) > 1:
                mids = iter(list(pool.map(split, inner)))
            elif pool and inner:  # the first split: its passes on the threads
                mids = iter([_split_root(cen, lo, hi, order, *inner[0], bins, threads)])
            else:
                mids = iter([split(r) for r in inner])
            for node, s, e in level[:taken]:
                if e - s <= leaf_size:
                    first[node], count[node] = s, e - s
                    continue
                mid = next(mids)
                left = len(first)
                first += [0, 0]
                count += [0, 0]
                first[node], count[node] = left, 0
                queue += [(left, s, mid), (left + 1, mid, e)]
            queue = level[taken:] + queue
    finally:
        if pool is not None:
            pool.shutdown()
    return first, count, subtrees + queue


@numba.njit(cache=True, nogil=True)
def _build_subtree(cen, lo, hi, order, s0, e0, leaf_size, bins):
    """The BVH over entries s0..e0 of `order`, with an explicit stack.

    Returns first, count (int64, capacity 2(e0 - s0)) and the number of nodes:
    local node 0 is the subtree root; an inner node's `first` is a local node
    index, a leaf's `first` a position in the whole `order`.
    """
    n = e0 - s0
    cap = max(1, 2 * n)
    first = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    stack = np.empty((n + 1, 3), np.int64)  # node, start, end
    stack[0, 0] = 0
    stack[0, 1] = s0
    stack[0, 2] = e0
    sp = 1
    n_nodes = 1
    while sp > 0:
        sp -= 1
        node = stack[sp, 0]
        s = stack[sp, 1]
        e = stack[sp, 2]
        if e - s <= leaf_size:
            first[node] = s
            count[node] = e - s
            continue
        mid = _split_node(cen, lo, hi, order, s, e, bins)
        left = n_nodes
        n_nodes += 2
        first[node] = left
        count[node] = 0
        stack[sp, 0] = left + 1
        stack[sp, 1] = mid
        stack[sp, 2] = e
        stack[sp + 1, 0] = left
        stack[sp + 1, 1] = s
        stack[sp + 1, 2] = mid
        sp += 2
    return first, count, n_nodes


@numba.njit(cache=True, nogil=True)
def _split_node(cen, lo, hi, order, s, e, bins):
    """Binned-SAH split of entries s..e (more than one); reorders them, returns the middle.

    cen float64 (R, 3) centroids and lo, hi float32 (R, 3) boxes are in the
    order of `order` and permuted with it.
    """
    nb = min(bins, e - s)  # a node of m regions needs no more than m bins (most nodes are small)
    cmin, cmax = _centroid_bounds(cen, s, e)
    scale = _scales(cmin, cmax, nb)
    bcount, bbox = _binned(cen, lo, hi, s, e, cmin, cmax, scale, nb)
    return _split_at_best(cen, lo, hi, order, s, e, nb, cmin, cmax, scale, bcount, bbox)


def _split_root(cen, lo, hi, order, s, e, bins, chunks):
    """_split_node with its two passes over the entries (their centroids' bounds,
    then the bins) in `chunks` parts on numba's threads, merged: the same bounds,
    counts and boxes (minima, maxima and sums do not depend on the order), so the
    same split. For the first split, which no other split runs beside."""
    nb = min(bins, e - s)
    edges = np.linspace(s, e, chunks + 1).astype(np.int64)
    lows, highs = _centroid_bounds_chunks(cen, edges)
    cmin, cmax = lows.min(axis=0), highs.max(axis=0)
    scale = _scales(cmin, cmax, nb)
    counts, boxes = _binned_chunks(cen, lo, hi, edges, cmin, cmax, scale, nb)
    bbox = np.concatenate([boxes[..., :3].min(axis=0), boxes[..., 3:].max(axis=0)], axis=-1)
    return _split_at_best(cen, lo, hi, order, s, e, nb, cmin, cmax, scale, counts.sum(axis=0), bbox)


@numba.njit(cache=True, nogil=True)
def _centroid_bounds(cen, s, e):
    cmin = np.full(3, np.inf)
    cmax = np.full(3, -np.inf)
    for k in range(s, e):
        for ax in range(3):
            c = cen[k, ax]
            if c < cmin[ax]:
                cmin[ax] = c
            if c > cmax[ax]:
                cmax[ax] = c
    return cmin, cmax


@numba.njit(cache=True, parallel=True)
def _centroid_bounds_chunks(cen, edges):
    n = edges.shape[0] - 1
    lows = np.empty((n, 3))
    highs = np.empty((n, 3))
    for i in numba.prange(n):
        lows[i], highs[i] = _centroid_bounds(cen, edges[i], edges[i + 1])
    return lows, highs


@numba.njit(cache=True, nogil=True)
def _scales(cmin, cmax, nb):
    scale = np.empty(3)
    for ax in range(3):
        scale[ax] = nb / (cmax[ax] - cmin[ax]) if cmax[ax] > cmin[ax] else 0.0
    return scale


@numba.njit(cache=True, nogil=True)
def _binned(cen, lo, hi, s, e, cmin, cmax, scale, nb):
    """Every entry's bin by centroid on every axis: counts and boxes (lower, upper)."""
    inf = np.inf
    bcount = np.zeros((3, nb), np.int64)
    bbox = np.empty((3, nb, 6))
    for ax in range(3):
        for t in range(nb):
            for q in range(3):
                bbox[ax, t, q] = inf
                bbox[ax, t, 3 + q] = -inf
    for k in range(s, e):
        for ax in range(3):
            if cmax[ax] <= cmin[ax]:
                continue
            t = _bin(cen[k, ax], cmin[ax], scale[ax], nb)
            bcount[ax, t] += 1
            for q in range(3):
                if lo[k, q] < bbox[ax, t, q]:
                    bbox[ax, t, q] = lo[k, q]
                if hi[k, q] > bbox[ax, t, 3 + q]:
                    bbox[ax, t, 3 + q] = hi[k, q]
    return bcount, bbox


@numba.njit(cache=True, parallel=True)
def _binned_chunks(cen, lo, hi, edges, cmin, cmax, scale, nb):
    n = edges.shape[0] - 1
    counts = np.empty((n, 3, nb), np.int64)
    boxes = np.empty((n, 3, nb, 6))
    for i in numba.prange(n):
        counts[i], boxes[i] = _binned(cen, lo, hi, edges[i], edges[i + 1], cmin, cmax, scale, nb)
    return counts, boxes


@numba.njit(cache=True, nogil=True)
def _split_at_best(cen, lo, hi, order, s, e, nb, cmin, cmax, scale, bcount, bbox):
    """The SAH sweep over the bins, then the entries of the best side moved left."""
    m = e - s
    inf = np.inf
    right_area = np.empty(nb)
    right_count = np.empty(nb, np.int64)
    best_cost = inf
    best_axis = -1
    best_split = -1
    for ax in range(3):
        if cmax[ax] <= cmin[ax]:
            continue
        # Suffix sweep: area and count of bins t..nb-1.
        l0 = inf
        l1 = inf
        l2 = inf
        h0 = -inf
        h1 = -inf
        h2 = -inf
        c = 0
        for t in range(nb - 1, 0, -1):
            c += bcount[ax, t]
            l0 = min(l0, bbox[ax, t, 0])
            l1 = min(l1, bbox[ax, t, 1])
            l2 = min(l2, bbox[ax, t, 2])
            h0 = max(h0, bbox[ax, t, 3])
            h1 = max(h1, bbox[ax, t, 4])
            h2 = max(h2, bbox[ax, t, 5])
            right_count[t] = c
            right_area[t] = _half_area(l0, l1, l2, h0, h1, h2) if c > 0 else 0.0
        l0 = inf
        l1 = inf
        l2 = inf
        h0 = -inf
        h1 = -inf
        h2 = -inf
        c = 0
        for t in range(nb - 1):
            c += bcount[ax, t]
            l0 = min(l0, bbox[ax, t, 0])
            l1 = min(l1, bbox[ax, t, 1])
            l2 = min(l2, bbox[ax, t, 2])
            h0 = max(h0, bbox[ax, t, 3])
            h1 = max(h1, bbox[ax, t, 4])
            h2 = max(h2, bbox[ax, t, 5])
            if c == 0 or right_count[t + 1] == 0:
                continue
            cost = c * _half_area(l0, l1, l2, h0, h1, h2) + right_count[t + 1] * right_area[t + 1]
            if cost < best_cost:
                best_cost = cost
                best_axis = ax
                best_split = t
    mid = s
    if best_axis >= 0:
        # Left: bins 0..best_split.  Same _bin call as above, so the counts hold.
        j = s
        for k in range(s, e):
            if _bin(cen[k, best_axis], cmin[best_axis], scale[best_axis], nb) <= best_split:
                _swap(order, cen, lo, hi, j, k)
                j += 1
        mid = j
    if mid == s or mid == e:
        # All centroids equal (degenerate input): split the list in half.
        mid = s + m // 2
    return mid


@numba.njit(cache=True, inline="always")
def _swap(order, cen, lo, hi, j, k):
    """Exchange entries j and k of the order and of the per-entry arrays."""
    t = order[j]
    order[j] = order[k]
    order[k] = t
    for ax in range(3):
        c = cen[j, ax]
        cen[j, ax] = cen[k, ax]
        cen[k, ax] = c
        a = lo[j, ax]
        lo[j, ax] = lo[k, ax]
        lo[k, ax] = a
        b = hi[j, ax]
        hi[j, ax] = hi[k, ax]
        hi[k, ax] = b


@numba.njit(cache=True, inline="always")
def _bin(c, cmin, scale, bins):
    """Bin of centroid coordinate c: floor((c - cmin) * scale), clamped to 0..bins-1."""
    t = int((c - cmin) * scale)
    return min(max(t, 0), bins - 1)


@numba.njit(cache=True)
def refit(first, count, order, lo, hi, region_vr, region_finest):
    """Node bounds, value ranges and finest levels, children before parents.

    Returns lower, upper float32 (M, 3), value_range float32 (M, F, 2) and
    finest_level int8 (M,).  NaN region ranges (no data) are ignored; a node
    with no number in a field gets NaN.
    """
    m = first.shape[0]
    n_fields = region_vr.shape[1]
    nlo = np.empty((m, 3), np.float32)
    nhi = np.empty((m, 3), np.float32)
    vr = np.empty((m, n_fields, 2), np.float32)
    fl = np.empty(m, np.int8)
    for node in range(m - 1, -1, -1):
        for ax in range(3):
            nlo[node, ax] = np.inf
            nhi[node, ax] = -np.inf
        for f in range(n_fields):
            vr[node, f, 0] = np.inf
            vr[node, f, 1] = -np.inf
        finest = 127
        if count[node] == 0:
            a = first[node]
            for c in range(a, a + 2):
                for ax in range(3):
                    nlo[node, ax] = min(nlo[node, ax], nlo[c, ax])
                    nhi[node, ax] = max(nhi[node, ax], nhi[c, ax])
                for f in range(n_fields):
                    if vr[c, f, 0] < vr[node, f, 0]:
                        vr[node, f, 0] = vr[c, f, 0]
                    if vr[c, f, 1] > vr[node, f, 1]:
                        vr[node, f, 1] = vr[c, f, 1]
                finest = min(finest, fl[c])
        else:
            for k in range(first[node], first[node] + count[node]):
                r = order[k]
                for ax in range(3):
                    nlo[node, ax] = min(nlo[node, ax], lo[r, ax])
                    nhi[node, ax] = max(nhi[node, ax], hi[r, ax])
                for f in range(n_fields):
                    if region_vr[r, f, 0] < vr[node, f, 0]:
                        vr[node, f, 0] = region_vr[r, f, 0]
                    if region_vr[r, f, 1] > vr[node, f, 1]:
                        vr[node, f, 1] = region_vr[r, f, 1]
                finest = min(finest, region_finest[r])
        fl[node] = finest
    # Only after all parents read their children: inf/-inf (no number) becomes NaN.
    for node in range(m):
        for f in range(n_fields):
            if vr[node, f, 0] > vr[node, f, 1]:
                vr[node, f, 0] = np.nan
                vr[node, f, 1] = np.nan
    return nlo, nhi, vr, fl
