"""`exabricks brick` (paper §3.1): exact small cases, random layouts, real data, the CLI.

Every result is checked against a brute-force NumPy expansion of the bricks
back into cells (`check_bricks`), independent of the numba build.
"""

from __future__ import annotations

import importlib
import json
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from exabricks import schema
from exabricks.util.errors import ExabricksError
from exabricks.builders.bricks import build_bricks, merge_bricks

from amr_strategies import amr_cells, make_cells, refine_octree
from helpers import (AMREX, ATHENA, ENZO, GERRIS, LEAF_COUNTS, assert_one_error_line, peak_rss,
                     run_cli)
from helpers.checks import assert_disjoint, check_bricks

HYPOTHESIS_EXAMPLES = int(os.environ.get("EXABRICKS_HYPOTHESIS_EXAMPLES", "200"))


# ---------------------------------------------------------------------------
# independent reference checks


def make(cells_lower, cells_level, values=None) -> schema.Cells:
    """Cells from lists; one field "v" = 0, 1, 2, ... unless given."""
    lower = np.array(cells_lower, np.int32).reshape(-1, 3)
    level = np.array(cells_level, np.int8)
    if values is None:
        values = np.arange(len(level), dtype=np.float32)[None]
    return schema.Cells(
        fields=tuple(f"f{i}" for i in range(len(values))), origin_world=np.zeros(3),
        spacing_world=np.ones(3), lower_lattice=lower, level=level,
        values=np.asarray(values, np.float32),
    )


def brick_set(bricks: schema.Bricks) -> set:
    """{(lower, level, dims, values of field 0 in storage order)} for exact comparisons."""
    out = set()
    for b in range(bricks.n_bricks):
        n = int(bricks.dims[b].prod())
        v = bricks.values[0, bricks.offset[b]: bricks.offset[b] + n]
        out.add((tuple(bricks.lower_lattice[b].tolist()), int(bricks.level[b]),
                 tuple(bricks.dims[b].tolist()), tuple(v.tolist())))
    return out


# ---------------------------------------------------------------------------
# (1) tiny hand-built inputs with exact answers


def two_level_cells() -> schema.Cells:
    """A 2x2x2 block of level-1 cells whose (0,0,0) corner is refined into 8 level-0 cells.

    Values: the 8 fine cells 0..7 (x fastest), then the coarse cells 8..14 in
    x-fastest order: 8 (2,0,0), 9 (0,2,0), 10 (2,2,0), 11 (0,0,2), 12 (2,0,2),
    13 (0,2,2), 14 (2,2,2).
    """
    lower = [(i, j, k) for k in range(2) for j in range(2) for i in range(2)]
    lower += [(2 * i, 2 * j, 2 * k) for k in range(2) for j in range(2) for i in range(2)][1:]
    return make(lower, [0] * 8 + [1] * 7)


def test_two_levels_exact():
    # Root box [0,4)^3, coarsest width 2: split x at 2 -> the x>=2 half is a full
    # 1x2x2 level-1 brick.  The x<2 half splits y at 2 (longest axes y, z tie:
    # y first) -> (0,2,0) and (0,2,2) make a 1x1x2 brick; the y<2 part splits z
    # at 2 -> the 2x2x2 fine block and the lone (0,0,2) cell.
    bricks = build_bricks(two_level_cells())
    assert brick_set(bricks) == {
        ((0, 0, 0), 0, (2, 2, 2), (0, 1, 2, 3, 4, 5, 6, 7)),
        ((0, 0, 2), 1, (1, 1, 1), (11,)),
        ((0, 2, 0), 1, (1, 1, 2), (9, 13)),
        ((2, 0, 0), 1, (1, 2, 2), (8, 10, 12, 14)),
    }
    s = bricks.meta["statistics"]
    assert s["bricks_per_level"] == {"0": 1, "1": 3}
    assert s["cells_per_brick_histogram"] == [[1, 1], [2, 1], [4, 1], [8, 1]]
    assert s["mean_cells_per_brick"] == 15 / 4
    check_bricks(two_level_cells(), bricks, 32)


