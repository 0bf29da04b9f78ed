"""Leaf cells of block-structured AMR: mask the cells of each box that finer boxes cover.

A level's boxes are given in that level's own cell-index space, `lo` and `hi`
inclusive (AMReX's convention).  The finer levels' boxes, coarsened to the same
index space, are the *cover*: a cell under any cover box is not a leaf.  The
cover boxes are binned on a uniform grid (bin edge ~ the median box extent), so
each box only meets the cover boxes near it instead of all of them; this keeps
a level with 10^5 boxes linear instead of quadratic.
"""

from __future__ import annotations

import numba
import numpy as np

from ..util.constants import LATTICE_DTYPE
from ..util import numba_compiles

numba_compiles.announce()  # its first compile on a machine says so on a terminal


def box_volumes(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Cells per box. lo, hi: int64 (B, 3) inclusive bounds -> int64 (B,)."""
    return np.prod(hi - lo + 1, axis=1, dtype=np.int64)


def coarsen(lo: np.ndarray, hi: np.ndarray, ratio: int) -> tuple[np.ndarray, np.ndarray]:
    """Boxes of a finer level in the index space `ratio` times coarser (floor division)."""
    return lo // ratio, hi // ratio


def leaf_mask(lo: np.ndarray, hi: np.ndarray, cover_lo: np.ndarray,
              cover_hi: np.ndarray) -> np.ndarray:
    """True for every cell of the boxes `lo..hi` that no cover box contains.

    lo, hi:             int64 (B, 3), the level's boxes, inclusive, in its cell indices.
    cover_lo, cover_hi: int64 (C, 3), finer boxes coarsened to the same indices.
    Returns bool (sum of box volumes,): box after box, x fastest, then y, then z
    (the Fortran order of an AMReX FAB).
    """
    lo = np.ascontiguousarray(lo, dtype=np.int64)
    hi = np.ascontiguousarray(hi, dtype=np.int64)
    start = np.zeros(lo.shape[0] + 1, dtype=np.int64)
    np.cumsum(box_volumes(lo, hi), out=start[1:])
    mask = np.ones(int(start[-1]), dtype=np.bool_)
    if cover_lo.shape[0] == 0 or lo.shape[0] == 0:
        return mask
    cover_lo = np.ascontiguousarray(cover_lo, dtype=np.int64)
    cover_hi = np.ascontiguousarray(cover_hi, dtype=np.int64)
    # Bin edge: the larger median extent of the two box sets, so a typical box of either
    # set touches at most 8 bins (a large one is entered into every bin it spans, bounded
    # by its volume); tiny cover boxes (deep levels coarsened) then share bins instead of
    # making a coarse box visit thousands of them.
    bin_size = max(int(np.median((cover_hi - cover_lo + 1).max(axis=1))),
                   int(np.median((hi - lo + 1).max(axis=1))), 1)
    origin = np.minimum(lo.min(axis=0), cover_lo.min(axis=0))
    top = np.maximum(hi.max(axis=0), cover_hi.max(axis=0))
    n_bins = (top - origin) // bin_size + 1
    keys, boxes = _bin_boxes(cover_lo, cover_hi, origin, n_bins, bin_size)
    _paint(lo, hi, start, cover_lo, cover_hi, keys, boxes, origin, n_bins, bin_size, mask)
    return mask


@numba.njit(cache=True)
def _bin_boxes(cover_lo, cover_hi, origin, n_bins, bin_size):
    """(bin key, cover index) pairs sorted by key; a box enters every bin it overlaps."""
    total = 0
    for c in range(cover_lo.shape[0]):
        n = 1
        for a in range(3):
            n *= (cover_hi[c, a] - origin[a]) // bin_size - (cover_lo[c, a] - origin[a]) // bin_size + 1
        total += n
    keys = np.empty(total, dtype=np.int64)
    boxes = np.empty(total, dtype=np.int64)
    m = 0
    for c in range(cover_lo.shape[0]):
        b0 = (cover_lo[c] - origin) // bin_size
        b1 = (cover_hi[c] - origin) // bin_size
        for bz in range(b0[2], b1[2] + 1):
            for by in range(b0[1], b1[1] + 1):
                for bx in range(b0[0], b1[0] + 1):
                    keys[m] = bx + n_bins[0] * (by + n_bins[1] * bz)
                    boxes[m] = c
                    m += 1
    order = np.argsort(keys, kind="mergesort")
    return keys[order], boxes[order]


@numba.njit(cache=True)
def _paint(lo, hi, start, cover_lo, cover_hi, keys, boxes, origin, n_bins, bin_size, mask):
    """Clear `mask` under every cover box that meets a box (explicit loops, no recursion)."""
    seen = np.full(cover_lo.shape[0], -1, dtype=np.int64)
    for b in range(lo.shape[0]):
        nx = hi[b, 0] - lo[b, 0] + 1
        ny = hi[b, 1] - lo[b, 1] + 1
        b0 = (lo[b] - origin) // bin_size
        b1 = (hi[b] - origin) // bin_size
        for bz in range(b0[2], b1[2] + 1):
            for by in range(b0[1], b1[1] + 1):
                for bx in range(b0[0], b1[0] + 1):
                    key = bx + n_bins[0] * (by + n_bins[1] * bz)
                    i = np.searchsorted(keys, key)
                    while i < keys.shape[0] and keys[i] == key:
                        c = boxes[i]
                        i += 1
                        if seen[c] == b:
                            continue
                        seen[c] = b
                        x0 = max(lo[b, 0], cover_lo[c, 0])
                        x1 = min(hi[b, 0], cover_hi[c, 0])
                        y0 = max(lo[b, 1], cover_lo[c, 1])
                        y1 = min(hi[b, 1], cover_hi[c, 1])
                        z0 = max(lo[b, 2], cover_lo[c, 2])
                        z1 = min(hi[b, 2], cover_hi[c, 2])
                        for z in range(z0, z1 + 1):
                            for y in range(y0, y1 + 1):
                                row = start[b] + (y - lo[b, 1]) * nx + (z - lo[b, 2]) * nx * ny
                                for x in range(x0, x1 + 1):
                                    mask[row + x - lo[b, 0]] = False


def leaf_lattice(lo: np.ndarray, hi: np.ndarray, mask: np.ndarray, domain_lo: np.ndarray,
                 width: int, out: np.ndarray | None = None) -> np.ndarray:
    """Lower lattice corners of the masked cells of the boxes.

    lo, hi:    int64 (B, 3), inclusive cell-index boxes of one level.
    mask:      bool (sum of box volumes,), from `leaf_mask` (same cell order).
    domain_lo: int64 (3,), the level's domain corner (lattice 0).
    width:     lattice units per cell of this level.
    out:       where to write them (int32 C-contiguous (count of True, 3)), or None.
    Returns int32 (count of True, 3): `out` or a new array.
    """
    if out is None:
        out = np.empty((int(np.count_nonzero(mask)), 3), dtype=LATTICE_DTYPE)
    _lattice(np.ascontiguousarray(lo, dtype=np.int64), np.ascontiguousarray(hi, dtype=np.int64),
             mask, np.asarray(domain_lo, dtype=np.int64), np.int64(width), out)
    return out


@numba.njit(cache=True)
def _lattice(lo, hi, mask, domain_lo, width, out):
    """Write the lattice corner of every masked cell into `out`, in mask order."""
    m = 0
    n = 0
    for b in range(lo.shape[0]):
        for z in range(lo[b, 2], hi[b, 2] + 1):
            for y in range(lo[b, 1], hi[b, 1] + 1):
                for x in range(lo[b, 0], hi[b, 0] + 1):
                    if mask[n]:
                        out[m, 0] = (x - domain_lo[0]) * width
                        out[m, 1] = (y - domain_lo[1]) * width
                        out[m, 2] = (z - domain_lo[2]) * width
                        m += 1
                    n += 1
