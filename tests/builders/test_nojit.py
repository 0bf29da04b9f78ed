"""The numba builders run as plain Python (NUMBA_DISABLE_JIT=1) give exactly what the
compiled ones give: ingest (validate_cells, cell_statistics, find_overlap,
amr_from_uniform, order_cells), brick (whole, and a piece of ordered cells),
regions, BVH and the brick-support tree, on tiny inputs.

The uncompiled run happens in a subprocess (numba reads the variable when it is
imported) that calls `stage_outputs` from this module; the compiled run calls it here.
Its outputs also pass the same independent checks as the compiled ones in
test_brick.py and test_regions_bvh.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from exabricks import schema
from exabricks.formats.pieces import Piece
from exabricks.builders.bricks import build_bricks
from exabricks.builders.piece_order import RUNS_KEY, order_cells
from exabricks.builders.bvh import build_bvh
from exabricks.engine.cell_location import build_brick_tree
from exabricks.builders.uniform import amr_from_uniform
from exabricks.builders.cells import cell_statistics, find_overlap, validate_cells
from exabricks.builders.regions import build_regions

from amr_strategies import make_cells, refine_octree

HERE = Path(__file__).resolve().parent


def tiny_inputs() -> tuple[schema.Cells, np.ndarray]:
    """A random three-level octree with holes (a few hundred cells, shuffled) and a
    smooth 16^3 volume with a sharp blob for amr_from_uniform, both from fixed seeds."""
    rng = np.random.default_rng(11)
    lower, level = refine_octree(
        rng, root_level=3, root_grid=(3, 3, 2), root_fill=0.8, refine=0.5, hole=0.1,
        clustered=False, base_depth=0, max_cells=1500, offset=(0, 0, 0),
    )
    cells = make_cells(lower, level, rng)
    z, y, x = np.meshgrid(*(np.linspace(0.0, 1.0, 16),) * 3, indexing="ij")
    volume = (0.3 * x + 0.2 * y * z
              + np.exp(-((x - 0.7) ** 2 + (y - 0.3) ** 2 + (z - 0.6) ** 2) / 0.01)).astype(np.float32)
    return cells, volume


def stage_outputs(cells: schema.Cells, volume: np.ndarray) -> dict[str, np.ndarray]:
    """Every builder's output on the tiny inputs, as named arrays (dicts as JSON strings)."""
    out = {}

    def put(prefix, obj):
        for name, array in obj.arrays().items():
            out[f"{prefix}.{name}"] = array
        if "statistics" in obj.meta:
            out[f"{prefix}.statistics"] = np.array(json.dumps(obj.meta["statistics"], sort_keys=True))

    put("validated", validate_cells(cells, source="tiny"))
    out["cell_statistics"] = np.array(json.dumps(cell_statistics(cells), sort_keys=True))
    # The last cell repeats one in the middle: the pair names both.
    doubled = np.vstack([cells.lower_lattice, cells.lower_lattice[len(cells.level) // 2]])
    out["overlap"] = np.array(find_overlap(doubled, np.append(cells.level, cells.level[len(cells.level) // 2])))
    for name, array in zip(("lower", "level", "values"),
                           amr_from_uniform(volume, max_level=3, threshold=0.02)):
        out[f"merged.{name}"] = array
    bricks = build_bricks(cells, max_brick_width=4)
    put("bricks", bricks)
    ordered = order_cells(cells.replace(lower_lattice=cells.lower_lattice.copy(),
                                        level=cells.level.copy()), run_cells=32)
    put("ordered", ordered)
    out["ordered.runs"] = np.array(ordered.meta[RUNS_KEY]["starts"])
    put("piece", build_bricks(ordered, max_brick_width=4, piece=Piece(1, 3)))
    regions = build_regions(bricks)
    put("regions", regions)
    put("bvh", build_bvh(regions, leaf_size=2))
    tree = build_brick_tree(bricks)
    for name in ("lower", "upper", "first", "count", "brick_index"):
        out[f"tree.{name}"] = getattr(tree, name)
    out["tree.depth"] = np.array(tree.depth)
    return out


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """(outputs of the plain-Python run, outputs of the compiled run, the inputs)."""
    tmp = tmp_path_factory.mktemp("nojit")
    cells, volume = tiny_inputs()
    schema.save(tmp / "cells.npz", cells)
    np.save(tmp / "volume.npy", volume)
    script = (
        "import sys, numpy as np;"
        "import numba.core.config as c; assert c.DISABLE_JIT;"
        "from exabricks import schema; from test_nojit import stage_outputs;"
        "np.savez(sys.argv[3], **stage_outputs(schema.load(sys.argv[1], 'cells'), np.load(sys.argv[2])))"
    )
    # This module and tests/amr_strategies.py are found through PYTHONPATH, as pytest finds them.
    path = os.pathsep.join(filter(None, (str(HERE), str(HERE.parent), os.environ.get("PYTHONPATH"))))
    subprocess.run([sys.executable, "-c", script, str(tmp / "cells.npz"),
                    str(tmp / "volume.npy"), str(tmp / "python.npz")],
                   check=True, env={**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": path})
    with np.load(tmp / "python.npz") as z:
        python = {name: z[name] for name in z.files}
    return python, stage_outputs(cells, volume), (cells, volume)


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["validated", "cell_statistics", "overlap", "merged", "bricks",
                                   "ordered", "piece", "regions", "bvh", "tree"])
def test_plain_python_equals_compiled(both, stage):
    python, compiled, _ = both
    names = sorted(k for k in compiled if k == stage or k.startswith(stage + "."))
    assert names and names == sorted(k for k in python if k == stage or k.startswith(stage + "."))
    for name in names:
        assert python[name].dtype == compiled[name].dtype, name
        np.testing.assert_array_equal(python[name], compiled[name], err_msg=name)


@pytest.mark.slow
def test_plain_python_outputs_pass_the_independent_checks(both):
    """The uncompiled builders' bricks, regions and BVH pass brute-force checks
    of test_brick and test_regions_bvh (helpers.checks); the overlap found is the repeated cell."""
    from helpers.checks import (check_bricks, check_bvh, check_coverage_raster, check_regions_brute_force,
                                check_support_tiling, query_points)

    python, _, (cells, _) = both

    def load(kind, cls):
        arrays = {name: python[f"{kind}.{name}"] for name in cls.SPECS}
        return cls(fields=cells.fields,
                   meta={"statistics": json.loads(str(python[f"{kind}.statistics"]))}, **arrays)

    bricks, regions, bvh = (load("bricks", schema.Bricks), load("regions", schema.Regions),
                            load("bvh", schema.Bvh))
    check_bricks(cells, bricks, 4)
    check_coverage_raster(bricks, regions, exact=False)  # merged regions (the default)
    check_support_tiling(bricks, regions)
    check_regions_brute_force(bricks, regions, exact=False)
    check_bvh(regions, bvh, query_points(regions, np.random.default_rng(0)))
    middle = len(cells.level) // 2
    assert python["overlap"].tolist() == [middle, len(cells.level)]
