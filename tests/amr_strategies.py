"""Hypothesis strategies for random valid AMR layouts (shared by the stage tests).

`amr_cells()` draws a `schema.Cells` made by randomly refining an octree that
grows from a few root cells on a coarse grid: every cell is kept, dropped (a
hole) or split into its 8 children, so neighbours may differ by several
levels, holes appear at every level, and lone cells make single-cell bricks.
Refinement is either independent per cell or clustered around a few random
centres (which gives the larger uniform patches of block-structured codes).
Hypothesis draws the shape parameters (levels, root grid, probabilities, cell
budget, lattice offset); a drawn seed fills in the details with NumPy, so
layouts of a few thousand cells stay cheap to draw.  The cells come out in a
random order.  Field 0 ("id") holds each cell's index in the output (exact in
float32), field 1 ("noise") random values.
"""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from exabricks import schema


def refine_octree(
    rng: np.random.Generator,
    *,
    root_level: int,
    root_grid: tuple[int, int, int],
    root_fill: float,
    refine: float,
    hole: float,
    clustered: bool,
    base_depth: int,
    max_cells: int,
    offset: tuple[int, int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Lower corners int32 (N, 3) and levels int8 (N,) of a random octree refinement.

    Roots are level-`root_level` cells on a `root_grid` of such cells, each present
    with probability `root_fill`, shifted by `offset` root widths.  Cells less than
    `base_depth` levels below the roots are always split; every other cell above
    level 0 with probability `refine` (clustered: certainly when near one of a few
    random centres that asks for finer cells, else with probability `refine` / 4); every
    leaf is dropped with probability `hole`; refinement stops before it would add
    more than `max_cells` cells to the roots.
    """
    w_root = 1 << root_level
    grid = np.argwhere(np.ones(root_grid, bool))
    roots = grid[rng.random(len(grid)) < root_fill]
    if len(roots) == 0:
        roots = grid[rng.integers(len(grid))][None]
    lower = [tuple(int(v) for v in (r + np.asarray(offset)) * w_root) for r in roots]
    level = [root_level] * len(lower)
    extent = np.asarray(root_grid, float) * w_root
    centres = np.asarray(offset) * w_root + rng.random((3, 3)) * extent
    reach = rng.uniform(0.1, 0.6, 3) * extent.max()
    finest = rng.integers(0, root_level + 1, 3)
    leaves_lower, leaves_level = [], []
    queue = list(zip(lower, level))
    count = 0  # cells added by refinement
    head = 0
    while head < len(queue):
        (x, y, z), l = queue[head]
        head += 1
        if l > 0 and count + 7 <= max_cells:
            if l > root_level - base_depth:
                split = True
            elif clustered:
                w = 1 << l
                centre = np.array([x, y, z], float) + w / 2
                near = np.linalg.norm(centres - centre, axis=1) < reach + w
                split = bool(np.any(near & (finest < l))) or rng.random() < refine / 4
            else:
                split = rng.random() < refine
            if split:
                h = 1 << (l - 1)
                for dz in (0, h):
                    for dy in (0, h):
                        for dx in (0, h):
                            queue.append(((x + dx, y + dy, z + dz), l - 1))
                count += 7
                continue
        if rng.random() >= hole:
            leaves_lower.append((x, y, z))
            leaves_level.append(l)
    if not leaves_level:  # everything was a hole: keep one cell
        leaves_lower.append(lower[0])
        leaves_level.append(root_level)
    return np.array(leaves_lower, np.int32).reshape(-1, 3), np.array(leaves_level, np.int8)


def make_cells(lower: np.ndarray, level: np.ndarray, rng: np.random.Generator) -> schema.Cells:
    """Cells in a random order with fields "id" (index in the output) and "noise"."""
    order = rng.permutation(len(level))
    lower, level = np.ascontiguousarray(lower[order]), np.ascontiguousarray(level[order])
    n = len(level)
    values = np.stack([np.arange(n, dtype=np.float32), rng.standard_normal(n).astype(np.float32)])
    return schema.Cells(
        fields=("id", "noise"), origin_world=np.array([0.0, 0.0, 0.0]),
        spacing_world=np.array([1.0, 1.0, 1.0]),
        lower_lattice=lower, level=level, values=values,
    )


@st.composite
def amr_cells(draw, max_cells: int = 3000, max_level: int = 5) -> schema.Cells:
    """A random valid AMR layout as schema.Cells (see the module docstring).

    About 40% of the layouts have one level, 60% have holes, 20% have face
    neighbours two or more levels apart; most have single-cell bricks.  Sizes run
    from 1 cell to the root cells (at most 216) plus `max_cells`.
    """
    root_level = draw(st.integers(1, max_level))
    root_grid = tuple(draw(st.lists(st.integers(1, 6), min_size=3, max_size=3)))
    params = dict(
        root_level=root_level,
        root_grid=root_grid,
        root_fill=draw(st.sampled_from([1.0, 0.9, 0.6, 0.3])),
        refine=draw(st.sampled_from([0.0, 0.15, 0.4, 0.7, 0.9])),
        hole=draw(st.sampled_from([0.0, 0.0, 0.05, 0.3])),
        clustered=draw(st.booleans()),
        base_depth=draw(st.integers(0, 2)),
        # Budgets in buckets, so that large layouts are as common as small ones.
        max_cells=draw(st.sampled_from(sorted({40, 300, max_cells // 3, max_cells}))),
        offset=tuple(draw(st.lists(st.integers(-3, 3), min_size=3, max_size=3))),
    )
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    lower, level = refine_octree(rng, **params)
    return make_cells(lower, level, rng)