def test_width_limit_and_rounded_split():
    # Five level-1 cells in a row, box [0,10): middle 5 rounds to 6 (a multiple
    # of the width 2); [0,6) is 3 cells wide > 2, so it splits at 4.
    cells = make([(0, 0, 0), (2, 0, 0), (4, 0, 0), (6, 0, 0), (8, 0, 0)], [1] * 5)
    assert brick_set(build_bricks(cells, max_brick_width=2)) == {
        ((0, 0, 0), 1, (2, 1, 1), (0, 1)),
        ((4, 0, 0), 1, (1, 1, 1), (2,)),
        ((6, 0, 0), 1, (2, 1, 1), (3, 4)),
    }
    assert brick_set(build_bricks(cells)) == {((0, 0, 0), 1, (5, 1, 1), (0, 1, 2, 3, 4))}
    single = brick_set(build_bricks(cells, max_brick_width=1))
    assert single == {((2 * i, 0, 0), 1, (1, 1, 1), (i,)) for i in range(5)}


def test_hole_is_not_bricked_over():
    # Level-0 cells at x = 0, 1, 3: the box [0,4) is not full; split at 2.
    cells = make([(3, 0, 0), (0, 0, 0), (1, 0, 0)], [0, 0, 0])
    assert brick_set(build_bricks(cells)) == {
        ((0, 0, 0), 0, (2, 1, 1), (1, 2)),
        ((3, 0, 0), 0, (1, 1, 1), (0,)),
    }


def test_level_jump_of_two():
    # A 4^3 block of level-0 cells next to one level-2 cell (width 4).
    fine = [(i, j, k) for k in range(4) for j in range(4) for i in range(4)]
    order = np.random.default_rng(1).permutation(65)
    lower = np.array([(4, 0, 0)] + fine)[order]
    level = np.array([2] + [0] * 64)[order]
    bricks = build_bricks(make(lower, level, values=[order.astype(np.float32)]))
    assert brick_set(bricks) == {
        ((0, 0, 0), 0, (4, 4, 4), tuple(float(v) for v in range(1, 65))),
        ((4, 0, 0), 2, (1, 1, 1), (0.0,)),
    }


def test_merge_joins_bricks_that_fill_a_box():
    """merge_bricks: face-to-face runs of one level and cross-section, x then y then z,
    within the width limit; values moved along (x fastest)."""
    def merge(rows, width=32, source=None):
        lower = np.array([r[0] for r in rows], np.int32)
        level = np.array([r[1] for r in rows], np.int8)
        dims = np.array([r[2] for r in rows], np.int32)
        n = dims.prod(axis=1)
        offset = np.concatenate([[0], np.cumsum(n)[:-1]]).astype(np.int64)
        values = np.arange(n.sum(), dtype=np.float32)[None] * 10
        lo, lv, d, off, v = merge_bricks(lower, level, dims, offset, values, width, source)
        return {(tuple(lo[b].tolist()), int(lv[b]), tuple(d[b].tolist()),
                 tuple(v[0, off[b]:off[b] + d[b].prod()].tolist())) for b in range(len(lv))}

    # Two x-neighbours, then their run and a y-neighbour of the same cross-section.
    assert merge([((0, 0, 0), 0, (1, 1, 1)), ((1, 0, 0), 0, (1, 1, 1)),
                  ((0, 1, 0), 0, (2, 1, 1))]) == {((0, 0, 0), 0, (2, 2, 1), (0, 10, 20, 30))}
    # Other level, other cross-section, a gap: nothing joins.
    apart = [((0, 0, 0), 0, (2, 2, 2)), ((2, 0, 0), 1, (1, 1, 1)), ((0, 2, 0), 0, (1, 1, 1)),
             ((0, 0, 3), 0, (2, 2, 1))]
    assert len(merge(apart)) == 4
    # A run of three one-cell bricks within width 2: the first two join.
    assert merge([((4, 0, 0), 1, (1, 1, 1)), ((0, 0, 0), 1, (1, 1, 1)),
                  ((2, 0, 0), 1, (1, 1, 1))], width=2) == {
        ((0, 0, 0), 1, (2, 1, 1), (10, 20)), ((4, 0, 0), 1, (1, 1, 1), (0,))}
    # Values through a source index (what build_bricks passes).
    swapped = [((1, 0, 0), 0, (1, 1, 1)), ((0, 0, 0), 0, (1, 1, 1))]
    assert merge(swapped) == {((0, 0, 0), 0, (2, 1, 1), (10, 0))}
    assert merge(swapped, source=np.array([1, 0], np.int32)) == {
        ((0, 0, 0), 0, (2, 1, 1), (0, 10))}


