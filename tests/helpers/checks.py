"""Brute-force checks of built bricks, regions and BVH (the builders' tests and
their uncompiled twins in test_nojit run them)."""

from __future__ import annotations

import numpy as np
import pytest

from exabricks import schema
from exabricks.builders.regions import support_boxes_doubled


def expand(bricks: schema.Bricks) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every cell stored in `bricks`: int64 (V, 4) (x, y, z, level), float32 (F, V), brick ids (V,)."""
    n = bricks.dims.astype(np.int64).prod(axis=1)
    brick = np.repeat(np.arange(bricks.n_bricks), n)
    local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    d = bricks.dims.astype(np.int64)[brick]
    ijk = np.stack([local % d[:, 0], (local // d[:, 0]) % d[:, 1], local // (d[:, 0] * d[:, 1])], 1)
    width = (np.int64(1) << bricks.level.astype(np.int64))[brick]
    xyz = bricks.lower_lattice.astype(np.int64)[brick] + ijk * width[:, None]
    slot = bricks.offset[brick] + local  # x fastest, then y, then z
    return np.column_stack([xyz, bricks.level[brick]]), bricks.values[:, slot], brick


def by_key(keys: np.ndarray) -> np.ndarray:
    return np.lexsort(keys.T[::-1])


def assert_disjoint(lower: np.ndarray, upper: np.ndarray) -> None:
    """No two boxes [lower, upper) share volume (sweep along x, then exact tests)."""
    order = np.argsort(lower[:, 0], kind="stable")
    lo, hi = lower[order], upper[order]
    stop = np.searchsorted(lo[:, 0], hi[:, 0], side="left")
    count = stop - np.arange(len(lo)) - 1
    i = np.repeat(np.arange(len(lo)), count)
    j = i + 1 + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    overlap = np.all((lo[i] < hi[j]) & (lo[j] < hi[i]), axis=1)
    assert not overlap.any(), (order[i[overlap][:3]], order[j[overlap][:3]])


def check_bricks(cells: schema.Cells, bricks: schema.Bricks, max_brick_width: int) -> None:
    """The §3.1 contract: the bricks hold exactly the input cells, with their values."""
    schema.validate(bricks)
    assert bricks.fields == cells.fields
    np.testing.assert_array_equal(bricks.origin_world, cells.origin_world)
    np.testing.assert_array_equal(bricks.spacing_world, cells.spacing_world)
    assert bricks.dims.min() >= 1 and bricks.dims.max() <= max_brick_width
    # Each brick slot is one (x, y, z, level) cell; matching the input multiset
    # one to one means: every cell lands in exactly one brick, every brick is
    # completely full of same-level cells, and the bricks cover exactly the cells.
    keys, values, _ = expand(bricks)
    want = np.column_stack([cells.lower_lattice.astype(np.int64), cells.level])
    assert keys.shape == want.shape
    a, b = by_key(keys), by_key(want)
    np.testing.assert_array_equal(keys[a], want[b])
    np.testing.assert_array_equal(values[:, a], cells.values[:, b])
    width = (np.int64(1) << bricks.level.astype(np.int64))[:, None]
    assert_disjoint(bricks.lower_lattice.astype(np.int64),
                    bricks.lower_lattice + bricks.dims.astype(np.int64) * width)
    s = bricks.meta["statistics"]
    assert s["bricks"] == bricks.n_bricks and s["cells"] == cells.n_cells
    assert sum(s["bricks_per_level"].values()) == bricks.n_bricks
    hist = np.array(s["cells_per_brick_histogram"]).reshape(-1, 2)
    n_cells = bricks.dims.astype(np.int64).prod(axis=1)
    for k, count in hist:  # bins [k, 2k), powers of two in increasing order
        assert count == np.count_nonzero((n_cells >= k) & (n_cells < 2 * k)) > 0
    assert hist[:, 1].sum() == bricks.n_bricks and np.all(np.diff(np.log2(hist[:, 0])) >= 1)
    assert s["mean_cells_per_brick"] == pytest.approx(cells.n_cells / bricks.n_bricks)


def raster_count(lo2, hi2, origin, shape):
    """How many of the boxes (doubled integer bounds) cover each doubled-lattice voxel."""
    diff = np.zeros(tuple(s + 1 for s in shape), np.int32)
    lo = lo2 - origin
    hi = hi2 - origin
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                sign = (-1) ** (cx + cy + cz)
                idx = tuple((hi if c else lo)[:, a] for a, c in enumerate((cx, cy, cz)))
                np.add.at(diff, idx, sign)
    return diff.cumsum(0).cumsum(1).cumsum(2)[:-1, :-1, :-1]


def region_doubled(regions):
    lo2 = regions.lower_lattice.astype(np.float64) * 2
    hi2 = regions.upper_lattice.astype(np.float64) * 2
    assert np.array_equal(lo2, np.round(lo2)) and np.array_equal(hi2, np.round(hi2))
    return lo2.astype(np.int64), hi2.astype(np.int64)


def check_coverage_raster(bricks, regions, exact=True):
    """Regions are disjoint and cover exactly the union of brick supports (voxel raster);
    merged regions (exact False) cover it and may hold empty space besides, but every
    region overlaps some support."""
    s_lo, s_hi = support_boxes_doubled(bricks)
    r_lo, r_hi = region_doubled(regions)
    origin = s_lo.min(axis=0)
    shape = tuple(int(v) for v in s_hi.max(axis=0) - origin)
    assert r_lo.min() >= 0 or np.all(r_lo >= origin)
    assert np.all(r_hi <= s_hi.max(axis=0))
    cover = raster_count(r_lo, r_hi, origin, shape)
    union = raster_count(s_lo, s_hi, origin, shape) > 0
    assert cover.max() <= 1, "regions overlap"
    if exact:
        np.testing.assert_array_equal(cover == 1, union)
    else:
        assert np.all(cover[union] == 1), "a support point outside every region"


def check_regions_brute_force(bricks, regions, which=None, exact=True):
    """Brick lists, value ranges and finest levels of `which` regions against every cell;
    with `exact`, also that every listed support covers its whole region."""
    s_lo, s_hi = support_boxes_doubled(bricks)
    r_lo, r_hi = region_doubled(regions)
    c_lower, c_w, c_values, c_brick = brick_cells(bricks)
    c_lo = 2 * c_lower - c_w[:, None]
    c_hi = 2 * (c_lower + c_w[:, None]) + c_w[:, None]
    which = range(regions.n_regions) if which is None else which
    for r in which:
        overlap = np.all((s_lo < r_hi[r]) & (s_hi > r_lo[r]), axis=1)
        listed = regions.brick_ids[regions.brick_start[r]:regions.brick_start[r + 1]]
        np.testing.assert_array_equal(listed, np.flatnonzero(overlap))
        if exact:  # every listed support covers the whole region (it lies in one ABR)
            assert np.all(s_lo[listed] <= r_lo[r]) and np.all(s_hi[listed] >= r_hi[r])
        cells = np.all((c_lo < r_hi[r]) & (c_hi > r_lo[r]), axis=1)
        assert cells.any()
        assert set(np.unique(c_brick[cells])) == set(listed.tolist())
        v = c_values[:, cells]
        np.testing.assert_array_equal(regions.value_range[r, :, 0], v.min(axis=1))
        np.testing.assert_array_equal(regions.value_range[r, :, 1], v.max(axis=1))
        assert regions.finest_level[r] == bricks.level[listed].min()


def bvh_locate(bvh, regions, p):
    """Region containing point p (lattice units) by traversing the BVH; -1 if none."""
    stack = [0]
    found = []
    while stack:
        node = stack.pop()
        if np.any(p < bvh.lower_lattice[node]) or np.any(p >= bvh.upper_lattice[node]):
            continue
        if bvh.count[node] == 0:
            stack += [bvh.first[node], bvh.first[node] + 1]
            continue
        for k in range(bvh.first[node], bvh.first[node] + bvh.count[node]):
            r = bvh.region_index[k]
            if np.all(p >= regions.lower_lattice[r]) and np.all(p < regions.upper_lattice[r]):
                found.append(r)
    assert len(found) <= 1
    return found[0] if found else -1


def check_bvh(regions, bvh, points):
    m = bvh.n_nodes
    inner = bvh.count == 0
    # every node but the root is the child of exactly one inner node
    children = np.concatenate([bvh.first[inner], bvh.first[inner] + 1])
    assert sorted(children.tolist()) == list(range(1, m))
    # every region in exactly one leaf; leaf ranges tile region_index
    leaf_ranges = sorted((int(bvh.first[i]), int(bvh.count[i])) for i in np.flatnonzero(~inner))
    pos = 0
    for f, c in leaf_ranges:
        assert f == pos and c >= 1
        pos += c
    assert pos == regions.n_regions
    assert sorted(bvh.region_index.tolist()) == list(range(regions.n_regions))
    # bounds, value ranges, levels: children nest in parents
    par = np.flatnonzero(inner)
    for c in (bvh.first[par], bvh.first[par] + 1):
        assert np.all(bvh.lower_lattice[c] >= bvh.lower_lattice[par])
        assert np.all(bvh.upper_lattice[c] <= bvh.upper_lattice[par])
        assert np.all(bvh.finest_level[c] >= bvh.finest_level[par])
        assert np.all(bvh.value_range[c, :, 0] >= bvh.value_range[par, :, 0])
        assert np.all(bvh.value_range[c, :, 1] <= bvh.value_range[par, :, 1])
    # a leaf is exactly the union of its regions (reduce over each leaf's run)
    leaves = np.flatnonzero(~inner)
    leaves = leaves[np.argsort(bvh.first[leaves])]
    starts = bvh.first[leaves]
    rs = bvh.region_index
    for node_arr, reg_arr, ufunc in (
        (bvh.lower_lattice, regions.lower_lattice, np.minimum),
        (bvh.upper_lattice, regions.upper_lattice, np.maximum),
        (bvh.value_range[:, :, 0], regions.value_range[:, :, 0], np.minimum),
        (bvh.value_range[:, :, 1], regions.value_range[:, :, 1], np.maximum),
        (bvh.finest_level, regions.finest_level, np.minimum),
    ):
        np.testing.assert_array_equal(node_arr[leaves], ufunc.reduceat(reg_arr[rs], starts, axis=0))
    # the root covers everything
    np.testing.assert_array_equal(bvh.lower_lattice[0], regions.lower_lattice.min(0))
    np.testing.assert_array_equal(bvh.upper_lattice[0], regions.upper_lattice.max(0))
    np.testing.assert_array_equal(bvh.value_range[0, :, 0], regions.value_range[:, :, 0].min(0))
    np.testing.assert_array_equal(bvh.value_range[0, :, 1], regions.value_range[:, :, 1].max(0))
    # point location: BVH traversal agrees with a linear scan over all regions
    for p in points:
        inside = np.flatnonzero(np.all((p >= regions.lower_lattice) & (p < regions.upper_lattice), axis=1))
        assert len(inside) <= 1
        assert bvh_locate(bvh, regions, p) == (inside[0] if len(inside) else -1)


def query_points(regions, rng, n_random=200):
    """Region centres plus random points in (and a little around) the root box."""
    lo = regions.lower_lattice.min(0).astype(np.float64)
    hi = regions.upper_lattice.max(0).astype(np.float64)
    centres = 0.5 * (regions.lower_lattice + regions.upper_lattice)
    pad = 0.1 * (hi - lo)
    rand = rng.uniform(lo - pad, hi + pad, size=(n_random, 3))
    return np.concatenate([centres, rand.astype(np.float32)])


def check_support_tiling(bricks, regions):
    """Every support is tiled by the regions that list it: the volumes of its overlaps
    with them add up to its own volume (so no part of it lies in a region that does not
    list it).  With exact regions each overlap is the whole region."""
    s_lo, s_hi = support_boxes_doubled(bricks)
    r_lo, r_hi = region_doubled(regions)
    region = np.repeat(np.arange(regions.n_regions), np.diff(regions.brick_start))
    brick = regions.brick_ids
    overlap = np.minimum(r_hi[region], s_hi[brick]) - np.maximum(r_lo[region], s_lo[brick])
    assert np.all(overlap > 0), "a listed brick whose support misses the region"
    tiled = np.bincount(brick, weights=np.prod(overlap.astype(np.float64), axis=1),
                        minlength=bricks.n_bricks)
    np.testing.assert_array_equal(tiled, np.prod(s_hi - s_lo, axis=1).astype(np.float64))


def brick_cells(bricks: schema.Bricks):
    """Every cell of every brick: lower int64 (N, 3), width int64 (N,), values (F, N), brick (N,)."""
    lower, width, brick = [], [], []
    for b in range(bricks.n_bricks):
        d = bricks.dims[b]
        w = 1 << int(bricks.level[b])
        z, y, x = np.meshgrid(*(np.arange(d[a]) for a in (2, 1, 0)), indexing="ij")
        ijk = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)  # x fastest
        lower.append(bricks.lower_lattice[b].astype(np.int64) + w * ijk)
        width.append(np.full(len(ijk), w, np.int64))
        brick.append(np.full(len(ijk), b, np.int64))
    return (np.concatenate(lower), np.concatenate(width), bricks.values,
            np.concatenate(brick))
