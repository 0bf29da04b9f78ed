"""Checks that every reader applies to what a file claims, before trusting it.

- `check_frame`: the world frame (origin, spacing) a reader derives from a header must
  be usable: finite origin, spacing finite, positive and normal (>= the smallest
  normal float64), and the lattice extent times the spacing finite, so that every
  later `origin + spacing * lattice` is a finite number.
- `claim`: a size claimed by a header (a box, a dataset, a count) compared with what
  the file really holds, *before* anything of that size is allocated or read, so a
  24 KB file that claims a 1024^3 box fails at once instead of after gigabytes.
"""

from __future__ import annotations

import numpy as np

from ..util.errors import ExabricksError

TINY = float(np.finfo(np.float64).tiny)


def check_frame(where, origin, spacing, extent) -> None:
    """Raise ExabricksError naming `where` unless the world frame is usable.

    origin, spacing: (3,) floats (world units); extent: (3,) lattice units covered.
    """
    with np.errstate(all="ignore"):
        origin = np.asarray(origin, dtype=np.float64)
        spacing = np.asarray(spacing, dtype=np.float64)
        extent = np.asarray(extent, dtype=np.float64)
        if not np.all(np.isfinite(origin)):
            raise ExabricksError(f"{where}: the domain origin {origin.tolist()} is not finite")
        bad = ~(np.isfinite(spacing) & (spacing >= TINY))
        if np.any(bad):
            a = int(np.flatnonzero(bad)[0])
            raise ExabricksError(
                f"{where}: cell size {spacing[a]!r} along axis {'xyz'[a]} is not a finite, "
                f"positive, normal number (the domain extent is degenerate or too large)"
            )
        top = origin + spacing * extent
        if not np.all(np.isfinite(spacing * extent)) or not np.all(np.isfinite(top)):
            raise ExabricksError(
                f"{where}: the domain {origin.tolist()} + {spacing.tolist()} x {extent.tolist()} "
                f"cells overflows float64"
            )


def check_cell_size(where, values, what: str = "cell size") -> None:
    """Raise unless every value in `values` is finite, positive and normal."""
    with np.errstate(all="ignore"):
        values = np.asarray(values, dtype=np.float64).ravel()
        bad = np.flatnonzero(~(np.isfinite(values) & (values >= TINY)))
    if bad.size:
        raise ExabricksError(
            f"{where}: {what} {float(values[bad[0]])!r} is not a finite, positive, normal number"
        )


def claim(where, what: str, claimed: int, file, size: int, at: int = 0) -> None:
    """Raise unless `claimed` bytes starting at byte `at` fit in `file` of `size` bytes.

    claimed, at, size: Python ints (no overflow); the message names both files.
    """
    if at < 0 or at + claimed > size:
        where_at = f" from byte {at}" if at else ""
        raise ExabricksError(
            f"{where}: {what} claims {claimed} bytes{where_at} but {file} holds only {size}"
        )
