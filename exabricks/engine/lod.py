"""Mip levels of every brick for level-of-detail rendering (`render --lod`).

Mip level m of a brick of level l and dims N is a grid of cells of level
l + m anchored at the brick's lower corner, ceil(N / 2**m) per axis; each
mip cell holds the mean of the brick's cells inside it (all of equal volume,
so the volume-weighted average; partial cells at the brick's upper faces
average the cells they cover). kernels/reconstruction.cl (eb_add_brick_lod)
reconstructs from them with the basis method at the coarser width when a
region is sampled at a coarser level than its data. Levels 1 .. MAX_MIP are
kept (the kernels' EB_MAX_MIP); a brick of one cell has one-cell mips.
"""

from __future__ import annotations

import numba
import numpy as np

from .. import schema
from ..device.kernel_abi import MAX_MIP



def mip_layout(dims: np.ndarray) -> tuple[np.ndarray, int]:
    """Offsets int64 (B, MAX_MIP) of every brick's mip levels 1..MAX_MIP, and the total."""
    dims = dims.astype(np.int64)
    counts = np.stack([(((dims - 1) >> m) + 1).prod(axis=1) for m in range(1, MAX_MIP + 1)],
                      axis=1)
    flat = counts.ravel()
    offset = np.zeros(flat.size, np.int64)
    np.cumsum(flat[:-1], out=offset[1:])
    return offset.reshape(counts.shape), int(flat.sum())


@numba.njit(cache=True, parallel=True)
def _mips(values, brick_offset, dims, mip_offset, total):
    """Mean of the fine cells under each mip cell, per field: float32 (F, total)."""
    n_fields = values.shape[0]
    out = np.zeros((n_fields, total), np.float32)
    for b in numba.prange(dims.shape[0]):
        nx, ny, nz = dims[b, 0], dims[b, 1], dims[b, 2]
        for m in range(1, mip_offset.shape[1] + 1):
            mx, my = ((nx - 1) >> m) + 1, ((ny - 1) >> m) + 1
            mz = ((nz - 1) >> m) + 1
            base = mip_offset[b, m - 1]
            for f in range(n_fields):
                sums = np.zeros(mx * my * mz, np.float64)
                counts = np.zeros(mx * my * mz, np.int64)
                i = brick_offset[b]
                for z in range(nz):
                    for y in range(ny):
                        for x in range(nx):
                            k = ((z >> m) * my + (y >> m)) * mx + (x >> m)
                            sums[k] += values[f, i]
                            counts[k] += 1
                            i += 1
                for k in range(sums.size):
                    out[f, base + k] = sums[k] / counts[k]
    return out


def brick_mips(bricks: schema.Bricks, field_indices) -> tuple[np.ndarray, np.ndarray]:
    """(offset int64 (B, MAX_MIP), values float32 (F, total)) of the fields
    `field_indices` of `bricks` (NaN cells make their mip cells NaN)."""
    offset, total = mip_layout(bricks.dims)
    values = np.ascontiguousarray(bricks.values[list(field_indices)])
    return offset, _mips(values, bricks.offset, bricks.dims.astype(np.int64), offset, total)
