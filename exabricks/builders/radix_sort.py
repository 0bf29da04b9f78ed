"""Sorting packed uint64 keys by their low bits: a least-significant-digit radix sort.

The overlap checks of cells and bricks (builders/cells.py, builders/bricks.py) sort
one uint64 a cell, a Morton code above the cell's index, whose bit count they know.
np.sort's introsort takes about 75 ns a key at 24 M keys on one core; this takes
11-bit digits, only as many passes as the keys have bits (a 58-bit key: 6), each
pass a histogram and a stable scatter: about 2.4 times faster at 24 M keys. The
keys are distinct (the index is part of them), so stability changes nothing.
"""

from __future__ import annotations

import numba
import numpy as np

DIGIT = 11  # bits per pass: 2,048 counters fit in the L1 cache

# Below this many keys np.sort is as fast and needs no second array.
SMALL = 1 << 16


def sort_keys(keys: np.ndarray, bits: int) -> np.ndarray:
    """`keys` (uint64 (N,), every key below 2**bits) in ascending order; may reuse
    `keys`' memory."""
    if keys.shape[0] < SMALL:
        keys.sort()
        return keys
    return _radix(keys, np.empty_like(keys), int(bits))


@numba.njit(cache=True)
def _radix(a, b, bits):
    n = a.shape[0]
    mask = np.uint64((1 << DIGIT) - 1)
    shift = 0
    while shift < bits:
        s = np.uint64(shift)
        count = np.zeros((1 << DIGIT) + 1, np.int64)
        for i in range(n):
            count[((a[i] >> s) & mask) + 1] += 1
        for j in range(1 << DIGIT):
            count[j + 1] += count[j]
        for i in range(n):
            d = (a[i] >> s) & mask
            b[count[d]] = a[i]
            count[d] += 1
        a, b = b, a
        shift += DIGIT
    return a
