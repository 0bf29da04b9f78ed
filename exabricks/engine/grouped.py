"""Arrays of one element size grouped into one kernel buffer (kernels/dataset.cl,
the frame's look in render.cl): each part starts at an offset the kernel finds
in eb_params (exabricks.device.kernel_abi.PARAMS, the "*_at" members)."""

from __future__ import annotations

import numpy as np


class Grouped:
    """Parts appended one after the other as `dtype` elements; `add` returns where
    a part starts, counted in elements, a multiple of `align` (so that a part
    read as float4, int2 or int4 is aligned)."""

    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)
        self.parts: list[np.ndarray] = []
        self.size = 0

    def add(self, array, align: int = 1) -> int:
        """Append `array` (any shape; its numbers converted to dtype: a part read
        as another type is passed as a view, `ints.view(np.float32)`) and return
        its offset."""
        part = np.ascontiguousarray(array, self.dtype)
        at = -(-self.size // align) * align
        if at > self.size:
            self.parts.append(np.zeros(at - self.size, self.dtype))
        self.parts.append(part.reshape(-1))
        self.size = at + part.size
        return at

    def array(self) -> np.ndarray:
        """The parts, concatenated (one zero element when there is none)."""
        return np.concatenate(self.parts) if self.parts else np.zeros(1, self.dtype)
