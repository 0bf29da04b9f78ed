"""Vertex values for the "vertex" reconstruction (Kähler & Hege; docs/design.md).

Every brick gets a value at each of its (N.x+1)(N.y+1)(N.z+1) cell corners,
and a point inside one of its cells is the trilinear interpolation of that
cell's 8 corners (kernels/reconstruction.cl, eb_vertex). The corner values
are the basis field (paper eq. 1-2) there: continuous, so bricks of one level
agree on the corners they share.

Stitching level boundaries: a corner of a fine brick that lies on the closed
box of a coarser leaf cell (a "hanging" vertex on the coarse cell's face,
edge or corner) takes the coarse cell's trilinear interpolation instead, from
the coarsest such cell. Levels are done coarsest first, so the coarse values
are final when a finer level reads them. A fine face is then bilinear between
corners that lie on the coarse cell's bilinear face function, so both sides
agree everywhere on the face: the field is continuous across level boundaries
(T-junctions close), whatever the level jump.
"""

from __future__ import annotations

from typing import Callable

import numba
import numpy as np

from .. import schema
from ..util.errors import ExabricksError


def vertex_layout(bricks: schema.Bricks) -> tuple[np.ndarray, int]:
    """Offsets (int64 (B,)) of every brick's vertex block, and the total count."""
    counts = (bricks.dims.astype(np.int64) + 1).prod(axis=1)
    offset = np.zeros(bricks.n_bricks, np.int64)
    np.cumsum(counts[:-1], out=offset[1:])
    return offset, int(counts.sum())


@numba.njit(cache=True, parallel=True)
def _vertex_lattice(lower, level, dims, offset, total):
    """Lattice position of every vertex, int64 (M, 3), x fastest within a brick."""
    out = np.empty((total, 3), np.int64)
    for b in numba.prange(lower.shape[0]):
        w = np.int64(1) << np.int64(level[b])
        i = offset[b]
        for z in range(dims[b, 2] + 1):
            for y in range(dims[b, 1] + 1):
                for x in range(dims[b, 0] + 1):
                    out[i, 0] = lower[b, 0] + x * w
                    out[i, 1] = lower[b, 1] + y * w
                    out[i, 2] = lower[b, 2] + z * w
                    i += 1
    return out


def vertex_values(bricks: schema.Bricks,
                  basis_at: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(offset int64 (B,), values float32 (F, M)): the stitched vertex values.

    basis_at(lattice float64 (K, 3)) -> (F, K) values of the basis field at
    lattice points (the device probe, exabricks.engine.device_data.DeviceDataset.probe_fields).
    """
    offset, total = vertex_layout(bricks)
    lattice = _vertex_lattice(bricks.lower_lattice.astype(np.int64), bricks.level,
                              bricks.dims.astype(np.int64), offset, total)
    values = np.ascontiguousarray(basis_at(lattice.astype(np.float64)), np.float32)
    counts = (bricks.dims.astype(np.int64) + 1).prod(axis=1)
    vertex_level = np.repeat(bricks.level, counts)
    levels = sorted(set(int(l) for l in np.unique(bricks.level)), reverse=True)
    cells = {L: _LevelCells(bricks, L) for L in levels}
    for i, l in enumerate(levels):
        todo = np.flatnonzero(vertex_level == l)
        for L in levels[:i]:  # coarser levels, coarsest first
            if todo.size == 0:
                break
            found, brick, local, frac = cells[L].containing(lattice[todo])
            hit = todo[found]
            values[:, hit] = _interpolate(values, bricks, offset, brick[found], local[found],
                                          frac[found])
            todo = todo[~found]
    return offset, values


class _LevelCells:
    """The leaf cells of one level, found by their integer index lower >> level."""

    def __init__(self, bricks: schema.Bricks, level: int):
        ids = np.flatnonzero(bricks.level == level)
        dims = bricks.dims[ids].astype(np.int64)
        n = dims.prod(axis=1)
        self.level = level
        self.brick_lower = bricks.lower_lattice.astype(np.int64)
        brick = np.repeat(ids, n)
        first = np.repeat(np.cumsum(n) - n, n)
        k = np.arange(brick.size) - first  # cell index within its brick, x fastest
        d = dims[np.repeat(np.arange(ids.size), n)]
        local = np.column_stack([k % d[:, 0], (k // d[:, 0]) % d[:, 1], k // (d[:, 0] * d[:, 1])])
        q = (bricks.lower_lattice[brick].astype(np.int64) >> level) + local
        self.qmin = q.min(axis=0) - 1
        span = q.max(axis=0) + 2 - self.qmin
        if np.sum(np.ceil(np.log2(span + 1))) > 62:
            raise ExabricksError(f"level-{level} cells span {span.tolist()} cells: too wide "
                                 "for the vertex reconstruction's cell index")
        self.span = span
        key = self._key(q)
        order = np.argsort(key, kind="stable")
        self.keys, self.brick, self.local = key[order], brick[order], local[order]

    def _key(self, q):
        q = q - self.qmin
        return (q[..., 2] * self.span[1] + q[..., 1]) * self.span[0] + q[..., 0]

    def containing(self, points: np.ndarray):
        """For lattice points int64 (K, 3): found (bool (K,)), and for each the brick,
        the local cell index (K, 3) and the position in the cell in [0, 1]^3 of a
        level cell whose closed box contains the point."""
        w = np.int64(1) << np.int64(self.level)
        base = points >> self.level
        on_face = (points & (w - 1)) == 0
        found = np.zeros(points.shape[0], bool)
        cell = np.zeros(points.shape[0], np.int64)
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    d = np.array([dx, dy, dz])
                    ok = ~found & np.all(on_face | (d == 0), axis=1)
                    q = base[ok] - d
                    inside = np.all((q >= self.qmin) & (q < self.qmin + self.span), axis=1)
                    key = np.where(inside, self._key(np.where(inside[:, None], q, self.qmin)), -1)
                    at = np.clip(np.searchsorted(self.keys, key), 0, max(self.keys.size - 1, 0))
                    hit = inside & (self.keys.size > 0) & (self.keys[at] == key)
                    rows = np.flatnonzero(ok)[hit]
                    found[rows] = True
                    cell[rows] = at[hit]
        brick = self.brick[cell]
        local = self.local[cell]
        cell_lower = self.brick_lower[brick] + local * w
        frac = (points - cell_lower).astype(np.float64) / float(w)
        return found, brick, local, frac


def _interpolate(values, bricks, offset, brick, local, frac) -> np.ndarray:
    """Trilinear interpolation (F, K) of the vertex values of cells (brick, local
    index) at positions `frac` in [0, 1]^3 (float64 sums)."""
    dims = bricks.dims[brick].astype(np.int64)
    nx, nxy = dims[:, 0] + 1, (dims[:, 0] + 1) * (dims[:, 1] + 1)
    base = offset[brick] + local[:, 2] * nxy + local[:, 1] * nx + local[:, 0]
    out = np.zeros((values.shape[0], brick.size), np.float64)
    for dz in (0, 1):
        wz = frac[:, 2] if dz else 1.0 - frac[:, 2]
        for dy in (0, 1):
            wy = frac[:, 1] if dy else 1.0 - frac[:, 1]
            for dx in (0, 1):
                wx = frac[:, 0] if dx else 1.0 - frac[:, 0]
                out += (wx * wy * wz) * values[:, base + dz * nxy + dy * nx + dx]
    return out.astype(np.float32)
