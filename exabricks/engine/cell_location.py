"""A tree over the brick supports for per-sample cell location (paper §6.4.2, Table 3).

The paper measures its reconstruction from the Active Brick Regions' brick
lists against the basis method with a cell-location kernel (Wald et al. 2017):
every sample descends a tree from the root to find the bricks whose support
contains it. This module builds that tree (binned SAH, exabricks.builders.bvh)
over the brick *supports*, each brick's box grown by half its cell width on
every side, the only place its cells' hats are non-zero. It is built in
memory when a `Renderer(reconstruction="cell-location")` asks for it, never
stored; kernels/cell_location.cl walks it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import schema
from ..util.constants import BOUNDS_DTYPE, INDEX_DTYPE, MAX_TREE_DEPTH
from ..util.errors import ExabricksError
from ..builders.bvh import tree_depths, build_tree, tree_bounds

# Bricks per leaf: with 1 a node box is the brick's support, so a sample adds only bricks
# whose support holds it; frames were faster than with 2 and 4 bricks per leaf
# (measured: docs/benchmarks-decisions.md, "Measurements behind design choices").
LEAF_SIZE = 1



@dataclass(frozen=True)
class BrickTree:
    """Binned-SAH tree over brick supports, node 0 the root.

    lower, upper: float32 (M, 3) node boxes, lattice units (union of the supports below).
    first, count: int32 (M,); count 0: inner node with children first, first + 1;
                  else a leaf listing brick_index[first : first + count].
    brick_index:  int32 (B,), brick ids in leaf order.
    depth:        levels of the tree (root alone: 1).
    """

    lower: np.ndarray
    upper: np.ndarray
    first: np.ndarray
    count: np.ndarray
    brick_index: np.ndarray
    depth: int


def support_boxes(bricks: schema.Bricks) -> tuple[np.ndarray, np.ndarray]:
    """Support of every brick, float32 (B, 3) lower and upper, lattice units (exact: half-integers)."""
    width = np.ldexp(1.0, bricks.level.astype(np.int32))[:, None]
    lower = bricks.lower_lattice.astype(np.float64)
    upper = lower + bricks.dims * width
    return (lower - 0.5 * width).astype(BOUNDS_DTYPE), (upper + 0.5 * width).astype(BOUNDS_DTYPE)


def build_brick_tree(bricks: schema.Bricks, *, leaf_size: int = LEAF_SIZE) -> BrickTree:
    """The tree over `bricks`' supports (see BrickTree); ExabricksError if there are no
    bricks or the tree is deeper than the kernel's stack."""
    lo, hi = support_boxes(bricks)
    first, count, order, _ = build_tree(lo, hi, leaf_size=leaf_size, item="brick")
    node_lo, node_hi = tree_bounds(first, count, order, lo, hi)
    depth = int(tree_depths(first, count).max()) + 1
    if depth > MAX_TREE_DEPTH:
        raise ExabricksError(f"the brick tree is {depth} levels deep, more than the cell-location "
                             f"kernel's stack of {MAX_TREE_DEPTH}")
    return BrickTree(node_lo, node_hi, first.astype(INDEX_DTYPE), count.astype(INDEX_DTYPE),
                     order.astype(INDEX_DTYPE), depth)

