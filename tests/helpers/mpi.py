"""Runs under mpiexec (pip's MPICH) and the structure files they read."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from exabricks.film.image_io import read_image


MPIEXEC = Path(sys.executable).parent / "mpiexec"


EB = [sys.executable, "-m", "exabricks.cli.main"]


def mpirun(n, *args, env=None):
    cmd = [str(MPIEXEC), "-n", str(n), *EB, *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600,
                          env={**os.environ, **(env or {})})


def files_of(tmp_path_factory, source, field):
    from exabricks import schema
    from exabricks.readers import read
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions

    d = tmp_path_factory.mktemp(Path(source).stem)
    bricks = build_bricks(read(source, fields=[field]))
    regions = build_regions(bricks)
    for name, obj in (("bricks", bricks), ("regions", regions), ("bvh", build_bvh(regions))):
        schema.save(d / f"{name}.npz", obj)
    return [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]


def same_image(a_path, b_path, exact=False):
    a, _ = read_image(a_path)
    b, _ = read_image(b_path)
    assert b[..., 3].max() > 1e-3
    if exact:
        np.testing.assert_array_equal(a, b)
    rmse = float(np.sqrt(np.mean((a - b) ** 2)))
    assert rmse <= 1e-5 * float(np.abs(b).max()), rmse


FLAGS = ["--size", 72, 48, "--max-opacity", 1]
