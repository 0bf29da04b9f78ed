"""ExaJet cells/scalars files (the base format of the ExaBricks paper, §5).

``NAME.cells``: little-endian int32 ``{x, y, z, level}`` per cell, level 0 the
finest, ``x, y, z`` the lower corner in finest-cell units.  Each scalar field is
a separate little-endian float32 file with one value per cell in the same order;
by convention ``STEM.FIELD.scalars`` next to ``STEM.cells``.  The files carry no
units: origin 0, spacing 1.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numba
import numpy as np

from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError
from ..schema import Cells
from ..util import numba_compiles

numba_compiles.announce()  # its first compile on a machine says so on a terminal

CELL_BYTES = 16  # four int32


def scalar_files(cells_path: Path) -> dict[str, Path]:
    """Sibling scalar files ``STEM.NAME.scalars`` of ``STEM.cells``, keyed by NAME, sorted."""
    cells_path = Path(cells_path)
    stem = cells_path.name[: -len(".cells")] if cells_path.name.endswith(".cells") else cells_path.stem
    found = {}
    for p in cells_path.parent.glob(f"{_escape_glob(stem)}.*.scalars"):
        name = p.name[len(stem) + 1: -len(".scalars")]
        if name and "." not in name:
            found[name] = p
    return dict(sorted(found.items()))


def _escape_glob(s: str) -> str:
    return "".join(f"[{c}]" if c in "*?[]" else c for c in s)


def read(path: str | Path, *, fields=None, scalars: dict[str, Path] | None = None) -> Cells:
    """Cells and scalar fields of an ExaJet ``.cells`` file.

    scalars: field name -> file; None: the siblings found by `scalar_files`.
    fields: names to read (None: all), in that order.
    Returns Cells with lower_lattice int32 (N, 3), level int8 (N,), values float32 (F, N).
    """
    path = Path(path)
    _check_file(path, "cells file")
    size = path.stat().st_size
    if size % CELL_BYTES:
        raise ExabricksError(
            f"{path}: size {size} bytes is not a multiple of {CELL_BYTES} "
            f"(4 int32 x, y, z, level per cell): truncated .cells file"
        )
    n = size // CELL_BYTES

    if scalars is None:
        scalars = scalar_files(path)
        if not scalars:
            raise ExabricksError(
                f"{path}: no scalar files {path.name[:-len('.cells')] if path.name.endswith('.cells') else path.stem}"
                f".NAME.scalars next to it; give them with --scalars NAME=FILE"
            )
    scalars = {name: Path(p) for name, p in scalars.items()}
    if fields:
        missing = [f for f in fields if f not in scalars]
        if missing:
            raise ExabricksError(
                f"{path}: no field {missing[0]!r} (fields: {', '.join(scalars)})"
            )
        scalars = {f: scalars[f] for f in fields}
    # Every file's size against the cell count before anything is allocated or read.
    for name, p in scalars.items():
        _check_file(p, f"scalars file for field {name!r}")
        nbytes = p.stat().st_size
        if nbytes % 4:
            raise ExabricksError(
                f"{p}: size {nbytes} bytes is not a multiple of 4 (float32 per cell): "
                f"truncated .scalars file"
            )
        if nbytes // 4 != n:
            raise ExabricksError(
                f"{p}: {nbytes // 4} values for field {name!r}, but {path} has {n} cells"
            )

    raw = _read_exact(path, np.empty((n, 4), np.int32))
    lower = np.empty((n, 3), LATTICE_DTYPE)
    level = np.empty(n, LEVEL_DTYPE)
    bad = _split(raw, lower, level, MAX_LEVEL)
    if bad >= 0:
        raise ExabricksError(
            f"{path}: cell {bad} at {raw[bad, :3].tolist()} has level {int(raw[bad, 3])}, "
            f"outside 0..{MAX_LEVEL}"
        )
    del raw
    values = np.empty((len(scalars), n), VALUE_DTYPE)
    for row, p in enumerate(scalars.values()):
        _read_exact(p, values[row])

    return Cells(
        fields=tuple(scalars),
        origin_world=np.zeros(3, WORLD_DTYPE),
        spacing_world=np.ones(3, WORLD_DTYPE),
        meta={"inputs": [str(path), *map(str, scalars.values())]},
        lower_lattice=lower,
        level=level,
        values=values,
    )


def _check_file(path: Path, what: str) -> None:
    if not path.exists():
        raise ExabricksError(f"{path}: no such file ({what})")
    if not path.is_file():
        raise ExabricksError(f"{path}: not a file ({what})")


def _read_exact(path: Path, out: np.ndarray) -> np.ndarray:
    """Fill the contiguous array `out` with the little-endian contents of `path`."""
    if out.nbytes == 0:
        return out
    with open(path, "rb") as f:
        got = f.readinto(memoryview(out).cast("B"))
    if got != out.nbytes:
        raise ExabricksError(f"{path}: read {got} of {out.nbytes} bytes (file changed while reading?)")
    if sys.byteorder != "little":
        out.byteswap(inplace=True)
    return out


@numba.njit(cache=True)
def _split(raw, lower, level, max_level):
    """Copy {x,y,z,level} rows into corners and int8 levels; first out-of-range level or -1."""
    for i in range(raw.shape[0]):
        l = raw[i, 3]
        if l < 0 or l > max_level:
            return i
        lower[i, 0] = raw[i, 0]
        lower[i, 1] = raw[i, 1]
        lower[i, 2] = raw[i, 2]
        level[i] = l
    return -1
