"""What the stackless region walk needs beyond the BVH's own links: each node's
parent, and the order in which a ray visits an inner node's two children.

kernels/traversal.cl walks the BVH without a stack (Hapala, Davidovič, Wald,
Havran and Slusallek, "Efficient Stack-less BVH Traversal for Ray Tracing",
SCCG 2011): from a node it goes down to the near child, across to the sibling,
or up to the parent, deciding from where it came, so it keeps a node index and
a state in registers where a stack would keep up to a tree depth of entries in
memory. Coming back up, it must tell the near child from the far one again
without reading their boxes: the near child is the one lower along the node's
split axis (the axis of the children's centres' largest separation) for a ray
running up that axis, the other one for a ray running down it.

Per node, one int32 (the links buffer's `node_parent_at`, kernels/dataset.cl):
parent << 3 | flip << 2 | axis, where axis (0..2) and flip (1 when the second
child, first + 1, is the lower one along the axis) describe the node's own
children (zero for a leaf), and the root's parent is -1.
"""

from __future__ import annotations

import numpy as np

AXIS_BITS = 2
FLIP_BIT = 1 << AXIS_BITS
PARENT_SHIFT = AXIS_BITS + 1


def walk_links(first: np.ndarray, count: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """int32 (n,): parent, flip and axis of each of the BVH's n nodes ((first,
    count) links, count 0 for an inner node whose children are first and
    first + 1; lower and upper its (n, 3) lattice corners)."""
    n = first.shape[0]
    if n >= 1 << (31 - PARENT_SHIFT):
        raise ValueError(f"{n} BVH nodes: more than the walk's links can index")
    parent = np.full(n, -1, np.int64)
    inner = np.flatnonzero(np.asarray(count) == 0) if n > 1 else np.zeros(0, np.int64)
    child = np.asarray(first, np.int64)[inner]
    parent[child] = inner
    parent[child + 1] = inner
    centre = (np.asarray(lower, np.float64) + np.asarray(upper, np.float64)) * 0.5
    apart = centre[child + 1] - centre[child]
    axis = np.zeros(n, np.int64)
    flip = np.zeros(n, np.int64)
    axis[inner] = np.argmax(np.abs(apart), axis=1)
    flip[inner] = apart[np.arange(inner.size), axis[inner]] < 0
    return (parent << PARENT_SHIFT | flip << AXIS_BITS | axis).astype(np.int32)
