"""The analytic fields and the refinement rule of the AMR outputs the tests write in
other codes' own on-disk layouts (FLASH, Chombo, RAMSES: tests/helpers/*_output.py),
and the independent float64 check of what a reader makes of them.

A writer decides its own domain and leaves (cubic cells, at least three levels, some
levels only partly refined, by `refined`), stores at every cell, covered or not, the
float64 value of `value` at the cell's centre, and returns the leaves it wrote as
`Leaves` in world units.  Nothing here uses exabricks' readers: the expected cells
(`expected_cells`) come from the writer's own record and the formula.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from exabricks import schema

FIELDS = ("density", "pressure")


def value(name: str, centres, lo, hi) -> np.ndarray:
    """float64 value of field `name` at the points `centres` (N, 3) of the domain [lo, hi]:
    smooth, not separable, of several orders of magnitude (density) or signed (pressure)."""
    u = (np.asarray(centres, np.float64) - np.asarray(lo, np.float64)) / (
        np.asarray(hi, np.float64) - np.asarray(lo, np.float64))
    r2 = np.sum((u - CENTRE) ** 2, axis=1)
    if name == FIELDS[0]:
        return 0.05 + 10.0 * np.exp(-r2 / 0.02) + u[:, 0] * u[:, 1]
    if name == FIELDS[1]:
        return np.sin(7.0 * u[:, 0] + 3.0 * u[:, 2]) * np.cos(5.0 * u[:, 1]) + 0.1 * u[:, 2]
    raise KeyError(name)


# The refinement rule's centre, in units of the domain (off every cell boundary).
CENTRE = np.array([0.41, 0.37, 0.55])


def refined(lower, upper, lo, hi, level: int, *, radius: float = 0.3) -> np.ndarray:
    """Whether each box [lower, upper) (N, 3) world, of refinement level `level` (0:
    the coarsest), is refined: where it meets the ball of radius `radius` / 2**level
    (in units of the domain's x extent) about CENTRE, so every level is only partly
    refined."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = lo + CENTRE * (hi - lo)
    nearest = np.clip(centre, np.asarray(lower, np.float64), np.asarray(upper, np.float64))
    r = radius / 2 ** level * (hi[0] - lo[0])
    return np.sum((nearest - centre) ** 2, axis=1) < r ** 2


@dataclass(frozen=True)
class Leaves:
    """The leaf cells a writer wrote: lower corners (N, 3) and widths (N,), float64 world
    units, and the domain [lo, hi] its values were sampled over."""

    lower: np.ndarray
    width: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @property
    def centres(self) -> np.ndarray:
        return self.lower + 0.5 * self.width[:, None]


def expected_cells(leaves: Leaves, fields=FIELDS) -> schema.Cells:
    """The leaves as Cells, values float32 of the float64 formula at their centres."""
    fine = float(leaves.width.min())
    level = np.rint(np.log2(leaves.width / fine)).astype(np.int8)
    lattice = np.rint((leaves.lower - leaves.lo) / fine).astype(np.int32)
    values = np.stack([value(f, leaves.centres, leaves.lo, leaves.hi) for f in fields])
    return schema.Cells(fields=tuple(fields), origin_world=leaves.lo.astype(np.float64),
                        spacing_world=np.full(3, fine), lower_lattice=lattice, level=level,
                        values=values.astype(np.float32))


def assert_cells_match(cells: schema.Cells, leaves: Leaves, fields=FIELDS) -> None:
    """`cells` (what a reader made of a written output) hold exactly the written leaves,
    in world units, with float32 of the formula's float64 value at each centre."""
    want = expected_cells(leaves, fields)
    assert cells.fields == tuple(fields)
    assert cells.n_cells == want.n_cells
    np.testing.assert_allclose(cells.origin_world, want.origin_world, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cells.spacing_world, want.spacing_world, rtol=1e-12)
    assert len(np.unique(want.level)) >= 3
    mine = np.lexsort((cells.level, *cells.lower_lattice.T))
    theirs = np.lexsort((want.level, *want.lower_lattice.T))
    np.testing.assert_array_equal(cells.lower_lattice[mine], want.lower_lattice[theirs])
    np.testing.assert_array_equal(cells.level[mine], want.level[theirs])
    for i, name in enumerate(fields):
        np.testing.assert_array_equal(cells.values[i][mine], want.values[i][theirs], err_msg=name)


def assert_leaves_tile(leaves: Leaves) -> None:
    """The written leaves cover the domain once: their volumes add up to its volume and
    no two overlap (painted on the finest lattice)."""
    fine = leaves.width.min()
    extent = np.rint((leaves.hi - leaves.lo) / fine).astype(np.int64)
    lower = np.rint((leaves.lower - leaves.lo) / fine).astype(np.int64)
    size = np.rint(leaves.width / fine).astype(np.int64)
    paint = np.zeros(extent, np.int32)
    for (x, y, z), w in zip(lower, size):
        paint[x:x + w, y:y + w, z:z + w] += 1
    assert paint.min() == 1 and paint.max() == 1
