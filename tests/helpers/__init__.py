"""What the tests share (tests/conftest.py holds the fixtures): paths of the real
datasets, the OpenCL devices, structures built in memory, the CLI runner and its
checks.  Tests import it as `helpers`; its modules hold the frames, budgets, MPI
runs and hostile runs that several test folders use."""

from __future__ import annotations

import functools
from dataclasses import dataclass
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]

PACKAGE_DATA = ROOT / "exabricks" / "data"


def _data_dir() -> Path:
    for candidate in (os.environ.get("EXABRICKS_TEST_DATA"), ROOT / "tests" / "data",
                      ROOT.parent / "shared" / "data"):
        if candidate and Path(candidate, "amrex-advection3d").is_dir():
            return Path(candidate)
    raise RuntimeError("real test datasets not found (tests/data or ../shared/data)")


DATA = _data_dir()
AMREX = DATA / "amrex-advection3d" / "plt00020"
ATHENA = DATA / "athena-blast3d" / "Blast.out2.00001.athdf"
ENZO = DATA / "enzo-moving7" / "moving7_0010"
GERRIS = PACKAGE_DATA / "gerris-plume" / "plume7-1.cells"

# Leaf-cell counts read with yt 4.4.3 (shared/data/README.md).
def _opencl_devices() -> list[str]:
    """Specs of every OpenCL device here (none without a driver); kernel tests run on each."""
    from exabricks.device import opencl
    from exabricks.util.errors import ExabricksError

    try:
        return [d.spec for d in opencl.list_devices()]
    except ExabricksError:
        return []


DEVICES = _opencl_devices()
device_param = pytest.mark.parametrize("device", DEVICES)


@functools.lru_cache(maxsize=None)
def built_scene(path: Path, field: str):
    """(bricks, regions, bvh, field, camera, transfer function) of one field of a dataset:
    built in memory, default camera on its bounds, default transfer function over its range."""
    from exabricks import schema
    from exabricks.picture.camera import default_camera
    from exabricks.readers import read
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions
    from exabricks.picture.transfer_function import default_transfer_function

    bricks = build_bricks(read(path, fields=[field]))
    regions = build_regions(bricks)
    bvh = build_bvh(regions)
    values = bricks.values[0]
    tf = default_transfer_function((float(values.min()), float(values.max())))
    lo, hi = schema.world_bounds(bricks)
    return bricks, regions, bvh, field, default_camera(np.asarray(lo), np.asarray(hi)), tf


@dataclass(frozen=True)
class Built:
    """A cells set and the structures built from it in memory."""

    cells: object      # exabricks.schema.Cells
    bricks: object     # exabricks.schema.Bricks
    regions: object    # exabricks.schema.Regions
    bvh: object        # exabricks.schema.Bvh

    @property
    def finest_width_world(self) -> float:
        return float(2.0 ** self.cells.level.min() * self.cells.spacing_world.min())


def build(cells) -> Built:
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions

    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    return Built(cells, bricks, regions, build_bvh(regions))


LEAF_COUNTS = {"amrex": 505_856, "athena": 491_520, "gerris": 67_712, "enzo": 27_077}


def run_cli(*args, check=None, env=None):
    """Run `exabricks ARGS` in a subprocess; returns CompletedProcess with text output."""
    proc = subprocess.run(
        [sys.executable, "-m", "exabricks.cli.main", *map(str, args)],
        capture_output=True, text=True, env={**os.environ, **(env or {})},
    )
    if check is not None and proc.returncode != check:
        raise AssertionError(
            f"exit {proc.returncode} (expected {check}) for {args}\n"
            f"stdout: {proc.stdout}\nstderr: {proc.stderr}"
        )
    return proc


def assert_one_error_line(proc, *needles):
    """Exit 1, exactly one `error: ...` line on stderr mentioning every needle, no traceback."""
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    lines = [l for l in proc.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    for n in needles:
        assert str(n) in lines[0], (n, lines[0])


def peak_rss(args, env=None, warm=None) -> int:
    """Peak resident bytes of `exabricks ARGS`, measured once the kernels are in
    PoCL's and numba's caches: after `exabricks WARM` (a cheaper command of the same
    kernels), else after ARGS itself."""
    launcher = ("import os, subprocess, sys, resource; p = subprocess.run(sys.argv[1:]); "
                "print(os.wait4 and resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); "
                "sys.exit(p.returncode)")
    for run in (warm or args, args):
        proc = subprocess.run([sys.executable, "-c", launcher, sys.executable, "-m",
                               "exabricks.cli.main", *map(str, run)],
                              capture_output=True, text=True, env={**os.environ, **(env or {})})
        assert proc.returncode == 0, proc.stderr
    return int(proc.stdout.split()[-1]) * 1024



def two_level_cells():
    """A 2x2x2 block of level-1 cells with one corner refined into 8 level-0 cells."""
    from exabricks import schema

    lower, level = [], []
    for k in range(2):
        for j in range(2):
            for i in range(2):
                if (i, j, k) == (0, 0, 0):
                    for kk in range(2):
                        for jj in range(2):
                            for ii in range(2):
                                lower.append((ii, jj, kk))
                                level.append(0)
                else:
                    lower.append((2 * i, 2 * j, 2 * k))
                    level.append(1)
    n = len(level)
    values = np.stack([np.arange(n, dtype=np.float32), -np.arange(n, dtype=np.float32)])
    return schema.Cells(
        fields=("a", "b"), origin_world=np.array([1.0, 2.0, 3.0]),
        spacing_world=np.array([0.5, 0.5, 0.5]), meta=schema.make_meta(),
        lower_lattice=np.array(lower, np.int32), level=np.array(level, np.int8), values=values,
    )


# Examples per fuzzer (tests marked `fuzz`): a few in `make test`, many in `make fuzz`.
FUZZ_EXAMPLES = int(os.environ.get("EXABRICKS_FUZZ_EXAMPLES", "5"))
