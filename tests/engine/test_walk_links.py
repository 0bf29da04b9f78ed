"""The stackless region walk's links (exabricks.engine.walk_links): every node's
parent, and the order of each inner node's children along its split axis, on
the BVHs of the shared datasets; and the walk they drive, replayed here in
Python, visits the nodes a stack-based near-first traversal visits, in its order.
(tests/engine/test_render_traversal.py checks the kernel's frames.)"""

from __future__ import annotations

import numpy as np
import pytest

from exabricks.engine.walk_links import FLIP_BIT, PARENT_SHIFT, walk_links

from helpers import AMREX, ENZO, GERRIS, built_scene

DATASETS = {"gerris": (GERRIS, "T"), "amrex": (AMREX, "phi"), "enzo": (ENZO, "Density")}


def links_of(name):
    bvh = built_scene(*DATASETS[name])[2]
    return bvh, walk_links(bvh.first, bvh.count, bvh.lower_lattice, bvh.upper_lattice)


@pytest.mark.parametrize("name", list(DATASETS))
def test_parents_and_child_orders(name):
    bvh, links = links_of(name)
    assert bvh.n_nodes > 100  # a real tree
    parent = links >> PARENT_SHIFT
    assert parent[0] == -1
    inner = np.flatnonzero(bvh.count == 0)
    first = bvh.first[inner]
    np.testing.assert_array_equal(parent[first], inner)
    np.testing.assert_array_equal(parent[first + 1], inner)
    assert np.count_nonzero(parent >= 0) == bvh.n_nodes - 1  # every node but the root has one
    centre = (bvh.lower_lattice + bvh.upper_lattice) / 2.0
    axis = links[inner] & (FLIP_BIT - 1)
    flip = (links[inner] & FLIP_BIT) != 0
    apart = centre[first + 1] - centre[first]
    assert np.all(axis < 3)
    along = apart[np.arange(inner.size), axis]
    np.testing.assert_array_equal(np.abs(along), np.abs(apart).max(axis=1))
    np.testing.assert_array_equal(flip, along < 0)
    assert np.all(links[bvh.count > 0] & ((1 << PARENT_SHIFT) - 1) == 0)  # leaves: no order


def test_a_single_leaf_is_a_root_without_parent():
    links = walk_links(np.array([0]), np.array([3]), np.zeros((1, 3)), np.ones((1, 3)))
    assert links.tolist() == [-1 << PARENT_SHIFT]


def stackless_visits(bvh, links, direction):
    """The nodes the kernel's walk (traversal.cl, every box hit) tests, in order."""
    def near(node):
        bits = links[node]
        return bvh.first[node] + int((direction[bits & 3] >= 0) == bool(bits & FLIP_BIT))

    out, node, state = [], 0, "test"
    while True:
        if state == "test":
            out.append(node)
            if bvh.count[node] == 0:
                node = near(node)
                continue
            state = "done"
            continue
        if node == 0:
            return out
        parent = links[node] >> PARENT_SHIFT
        first = bvh.first[parent]
        if node == near(parent):
            node, state = 2 * first + 1 - node, "test"
        else:
            node = parent


def stack_visits(bvh, links, direction):
    """The same order by a stack: near child pushed last."""
    def near(node):
        bits = links[node]
        return bvh.first[node] + int((direction[bits & 3] >= 0) == bool(bits & FLIP_BIT))

    out, stack = [], [0]
    while stack:
        node = stack.pop()
        out.append(node)
        if bvh.count[node] == 0:
            c = near(node)
            stack += [2 * bvh.first[node] + 1 - c, c]
    return out


@pytest.mark.parametrize("name", ["gerris", "amrex"])
def test_the_walk_without_a_stack_visits_as_one_with_a_stack(name):
    bvh, links = links_of(name)
    rng = np.random.default_rng(7)
    for direction in rng.normal(size=(8, 3)):
        got = stackless_visits(bvh, links, direction)
        assert got == stack_visits(bvh, links, direction)
        assert sorted(got) == list(range(bvh.n_nodes))  # each node once
