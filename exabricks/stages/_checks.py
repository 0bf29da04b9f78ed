"""Whole-array checks that NumPy would make in several passes with temporaries
(exabricks.schema on every load and save, stages.ingest on every input): one
parallel pass each, at memory speed."""

from __future__ import annotations

import numba
import numpy as np

# Rows per parallel chunk: each chunk reports its first bad row.
_CHUNK = 1 << 16


@numba.njit(cache=True, parallel=True)
def first_misaligned(lower, level):
    """Index of the first row i with a corner lower[i] (int32 (N, 3)) that is not a
    multiple of 2**level[i] (int8 (N,), 0..30), else -1."""
    n = level.shape[0]
    chunks = (n + _CHUNK - 1) // _CHUNK
    first = np.full(chunks, -1, np.int64)
    for c in numba.prange(chunks):
        for i in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            mask = (np.int32(1) << np.int32(level[i])) - np.int32(1)
            if (lower[i, 0] | lower[i, 1] | lower[i, 2]) & mask:
                first[c] = i
                break
    for c in range(chunks):
        if first[c] >= 0:
            return first[c]
    return -1