def test_merge_on_an_octree_layout():
    """Every generated octree layout: the joined bricks still hold exactly the cells,
    and on the Gerris plume far fewer bricks than the k-d leaves."""
    rng = np.random.default_rng(5)
    lower, level = refine_octree(
        rng, root_level=4, root_grid=(4, 3, 3), root_fill=0.9, refine=0.5, hole=0.05,
        clustered=True, base_depth=0, max_cells=20_000, offset=(0, 0, 0))
    cells = make_cells(lower, level, rng)
    for width in (1, 2, 8, 32):
        check_bricks(cells, build_bricks(cells, max_brick_width=width), width)
    assert build_bricks(gerris_cells()).n_bricks < 1200  # 2,852 k-d leaves


def test_single_cell_and_negative_lattice():
    bricks = build_bricks(make([(-8, 16, -24)], [3], values=[[2.5], [-1.0]]))
    assert brick_set(bricks) == {((-8, 16, -24), 3, (1, 1, 1), (2.5,))}
    assert bricks.values[:, 0].tolist() == [2.5, -1.0] and bricks.offset.tolist() == [0]


def test_bad_input_raises():
    with pytest.raises(ExabricksError, match="no cells"):
        build_bricks(make(np.zeros((0, 3)), []))
    with pytest.raises(ExabricksError, match="at least 1"):
        build_bricks(two_level_cells(), max_brick_width=0)
    # A fine cell inside a coarse one: no plane can separate them.
    with pytest.raises(ExabricksError, match="overlap"):
        build_bricks(make([(0, 0, 0), (2, 2, 2), (8, 0, 0)], [2, 0, 0]))
    with pytest.raises(ExabricksError, match="overlap"):
        build_bricks(make([(0, 0, 0), (1, 0, 0), (0, 0, 0)], [0, 0, 0]))


@pytest.mark.parametrize("far", [40, 1 << 29])
def test_require_disjoint_names_the_overlapping_bricks(far):
    """Both ways of the check (one Morton-and-brick key a cell; per-cell corners
    when the lattice is too wide for one key, `far`) name the same two bricks."""
    from exabricks.builders.bricks import require_disjoint

    def bricks(lower, level, dims):
        dims = np.array(dims, np.int32)
        n = dims.prod(axis=1)
        return schema.Bricks(
            fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
            lower_lattice=np.array(lower, np.int32), level=np.array(level, np.int8), dims=dims,
            offset=np.concatenate([[0], np.cumsum(n)[:-1]]).astype(np.int64),
            values=np.zeros((1, int(n.sum())), np.float32))

    # brick 2 (level 1 at x = 8..12) covers a cell of brick 0 (level 0, x = 0..11)
    lower = [(0, 0, 0), (16, 0, 0), (8, 0, 0), (far, far, far)]
    level, dims = [0, 0, 1, 0], [(12, 1, 1), (2, 2, 2), (2, 1, 1), (1, 1, 1)]
    with pytest.raises(ExabricksError, match=r"brick 2 at \[8, 0, 0\] and brick 0 at \[0, 0, 0\]"):
        require_disjoint(bricks(lower, level, dims))
    lower[2] = (24, 0, 0)
    require_disjoint(bricks(lower, level, dims))


