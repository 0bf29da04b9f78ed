"""What a frame draws into on the host: the window of a tile in the frame, and
its float32 images, refused with one line where they cannot fit in memory."""

from __future__ import annotations

import numpy as np

from .. import schema
from ..util.errors import ExabricksError


def frame_window(window, width: int, height: int) -> tuple[int, int, int, int]:
    """(first column, first row, columns, rows) of a tile of a width x height frame
    (default: the whole frame)."""
    if window is None:
        return 0, 0, width, height
    col0, row0, cols, rows = (int(v) for v in window)
    if not (0 <= col0 and 0 <= row0 and cols >= 1 and rows >= 1 and col0 + cols <= width
            and row0 + rows <= height):
        raise ExabricksError(f"tile {cols}x{rows} at ({col0}, {row0}) is not inside the "
                             f"{width}x{height} frame")
    return col0, row0, cols, rows


def host_image(width: int, height: int, channels: int, what: str) -> np.ndarray:
    """A float32 (height, width, channels) array, or one clear error if it cannot fit."""
    nbytes = width * height * channels * 4
    limit = schema.memory_limit()
    if limit is not None and nbytes > limit:
        raise ExabricksError(f"{what} of {width}x{height} needs {nbytes / 2**30:.1f} GiB, more "
                             f"than the {limit / 2**30:.1f} GiB of memory available")
    return np.empty((height, width, channels), np.float32)
