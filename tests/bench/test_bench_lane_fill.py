"""benchmarks/bench_lane_fill.py: its BVH walk finds exactly the regions a ray
crosses (against every region's slab test), and packets of one ray fill their lanes."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from helpers import GERRIS

from benchmarks.bench_lane_fill import _fill, _walk, lattice_rays, tree_arrays
from exabricks.readers import read
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.builders.regions import build_regions

pytestmark = pytest.mark.slow  # a benchmark's helpers, compiled by numba on first use


@functools.lru_cache(maxsize=None)
def gerris():
    bricks = build_bricks(read(GERRIS))
    regions = build_regions(bricks)
    return bricks, regions, build_bvh(regions)


def test_the_walk_finds_every_region_a_ray_crosses():
    bricks, regions, bvh = gerris()
    origins, directions = lattice_rays(bricks, 24)
    tree = tree_arrays(regions, bvh)
    lo, hi = regions.lower_lattice.astype(np.float64), regions.upper_lattice.astype(np.float64)
    crossed = 0
    for o, d in zip(origins.reshape(-1, 3), directions.reshape(-1, 3)):
        ids, weights = np.empty(4096, np.int64), np.empty(4096)
        n = _walk(o, d, *tree, ids, weights)
        a, b = (lo - o) / d, (hi - o) / d
        t0 = np.maximum(np.minimum(a, b).max(axis=1), 0.0)
        t1 = np.maximum(a, b).min(axis=1)
        expected = np.flatnonzero(t0 < t1)
        assert sorted(ids[:n].tolist()) == expected.tolist()
        np.testing.assert_allclose(
            weights[:n], ((t1 - t0) * np.linalg.norm(d) / (1 << regions.finest_level.astype(np.int64)))[ids[:n]])
        crossed += n
    assert crossed > 24 * 24  # most rays cross several regions


def test_a_packet_of_one_ray_fills_every_lane():
    bricks, regions, bvh = gerris()
    origins, directions = lattice_rays(bricks, 8)
    same_o = np.broadcast_to(origins[4, 4], (8, 8, 3)).copy()
    same_d = np.broadcast_to(directions[4, 4], (8, 8, 3)).copy()
    out = _fill(same_o, same_d, 2, 2, *tree_arrays(regions, bvh), 4096)
    assert out[:, 1].min() > 0
    np.testing.assert_array_equal(out[:, 0], 4 * out[:, 1])  # every lane in every region
    np.testing.assert_array_equal(out[:, 2], 4 * out[:, 3])