# ---------------------------------------------------------------------------
# (2) properties on random valid AMR layouts


def test_generator_makes_valid_varied_layouts():
    """The strategy's layouts are valid (aligned, disjoint) and cover the cases we want."""
    rng = np.random.default_rng(7)
    lower, level = refine_octree(
        rng, root_level=4, root_grid=(3, 2, 2), root_fill=1.0, refine=0.5, hole=0.1,
        clustered=False, base_depth=0, max_cells=3000, offset=(-1, 0, 2),
    )
    cells = make_cells(lower, level, rng)
    schema.validate(cells)
    width = (np.int64(1) << cells.level.astype(np.int64))[:, None]
    assert_disjoint(cells.lower_lattice.astype(np.int64), cells.lower_lattice + width)
    assert len(np.unique(cells.level)) >= 4 and 1000 < cells.n_cells <= 3000 + 12
    assert cells.lower_lattice.min() < 0


@pytest.mark.slow
@settings(max_examples=HYPOTHESIS_EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cells=amr_cells(), max_brick_width=st.sampled_from([1, 2, 3, 4, 8, 32]))
def test_random_layouts(cells, max_brick_width):
    bricks = build_bricks(cells, max_brick_width=max_brick_width)
    check_bricks(cells, bricks, max_brick_width)


def test_parallel_build_matches_serial(monkeypatch):
    """Above the parallel threshold the build runs in subtrees; same bricks as serial."""
    rng = np.random.default_rng(3)
    lower, level = refine_octree(
        rng, root_level=5, root_grid=(6, 5, 4), root_fill=0.9, refine=0.6, hole=0.05,
        clustered=True, base_depth=0, max_cells=60_000, offset=(0, 0, 0),
    )
    cells = make_cells(lower, level, rng)
    brick = importlib.import_module("exabricks.builders.bricks")
    monkeypatch.setattr(brick, "_PARALLEL_MIN_CELLS", 1)
    monkeypatch.setattr(brick.numba, "get_num_threads", lambda: 2)
    parallel = build_bricks(cells, max_brick_width=8)
    monkeypatch.setattr(brick, "_PARALLEL_MIN_CELLS", 1 << 40)
    serial = build_bricks(cells, max_brick_width=8)
    check_bricks(cells, parallel, 8)
    for name in schema.Bricks.SPECS:
        np.testing.assert_array_equal(getattr(parallel, name), getattr(serial, name))


# ---------------------------------------------------------------------------
# (3) real datasets


def gerris_cells() -> schema.Cells:
    """The Gerris plume read directly from its ExaJet files (independent of the readers)."""
    raw = np.fromfile(GERRIS, dtype="<i4").reshape(-1, 4)
    fields = ("T", "U", "V", "W", "P")
    values = np.stack([np.fromfile(GERRIS.with_name(f"plume7-1.{f}.scalars"), dtype="<f4")
                       for f in fields])
    return schema.Cells(
        fields=fields, origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.ascontiguousarray(raw[:, :3]), level=raw[:, 3].astype(np.int8),
        values=values,
    )


def test_gerris_plume():
    cells = gerris_cells()
    assert cells.n_cells == LEAF_COUNTS["gerris"]
    bricks = build_bricks(cells)
    check_bricks(cells, bricks, 32)
    assert set(bricks.meta["statistics"]["bricks_per_level"]) == {"0", "1", "2", "3", "4"}
    narrow = build_bricks(cells, max_brick_width=4)
    check_bricks(cells, narrow, 4)
    assert narrow.n_bricks > bricks.n_bricks


@pytest.mark.slow
@pytest.mark.parametrize("name, path", [("gerris", GERRIS), ("amrex", AMREX),
                                        ("athena", ATHENA), ("enzo", ENZO)])
