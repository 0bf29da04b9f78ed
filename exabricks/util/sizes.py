"""Sizes in bytes as users write them: `--memory-budget 2G`, `memory_budget="512MiB"`."""

from __future__ import annotations

import math

from .errors import ExabricksError

# Units of a --memory-budget: binary for K, M, G, T and KiB..TiB (as SLURM's --mem,
# Java's -Xmx and numfmt --from=iec read them), decimal for kB, MB, GB, TB.
_UNITS = {"": 1, "b": 1}
for _i, _p in enumerate("kmgt", start=1):
    _UNITS.update({_p: 1024 ** _i, _p + "ib": 1024 ** _i, _p + "b": 1000 ** _i})

def parse_size(text) -> int:
    """Bytes of a size written as an integer, or a number with a unit ("512MiB",
    "8GiB", "2G", "1.5GB"; _UNITS); ExabricksError for anything else."""
    raw = str(text).strip()
    number = raw.rstrip("kKmMgGtTiIbB ")
    unit = raw[len(number):].strip().lower()
    try:
        value = float(number)
    except ValueError:
        value = float("nan")
    if unit not in _UNITS or not math.isfinite(value) or value <= 0:
        raise ExabricksError(f"memory budget {raw!r}: expected a positive size such as "
                             "1073741824, 512MiB, 8GiB or 2G")
    nbytes = int(value * _UNITS[unit])
    if nbytes < 1:
        raise ExabricksError(f"memory budget {raw!r}: less than one byte")
    return nbytes
