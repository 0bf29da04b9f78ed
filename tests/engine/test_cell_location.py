"""The cell-location variant of the renderer (paper §6.4.2, Table 3).

The tree over the brick supports (exabricks.engine.cell_location) finds, for
any point, exactly the bricks whose support contains it; a renderer that finds
each sample's bricks through it (kernels/cell_location.cl) takes the same
samples and makes the same frame as the default, which reads the region's
brick list.
"""

from __future__ import annotations


import numpy as np
import pytest

from exabricks.util.errors import ExabricksError
from exabricks.engine.cell_location import build_brick_tree, support_boxes
from exabricks.engine.renderer import Renderer

from helpers import AMREX, ENZO, GERRIS, DEVICES, built_scene

SIZE = 64
DATASETS = {"gerris": (GERRIS, "T"), "amrex": (AMREX, "phi"), "enzo": (ENZO, "x-velocity")}




def scene(name: str):
    """(bricks, regions, bvh, field, camera, transfer function) of a shared dataset."""
    return built_scene(*DATASETS[name])


def tree_query(tree, lo, hi, points) -> set[tuple[int, int]]:
    """(point, brick) pairs from descending `tree` for every point at once (closed boxes),
    down to the leaves' bricks, whose supports (lo, hi) are tested as the kernel's
    eb_add_brick does."""
    def inside(node, point):
        p = points[point]
        return np.all((tree.lower[node] <= p) & (p <= tree.upper[node]), axis=1)

    point = np.arange(len(points))
    node = np.zeros(len(points), np.int64)
    keep = inside(node, point)
    point, node = point[keep], node[keep]
    found = []
    while point.size:
        leaf = tree.count[node] > 0
        for k in range(int(tree.count[node[leaf]].max(initial=0))):
            has = tree.count[node[leaf]] > k
            found.append((point[leaf][has], tree.brick_index[tree.first[node[leaf][has]] + k]))
        point, node = point[~leaf], node[~leaf]
        point = np.concatenate([point, point])
        node = np.concatenate([tree.first[node], tree.first[node] + 1]).astype(np.int64)
        keep = inside(node, point)
        point, node = point[keep], node[keep]
    pairs = {(int(p), int(b)) for ps, bs in found for p, b in zip(ps, bs)}
    return {(p, b) for p, b in pairs if np.all((lo[b] <= points[p]) & (points[p] <= hi[b]))}


def brute_force_query(lo, hi, points) -> set[tuple[int, int]]:
    """(point, brick) pairs with the point in the brick's closed support."""
    hit = np.all((lo[None] <= points[:, None]) & (points[:, None] <= hi[None]), axis=2)
    return {(int(p), int(b)) for p, b in zip(*np.nonzero(hit))}


@pytest.mark.parametrize("leaf_size", [1, 4])
@pytest.mark.parametrize("name", ["gerris", "amrex"])
def test_tree_finds_exactly_the_supports_containing_a_point(name, leaf_size):
    bricks, *_ = scene(name)
    tree = build_brick_tree(bricks, leaf_size=leaf_size)
    lo, hi = support_boxes(bricks)
    # Every brick is in exactly one leaf, and every node box holds what lies below it.
    assert np.array_equal(np.sort(tree.brick_index), np.arange(bricks.n_bricks))
    assert tree.count.max() <= leaf_size
    for node in np.flatnonzero(tree.count == 0):
        for c in (tree.first[node], tree.first[node] + 1):
            assert np.all(tree.lower[node] <= tree.lower[c]) and np.all(tree.upper[c] <= tree.upper[node])
    for node in np.flatnonzero(tree.count > 0):
        ids = tree.brick_index[tree.first[node]: tree.first[node] + tree.count[node]]
        assert np.all(tree.lower[node] <= lo[ids]) and np.all(hi[ids] <= tree.upper[node])
    # Random points over (and a little beyond) the root box, half of them snapped to the
    # half-integer lattice on which every support face lies.
    rng = np.random.default_rng(7)
    margin = 0.1 * (tree.upper[0] - tree.lower[0])
    points = rng.uniform(tree.lower[0] - margin, tree.upper[0] + margin, (4000, 3)).astype(np.float32)
    points[::2] = np.round(points[::2] * 2) / 2
    want = brute_force_query(lo, hi, points)
    per_point = np.bincount([p for p, _ in want], minlength=len(points))
    assert (per_point >= 1).mean() > 0.5 and (per_point >= 2).sum() > 100  # overlaps are tested
    assert tree_query(tree, lo, hi, points) == want


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("name", list(DATASETS))
@pytest.mark.parametrize("shading", ["headlight", "none"])
def test_cell_location_frame_equals_regions_frame(name, device, shading):
    bricks, regions, bvh, field, camera, tf = scene(name)
    frames = {}
    for lookup in ("regions", "cell-location"):
        # One sample at a time in both (sample packets exist for the regions' lists:
        # tests/engine/test_packets.py compares them with this path).
        renderer = Renderer(bricks, regions, bvh, field=field, device=device,
                            lookup=lookup, packets=False)
        frames[lookup] = renderer.render(camera=camera, transfer_function=tf, width=SIZE,
                                                 height=SIZE, shading=shading)
    ours, located = frames["regions"], frames["cell-location"]
    assert ours.stats["samples"] > SIZE * SIZE  # the view is not empty
    assert located.stats["samples"] == ours.stats["samples"]
    assert located.stats["lookup"] == "cell-location"
    # Every sample sums the same bricks in the same (ascending) order in both kernels, so
    # they round alike: bit-identical on PoCL. 1e-6 leaves room only for a compiler that
    # contracts a multiply-add differently in the two programs. (Summed in tree order,
    # Enzo's shaded frame differs by 0.02 in a few pixels where the field is locally
    # constant and the normalised gradient is rounding noise.)
    np.testing.assert_allclose(located.rgba, ours.rgba, rtol=0, atol=1e-6)


def test_unknown_lookup_is_one_clear_error():
    if not DEVICES:
        pytest.skip("no OpenCL device")
    bricks, regions, bvh, field, *_ = scene("amrex")
    with pytest.raises(ExabricksError, match="unknown brick lookup 'kd-tree'"):
        Renderer(bricks, regions, bvh, field=field, device=DEVICES[0], lookup="kd-tree")
