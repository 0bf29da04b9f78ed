"""Unit vectors of directions given at any magnitude: a light direction, a clip
plane's or a slice's normal, a rotation axis of 1e-300 or 1e300 mean the same
direction as of 1 (squaring the components would underflow to 0 or overflow to
inf in float64, and float32 the kernels read would flush them)."""

from __future__ import annotations

import numpy as np

from .errors import ExabricksError


def unit(v) -> np.ndarray:
    """`v` (finite, not zero) divided by its length, float64: scaled by its largest
    component first, so that no square underflows or overflows."""
    v = np.asarray(v, np.float64)
    largest = float(np.max(np.abs(v))) if v.size else 0.0
    if not (np.isfinite(largest) and largest > 0.0):
        raise ExabricksError(f"{v.tolist()}: a direction must be finite and not zero")
    v = v / largest
    return v / np.sqrt(np.dot(v, v))
