"""A uniform volume as AMR: `amr_from_uniform` merges homogeneous 2x2x2 groups
level by level, which is how scale-test inputs of tens of millions of cells are
made from a raw volume (`exabricks ingest --format raw --max-level`)."""

from __future__ import annotations

import numba
import numpy as np

from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE
from ..util.errors import ExabricksError


def amr_from_uniform(
    volume: np.ndarray, *, max_level: int | None = None, threshold: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge homogeneous 2x2x2 groups of a uniform volume into coarser cells, level by level.

    volume: (Z, Y, X) array (x fastest, C order) of float32 or float64 voxel values;
            voxel (i, j, k) = volume[k, j, i] becomes the level-0 cell at lattice (i, j, k).
    max_level: the coarsest level to create (None: as coarse as the dims allow).
    threshold: absolute; an aligned group of 8 cells of level l becomes one cell of
            level l + 1 when all 8 are themselves merged cells (or voxels) and
            max - min over all voxels they cover is <= threshold.  Non-finite
            voxels never merge.  Cells at a ragged edge (dims not multiples of
            2**(l+1)) that cannot form a full aligned group stay at level l.
    Returns lower_lattice int32 (N, 3), level int8 (N,), values float32 (N,): each
    value is the mean of the voxels the cell covers (computed in float64).  Cells
    come coarsest level first, each level in z, y, x order.
    """
    volume = np.asarray(volume)
    if volume.ndim != 3 or min(volume.shape) < 1:
        raise ExabricksError(f"a uniform volume must be 3-D and non-empty, got shape {volume.shape}")
    if volume.dtype not in (np.float32, np.float64):
        volume = volume.astype(np.float32)
    volume = np.ascontiguousarray(volume)
    possible = int(min(volume.shape)).bit_length() - 1
    top = possible if max_level is None else min(int(max_level), possible)
    if max_level is not None and max_level < 0:
        raise ExabricksError(f"max level must be >= 0, got {max_level}")
    top = min(top, MAX_LEVEL)
    threshold = float(threshold)
    if not threshold >= 0:
        raise ExabricksError(f"threshold must be >= 0, got {threshold}")

    # Level by level: mean, min, max of covered voxels and whether the cell exists
    # as one merged block.  Level 0 is the volume itself (exists where finite).
    means, mins, maxs, merged = [volume], [None], [None], [None]
    for l in range(1, top + 1):
        if l == 1:
            m, lo, hi, ok = _merge_first(volume, threshold)
        else:
            m, lo, hi, ok = _merge_next(means[-1], mins[-1], maxs[-1], merged[-1], threshold)
        if not ok.any():
            break
        means.append(m)
        mins.append(lo)
        maxs.append(hi)
        merged.append(ok)
    top = len(means) - 1

    counts = np.zeros(top + 1, np.int64)
    for l in range(top + 1):
        parent = merged[l + 1] if l < top else np.zeros((0, 0, 0), np.bool_)
        if l == 0:
            counts[l] = _count_leaves_first(volume.shape, parent)
        else:
            counts[l] = _count_leaves(merged[l], parent)
    n = int(counts.sum())
    lower = np.empty((n, 3), LATTICE_DTYPE)
    level = np.empty(n, LEVEL_DTYPE)
    values = np.empty(n, VALUE_DTYPE)
    start = 0
    for l in range(top, -1, -1):
        parent = merged[l + 1] if l < top else np.zeros((0, 0, 0), np.bool_)
        ok = merged[l] if l > 0 else np.ones((0, 0, 0), np.bool_)
        _emit_leaves(means[l], ok, l == 0, parent, l, start, lower, level, values)
        start += int(counts[l])
    return lower, level, values


@numba.njit(cache=True)
def _merge_first(vol, threshold):
    nz, ny, nx = vol.shape[0] // 2, vol.shape[1] // 2, vol.shape[2] // 2
    mean = np.empty((nz, ny, nx), np.float64)
    vmin = np.empty((nz, ny, nx), vol.dtype)
    vmax = np.empty((nz, ny, nx), vol.dtype)
    ok = np.zeros((nz, ny, nx), np.bool_)
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                s = 0.0
                lo = vol[2 * k, 2 * j, 2 * i]
                hi = lo
                good = True
                for c in range(8):
                    v = vol[2 * k + (c >> 2), 2 * j + ((c >> 1) & 1), 2 * i + (c & 1)]
                    if not np.isfinite(v):
                        good = False
                    s += v
                    lo = min(lo, v)
                    hi = max(hi, v)
                mean[k, j, i] = s / 8.0
                vmin[k, j, i] = lo
                vmax[k, j, i] = hi
                ok[k, j, i] = good and (np.float64(hi) - np.float64(lo) <= threshold)
    return mean, vmin, vmax, ok


@numba.njit(cache=True)
def _merge_next(mean0, min0, max0, ok0, threshold):
    nz, ny, nx = mean0.shape[0] // 2, mean0.shape[1] // 2, mean0.shape[2] // 2
    mean = np.empty((nz, ny, nx), np.float64)
    vmin = np.empty((nz, ny, nx), min0.dtype)
    vmax = np.empty((nz, ny, nx), max0.dtype)
    ok = np.zeros((nz, ny, nx), np.bool_)
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                good = True
                s = 0.0
                lo = min0[2 * k, 2 * j, 2 * i]
                hi = max0[2 * k, 2 * j, 2 * i]
                for c in range(8):
                    a, b, d = 2 * k + (c >> 2), 2 * j + ((c >> 1) & 1), 2 * i + (c & 1)
                    if not ok0[a, b, d]:
                        good = False
                    s += mean0[a, b, d]
                    lo = min(lo, min0[a, b, d])
                    hi = max(hi, max0[a, b, d])
                mean[k, j, i] = s / 8.0
                vmin[k, j, i] = lo
                vmax[k, j, i] = hi
                ok[k, j, i] = good and (np.float64(hi) - np.float64(lo) <= threshold)
    return mean, vmin, vmax, ok


@numba.njit(cache=True, inline="always")
def _parent_merged(parent, k, j, i):
    pk, pj, pi = k >> 1, j >> 1, i >> 1
    if pk < parent.shape[0] and pj < parent.shape[1] and pi < parent.shape[2]:
        return parent[pk, pj, pi]
    return False


@numba.njit(cache=True)
def _count_leaves_first(shape, parent):
    n = 0
    for k in range(shape[0]):
        for j in range(shape[1]):
            for i in range(shape[2]):
                if not _parent_merged(parent, k, j, i):
                    n += 1
    return n


@numba.njit(cache=True)
def _count_leaves(ok, parent):
    n = 0
    for k in range(ok.shape[0]):
        for j in range(ok.shape[1]):
            for i in range(ok.shape[2]):
                if ok[k, j, i] and not _parent_merged(parent, k, j, i):
                    n += 1
    return n


@numba.njit(cache=True)
def _emit_leaves(mean, ok, all_ok, parent, lev, start, lower, level, values):
    """Write the cells of level `lev` that exist and whose parent was not merged."""
    t = start
    w = 1 << lev
    for k in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            for i in range(mean.shape[2]):
                if (all_ok or ok[k, j, i]) and not _parent_merged(parent, k, j, i):
                    lower[t, 0] = i * w
                    lower[t, 1] = j * w
                    lower[t, 2] = k * w
                    level[t] = lev
                    values[t] = mean[k, j, i]
                    t += 1
    return t