def test_real_datasets_through_readers(name, path):
    if name == "enzo":
        pytest.importorskip("yt")
    from exabricks.readers import read

    cells = read(path)
    assert cells.n_cells == LEAF_COUNTS[name]
    check_bricks(cells, build_bricks(cells), 32)
    if name == "gerris":  # the reader and the direct read give the same bricks
        direct = build_bricks(gerris_cells())
        assert brick_set(direct) == brick_set(build_bricks(cells.replace(
            values=cells.values[[cells.fields.index(f) for f in direct.fields]],
            fields=direct.fields)))


# ---------------------------------------------------------------------------
# (4) the command


def test_cli_round_trip(tmp_path):
    schema.save(tmp_path / "cells.npz", gerris_cells().replace(meta=schema.make_meta()))
    out = tmp_path / "bricks.npz"
    run_cli("brick", tmp_path / "cells.npz", "-o", out, "--max-brick-width", "16", check=0)
    bricks = schema.load(out, "bricks")
    check_bricks(gerris_cells(), bricks, 16)
    assert bricks.meta["parameters"] == {"max_brick_width": 16}
    assert bricks.meta["inputs"][0]["path"].endswith("cells.npz")
    assert bricks.meta["statistics"]["bricks"] == bricks.n_bricks
    info = run_cli("info", out, "--json", check=0)
    assert json.loads(info.stdout)["counts"]["bricks"] == bricks.n_bricks


def test_cli_refuses_wrong_kind_and_bad_width(tmp_path):
    cells = two_level_cells()
    schema.save(tmp_path / "cells.npz", cells)
    schema.save(tmp_path / "bricks.npz", build_bricks(cells))
    proc = run_cli("brick", tmp_path / "bricks.npz", "-o", tmp_path / "out.npz")
    assert_one_error_line(proc, "bricks.npz", "expected a cells file")
    proc = run_cli("brick", tmp_path / "cells.npz", "-o", tmp_path / "out.npz",
                   "--max-brick-width", "0")
    assert proc.returncode == 2 and "max-brick-width" in proc.stderr
    assert not (tmp_path / "out.npz").exists()


def test_cli_empty_input_names_the_file(tmp_path):
    schema.save(tmp_path / "empty.npz", make(np.zeros((0, 3)), []))
    proc = run_cli("brick", tmp_path / "empty.npz", "-o", tmp_path / "out.npz")
    assert_one_error_line(proc, "empty.npz", "no cells")
    assert not (tmp_path / "out.npz").exists()


@pytest.mark.slow
def test_builders_hold_at_most_twice_their_files(tmp_path):
    """Issue 11's bound for the builders, on the thin-shell layout (octree-like,
    many one-cell bricks, 4.8 M cells): each command's peak resident memory, less
    that of the same command on 64 cells, stays within twice the bytes of its
    input and output files."""
    from benchmarks.make_big import thin_shell_cells

    g = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    tiny = schema.Cells(fields=("rho",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                        lower_lattice=g.astype(np.int32), level=np.zeros(len(g), np.int8),
                        values=np.linspace(0, 1, len(g), dtype=np.float32)[None])
    sets = {"tiny": tiny, "shell": thin_shell_cells(512)}
    assert sets["shell"].n_cells > 4_000_000
    for name, cells in sets.items():
        schema.save(tmp_path / f"{name}_cells.npz", cells)
    del sets
    stages = [("brick", "cells", "bricks"), ("regions", "bricks", "regions"),
              ("bvh", "regions", "bvh")]
    for stage, src, dst in stages:
        peaks = {name: peak_rss([stage, tmp_path / f"{name}_{src}.npz",
                                 "-o", tmp_path / f"{name}_{dst}.npz"])
                 for name in ("tiny", "shell")}
        files = sum((tmp_path / f"shell_{n}.npz").stat().st_size for n in (src, dst))
        above = peaks["shell"] - peaks["tiny"]
        assert above <= 2 * files, (stage, above / 2**20, files / 2**20)
