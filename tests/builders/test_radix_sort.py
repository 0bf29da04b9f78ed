"""The overlap checks' key sort (exabricks.builders.radix_sort) against np.sort."""

from __future__ import annotations

import numpy as np
import pytest

from exabricks.builders.radix_sort import SMALL, sort_keys


@pytest.mark.parametrize("n, bits", [(10, 5), (SMALL - 1, 30), (SMALL, 1), (SMALL + 7, 11), (200_003, 22),
                                     (200_003, 58), (100_000, 64)])
def test_sorts_like_numpy(n, bits):
    rng = np.random.default_rng(n + bits)
    keys = rng.integers(0, 2**bits, n, dtype=np.uint64, endpoint=False) if bits < 64 \
        else rng.integers(0, 2**63, n, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
    want = np.sort(keys)
    np.testing.assert_array_equal(sort_keys(keys.copy(), bits), want)


def test_keys_already_sorted_and_reversed_stay_right():
    keys = np.arange(SMALL * 3, dtype=np.uint64) << np.uint64(20)
    np.testing.assert_array_equal(sort_keys(keys[::-1].copy(), 38), keys)
    np.testing.assert_array_equal(sort_keys(keys.copy(), 38), keys)
