"""Write a synthetic AMReX plotfile of a dense core smaller than a pixel.

    .venv/bin/python workflows/make_dense_core.py OUT

The generated data of the first picture (benchmarks/first_picture.py, issue
63): one field `density` = 1 / (1 + (r / CORE_RADIUS)^2) around the off-centre
point CORE, which spans 6 decades from the core to the domain's corners, as a
collapsed halo does; a 32^3 base grid on [0, 1]^3 and 5 levels of refinement
ratio 2 nested around the core (workflows/make_series.py's hierarchy), so that
the finest cells, about the core's size, are a quarter of a pixel of a
512-pixel frame of the whole domain. 196,608 cells, 1.6 MB. OUT is written under
a temporary name and renamed into place; an existing OUT is refused.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

from benchmarks.amrex_plotfile import write_plotfile
from workflows.make_series import hierarchy

CORE = np.array([0.43, 0.56, 0.47])
CORE_RADIUS = 8.7e-4  # world units: (0.87 / CORE_RADIUS)^2 = 1e6 to the farthest corner
SIZE, LEVELS = 32, 5


def density(x, y, z) -> np.ndarray:
    """The field at world points (broadcasting arrays)."""
    r2 = (x - CORE[0]) ** 2 + (y - CORE[1]) ** 2 + (z - CORE[2]) ** 2
    return 1.0 / (1.0 + r2 / CORE_RADIUS ** 2)


def write(out: Path) -> Path:
    """Write the plotfile `out` (module docstring); returns it."""
    out = Path(out)
    if out.exists():
        raise SystemExit(f"error: {out} exists; not replacing it")

    def data(level, glo, ghi):
        dx = 1.0 / (SIZE * 2 ** level)
        x, y, z = ((np.arange(glo[a], ghi[a] + 1) + 0.5) * dx for a in range(3))
        return density(x[None, None, :], y[None, :, None], z[:, None, None])[None]

    tmp = out.with_name(f".{out.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    write_plotfile(tmp, hierarchy(CORE, SIZE, LEVELS), [2] * LEVELS, ["density"], data,
                   base=SIZE, keep=False)
    tmp.rename(out)
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="the plotfile directory to write")
    print(write(p.parse_args(argv).out))


if __name__ == "__main__":
    main()
