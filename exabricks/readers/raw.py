"""A uniform raw volume (headerless binary, x fastest) turned into AMR cells.

The voxels become level-0 cells; aligned 2x2x2 groups whose voxel values lie
within an absolute `threshold` of each other are merged level by level up to
`max_level` (`exabricks.builders.uniform.amr_from_uniform`).  This is how large
multi-level inputs for scale tests are made.  Origin 0, spacing 1 (one voxel).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..util.constants import VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError, quoted
from ..schema import Cells

DTYPES = ("uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64")
BYTE_ORDERS = {"little": "<", "big": ">"}


def read(
    path: str | Path,
    *,
    fields=None,
    dims=None,
    dtype: str = "float32",
    name: str = "value",
    max_level: int | None = None,
    threshold: float = 0.0,
    byte_order: str = "little",
) -> Cells:
    """Cells of the raw volume `path` of `dims` = (X, Y, Z) voxels of `dtype`.

    max_level: coarsest level to merge to (None: as coarse as the dims allow).
    threshold: absolute value range (max - min of the covered voxels) up to which
               a 2x2x2 group merges; 0 merges only exactly constant groups.
    Returns one field, `name`, float32 (1, N).
    """
    path = Path(path)
    if not path.is_file():
        raise ExabricksError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    if dims is None:
        raise ExabricksError(f"{path}: a raw volume needs its size: give --dims X Y Z")
    dims = tuple(int(d) for d in dims)
    if len(dims) != 3 or min(dims) < 1:
        raise ExabricksError(f"{path}: --dims must be three positive sizes, got {list(dims)}")
    if dtype not in DTYPES:
        raise ExabricksError(f"{path}: unknown --dtype {dtype!r} (choose from {', '.join(DTYPES)})")
    if byte_order not in BYTE_ORDERS:
        raise ExabricksError(f"{path}: unknown byte order {byte_order!r} (little or big)")
    missing = [f for f in fields or () if f != name]
    if missing:
        raise ExabricksError(f"{path}: no field {quoted(missing[0])} (fields: {quoted(name)})")
    if fields and len(fields) > 1:
        raise ExabricksError(f"{path}: field {quoted(name)} is given twice")
    dt = np.dtype(dtype).newbyteorder(BYTE_ORDERS[byte_order])
    # Python ints: --dims of 2**22 each must not wrap around to a plausible size.  The
    # file must hold exactly the claimed voxels before any of them is allocated.
    expected = math.prod(dims) * dt.itemsize
    size = path.stat().st_size
    if size != expected:
        x, y, z = dims
        raise ExabricksError(
            f"{path}: size {size} bytes does not match --dims {x} {y} {z} of {dtype} "
            f"({expected} bytes)"
        )
    volume = np.fromfile(path, dtype=dt).reshape(dims[2], dims[1], dims[0])
    if not volume.dtype.isnative or volume.dtype not in (np.float32, np.float64):
        volume = volume.astype(np.float64 if dtype == "float64" else VALUE_DTYPE)
    from ..builders.uniform import amr_from_uniform  # numba, when a raw volume is read

    lower, level, values = amr_from_uniform(volume, max_level=max_level, threshold=threshold)
    return Cells(
        fields=(name,),
        origin_world=np.zeros(3, WORLD_DTYPE),
        spacing_world=np.ones(3, WORLD_DTYPE),
        meta={"inputs": [str(path)]},
        lower_lattice=lower,
        level=level,
        values=values[None, :],
    )
