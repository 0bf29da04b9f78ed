"""Active Brick Regions and the BVH over them, checked against brute force.

Every property is checked by an independent reference: coverage and
disjointness by rasterising boxes on the doubled lattice (where every support
and region bound is an integer), brick lists, value ranges and finest levels
by testing every cell of every brick, point location by a linear scan.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from exabricks import schema
from exabricks.util.errors import ExabricksError
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.builders.regions import EXACT, Merge, build_regions, partition, support_boxes_doubled

from amr_strategies import amr_cells
from helpers import AMREX, ATHENA, ENZO, GERRIS, assert_one_error_line, run_cli
from helpers.checks import (check_bvh, check_coverage_raster, check_regions_brute_force, check_support_tiling,
                            query_points)


# ---------------------------------------------------------------------------
# inputs


def make_cells(lower, level, values, fields=None) -> schema.Cells:
    values = np.asarray(values, np.float32)
    if values.ndim == 1:
        values = values[None]
    fields = fields or tuple(f"f{i}" for i in range(values.shape[0]))
    return schema.Cells(
        fields=tuple(fields), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.asarray(lower, np.int32).reshape(-1, 3),
        level=np.asarray(level, np.int8), values=values,
    )


def bricks_one_per_cell(cells: schema.Cells) -> schema.Bricks:
    """The simplest valid bricking: every cell its own 1x1x1 brick."""
    n = cells.n_cells
    return schema.Bricks(
        fields=cells.fields, origin_world=cells.origin_world, spacing_world=cells.spacing_world,
        lower_lattice=cells.lower_lattice, level=cells.level, dims=np.ones((n, 3), np.int32),
        offset=np.arange(n, dtype=np.int64), values=cells.values,
    )


def build_test_bricks(cells: schema.Cells, max_brick_width: int = 32) -> schema.Bricks:
    return build_bricks(cells, max_brick_width=max_brick_width)


# ---------------------------------------------------------------------------
# brute-force references


# ---------------------------------------------------------------------------
# tiny inputs with exact answers


def test_single_cell_regions_are_its_support():
    cells = make_cells([(4, 8, 12)], [2], [[7.0]])
    regions = build_regions(bricks_one_per_cell(cells))
    assert regions.n_regions == 1
    np.testing.assert_array_equal(regions.lower_lattice[0], [2, 6, 10])
    np.testing.assert_array_equal(regions.upper_lattice[0], [10, 14, 18])
    np.testing.assert_array_equal(regions.value_range[0, 0], [7, 7])
    assert regions.brick_ids.tolist() == [0] and regions.finest_level.tolist() == [2]
    assert regions.meta["statistics"]["n_regions"] == 1


def test_two_cells_in_a_row_three_regions():
    """Two unit cells side by side along x: supports [-.5,1.5] and [.5,2.5] overlap in [.5,1.5]."""
    cells = make_cells([(0, 0, 0), (1, 0, 0)], [0, 0], [[1.0, 5.0]])
    regions = build_regions(bricks_one_per_cell(cells), EXACT)
    order = np.argsort(regions.lower_lattice[:, 0])
    assert regions.lower_lattice[order, 0].tolist() == [-0.5, 0.5, 1.5]
    assert regions.upper_lattice[order, 0].tolist() == [0.5, 1.5, 2.5]
    lists = [regions.brick_ids[regions.brick_start[r]:regions.brick_start[r + 1]].tolist() for r in order]
    assert lists == [[0], [0, 1], [1]]
    assert regions.value_range[order, 0].tolist() == [[1, 1], [1, 5], [5, 5]]
    stats = regions.meta["statistics"]
    assert stats["avg_bricks_per_region_by_count"] == pytest.approx(4 / 3)
    assert stats["avg_bricks_per_region_by_volume"] == pytest.approx(4 / 3)
    assert stats["max_bricks_per_region"] == 2


def test_value_range_uses_only_cells_whose_support_overlaps():
    """A 4x1x1 brick next to a cell: the shared region sees only the brick's last cell."""
    bricks = schema.Bricks(
        fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.array([[0, 0, 0], [4, 0, 0]], np.int32), level=np.array([0, 0], np.int8),
        dims=np.array([[4, 1, 1], [1, 1, 1]], np.int32), offset=np.array([0, 4], np.int64),
        values=np.array([[-10, 1, 2, 3, 100]], np.float32),
    )
    regions = build_regions(bricks, EXACT)
    check_coverage_raster(bricks, regions)
    check_regions_brute_force(bricks, regions)
    # the region shared by both bricks, x in [3.5, 4.5]: cells 3 of brick 0 and brick 1
    r = int(np.flatnonzero(regions.lower_lattice[:, 0] == 3.5)[0])
    # (the whole of brick 0 would give [-10, 100])
    assert regions.value_range[r, 0].tolist() == [3, 100]


def test_nan_values_are_ignored():
    cells = make_cells([(0, 0, 0), (1, 0, 0)], [0, 0], [[np.nan, 2.0]])
    regions = build_regions(bricks_one_per_cell(cells), EXACT)
    order = np.argsort(regions.lower_lattice[:, 0])
    vr = regions.value_range[order, 0]
    assert np.isnan(vr[0]).all() and vr[1].tolist() == [2, 2] and vr[2].tolist() == [2, 2]
    bvh = build_bvh(regions, leaf_size=1)
    assert bvh.value_range[0, 0].tolist() == [2, 2]


def test_bvh_one_region_is_a_leaf_root():
    cells = make_cells([(0, 0, 0)], [0], [[3.0]])
    bvh = build_bvh(build_regions(bricks_one_per_cell(cells)))
    assert bvh.n_nodes == 1 and bvh.count.tolist() == [1] and bvh.first.tolist() == [0]


# ---------------------------------------------------------------------------
# properties on random layouts

# Merge settings every property must hold for: exact regions, the default, merging
# that keeps small boxes only, and merging nearly everything (big lists, empty space).
MERGES = (EXACT, Merge(), Merge(visit_cost=1.0, brick_cost=0.3, max_bricks=8),
          Merge(visit_cost=1e6, brick_cost=0.0, max_bricks=1 << 20, max_brick_cells=1 << 31))


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cells=amr_cells(max_cells=1500, max_level=4), width=st.sampled_from([0, 1, 2, 3, 8, 32]),
       leaf_size=st.integers(1, 6), seed=st.integers(0, 1000), merge=st.sampled_from(MERGES))
def test_random_layouts(cells, width, leaf_size, seed, merge):
    """Width 0: one brick per cell; otherwise the brick builder with that maximum width."""
    bricks = bricks_one_per_cell(cells) if width == 0 else build_test_bricks(cells, width)
    regions = build_regions(bricks, merge)
    schema.validate(regions)
    exact = not merge.enabled
    check_coverage_raster(bricks, regions, exact)
    check_support_tiling(bricks, regions)
    check_regions_brute_force(bricks, regions, exact=exact)
    stats = regions.meta["statistics"]
    counts = np.diff(regions.brick_start)
    assert stats["n_regions"] == regions.n_regions and stats["max_bricks_per_region"] == counts.max()
    assert stats["n_regions"] <= stats["n_partition_leaves"] and stats["n_bricks"] == bricks.n_bricks
    vol = np.prod((regions.upper_lattice - regions.lower_lattice).astype(np.float64), axis=1)
    assert stats["avg_bricks_per_region_by_count"] == pytest.approx(counts.mean())
    assert stats["avg_bricks_per_region_by_volume"] == pytest.approx((counts * vol).sum() / vol.sum())
    bvh = build_bvh(regions, leaf_size=leaf_size, bins=4 + seed % 13)
    schema.validate(bvh)
    assert bvh.count.max() <= leaf_size
    check_bvh(regions, bvh, query_points(regions, np.random.default_rng(seed)))


# ---------------------------------------------------------------------------
# real data


def gerris_cells() -> schema.Cells:
    """The Gerris plume read directly (little-endian int32 x, y, z, level; float32 per field)."""
    raw = np.fromfile(GERRIS, dtype="<i4").reshape(-1, 4)
    names = ("T", "U", "V", "W", "P")
    values = np.stack([np.fromfile(GERRIS.with_name(f"plume7-1.{n}.scalars"), "<f4") for n in names])
    return make_cells(raw[:, :3], raw[:, 3], values, names)


def check_real(cells, n_regions_checked=300, n_points=400, merge=None):
    merge = Merge() if merge is None else merge
    bricks = build_bricks(cells)
    regions = build_regions(bricks, merge)
    s_lo, s_hi = support_boxes_doubled(bricks)
    exact = not merge.enabled
    # exact coverage and disjointness by raster where the doubled lattice is small enough;
    # always: every support is tiled exactly by the regions listing it
    if np.prod((s_hi.max(0) - s_lo.min(0)).astype(np.float64)) <= 3e7:
        check_coverage_raster(bricks, regions, exact)
    check_support_tiling(bricks, regions)
    rng = np.random.default_rng(1)
    which = rng.choice(regions.n_regions, min(n_regions_checked, regions.n_regions), replace=False)
    check_regions_brute_force(bricks, regions, which, exact=exact)
    bvh = build_bvh(regions)
    pts = query_points(regions, rng, n_points)
    pts = pts[rng.choice(len(pts), min(len(pts), 2 * n_points), replace=False)]
    check_bvh(regions, bvh, pts)  # also: no sampled point lies in two regions
    return regions, bvh


@pytest.mark.slow
@pytest.mark.parametrize("merge", MERGES[:2], ids=["exact", "merged"])
def test_gerris_plume(merge):
    regions, bvh = check_real(gerris_cells(), merge=merge)
    assert regions.meta["statistics"]["n_bricks"] > 0


@pytest.mark.slow
def test_gerris_one_brick_per_cell_threads():
    """67,712 single-cell bricks: the partition splits into subtrees built on threads;
    the result must not depend on the thread count and must still tile every support."""
    bricks = bricks_one_per_cell(gerris_cells())
    s_lo, s_hi = support_boxes_doubled(bricks)
    one = partition(s_lo, s_hi, threads=1)
    two = partition(s_lo, s_hi, threads=2)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)
    cells = bricks.dims.astype(np.int64).prod(axis=1)
    for a, b in zip(partition(s_lo, s_hi, threads=1, level=bricks.level, cells=cells,
                              merge=Merge()),
                    partition(s_lo, s_hi, threads=2, level=bricks.level, cells=cells,
                              merge=Merge())):
        np.testing.assert_array_equal(a, b)
    regions = build_regions(bricks, EXACT)
    assert regions.meta["statistics"]["n_partition_leaves"] == one[0].shape[0]
    check_coverage_raster(bricks, regions)
    check_support_tiling(bricks, regions)
    rng = np.random.default_rng(2)
    check_regions_brute_force(bricks, regions, rng.choice(regions.n_regions, 100, replace=False))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["amrex", "athena", "enzo"])
def test_real_datasets(name):
    from exabricks import readers

    path = {"amrex": AMREX, "athena": ATHENA, "enzo": ENZO}[name]
    cells = readers.read(path)
    regions, bvh = check_real(cells)
    assert regions.fields == cells.fields and bvh.fields == cells.fields
    np.testing.assert_array_equal(regions.origin_world, cells.origin_world)


# ---------------------------------------------------------------------------
# command line


def write_bricks(path, cells):
    bricks = build_test_bricks(cells)
    schema.save(path, bricks.replace(meta=schema.make_meta()))
    return bricks


def test_cli_regions_and_bvh(tmp_path):
    cells = make_cells([(0, 0, 0), (1, 0, 0), (2, 0, 0)], [0, 0, 1], [[1, 2, 3]])
    bricks = write_bricks(tmp_path / "bricks.npz", cells)
    run_cli("regions", tmp_path / "bricks.npz", "-o", tmp_path / "regions.npz", check=0)
    run_cli("bvh", tmp_path / "regions.npz", "-o", tmp_path / "bvh.npz", "--leaf-size", "2", check=0)
    regions = schema.load(tmp_path / "regions.npz", "regions")
    bvh = schema.load(tmp_path / "bvh.npz", "bvh")
    assert regions.meta["consistency"]["n_bricks"] == bricks.n_bricks
    assert regions.meta["inputs"][0]["sha256"] == schema.sha256_file(tmp_path / "bricks.npz")
    assert regions.meta["statistics"]["n_regions"] == regions.n_regions
    assert bvh.meta["consistency"]["n_regions"] == regions.n_regions
    assert bvh.meta["consistency"]["n_bricks"] == bricks.n_bricks
    assert bvh.meta["inputs"][0]["sha256"] == schema.sha256_file(tmp_path / "regions.npz")
    assert bvh.meta["consistency"]["bricks_inputs"] == regions.meta["inputs"]
    assert bvh.meta["parameters"]["leaf_size"] == 2 and bvh.count.max() <= 2
    check_bvh(regions, bvh, query_points(regions, np.random.default_rng(0)))


@pytest.mark.slow
def test_cli_chain_gerris(tmp_path):
    """ingest -> brick -> regions -> bvh through the CLI; info reads the outputs."""
    cells, bricks, regions, bvh = (tmp_path / f"{k}.npz" for k in ("cells", "bricks", "regions", "bvh"))
    run_cli("ingest", GERRIS, "-o", cells, check=0)
    run_cli("brick", cells, "-o", bricks, check=0)
    run_cli("regions", bricks, "-o", regions, check=0)
    run_cli("bvh", regions, "-o", bvh, check=0)
    b = schema.load(bricks, "bricks")
    r = schema.load(regions, "regions")
    v = schema.load(bvh, "bvh")
    assert r.meta["consistency"] == {"n_bricks": b.n_bricks, "n_regions": r.n_regions}
    assert v.meta["consistency"]["n_regions"] == r.n_regions
    assert v.meta["consistency"]["bricks_inputs"][0]["sha256"] == schema.sha256_file(bricks)
    assert r.fields == b.fields == v.fields and set(r.fields) == {"T", "U", "V", "W", "P"}
    info = json.loads(run_cli("info", "--json", bvh, check=0).stdout)
    assert info["counts"]["regions"] == r.n_regions
    # the BVH root's value range is the range of all cell values (every cell is in some region)
    np.testing.assert_array_equal(v.value_range[0, :, 0], b.values.min(axis=1))
    np.testing.assert_array_equal(v.value_range[0, :, 1], b.values.max(axis=1))


def test_cli_wrong_kind(tmp_path):
    cells = make_cells([(0, 0, 0)], [0], [[1.0]])
    write_bricks(tmp_path / "bricks.npz", cells)
    proc = run_cli("bvh", tmp_path / "bricks.npz", "-o", tmp_path / "bvh.npz")
    assert_one_error_line(proc, "bricks.npz", "expected a regions file")
    proc = run_cli("regions", tmp_path / "nope.npz", "-o", tmp_path / "r.npz")
    assert proc.returncode == 2  # click: missing input
    assert not (tmp_path / "bvh.npz").exists() and not (tmp_path / "r.npz").exists()


def test_cli_inconsistent_regions(tmp_path):
    cells = make_cells([(0, 0, 0), (1, 0, 0)], [0, 0], [[1, 2]])
    write_bricks(tmp_path / "bricks.npz", cells)
    run_cli("regions", tmp_path / "bricks.npz", "-o", tmp_path / "regions.npz", check=0)
    regions = schema.load(tmp_path / "regions.npz", "regions")
    bad = regions.replace(brick_ids=regions.brick_ids + 5)
    schema.save(tmp_path / "bad.npz", bad)
    proc = run_cli("bvh", tmp_path / "bad.npz", "-o", tmp_path / "bvh.npz")
    assert_one_error_line(proc, "bad.npz", "brick ids")
    meta = dict(regions.meta, consistency={"n_bricks": 2, "n_regions": 99})
    schema.save(tmp_path / "bad2.npz", regions.replace(meta=meta))
    proc = run_cli("bvh", tmp_path / "bad2.npz", "-o", tmp_path / "bvh.npz")
    assert_one_error_line(proc, "bad2.npz", "99")
    assert not (tmp_path / "bvh.npz").exists()


def test_cli_bricks_beyond_float32_bounds(tmp_path):
    far = 1 << 24
    cells = make_cells([(far, 0, 0)], [0], [[1.0]])
    write_bricks(tmp_path / "bricks.npz", cells)
    proc = run_cli("regions", tmp_path / "bricks.npz", "-o", tmp_path / "regions.npz")
    assert_one_error_line(proc, "bricks.npz", "float32")
    assert not (tmp_path / "regions.npz").exists()


def test_stage_errors():
    cells = make_cells(np.zeros((0, 3)), [], np.zeros((1, 0)))
    with pytest.raises(ExabricksError, match="no cells"):
        build_regions(build_test_bricks(cells))
    regions = build_regions(build_test_bricks(make_cells([(0, 0, 0)], [0], [[1.0]])))
    with pytest.raises(ExabricksError, match="leaf size"):
        build_bvh(regions, leaf_size=0)


@pytest.mark.slow  # the library merge options are in the fast suite
def test_cli_merge_options(tmp_path):
    """Default merging, --exact, the tuning options and their refusals; the setting used
    is recorded in meta["parameters"]["merge"]."""
    cells, bricks = tmp_path / "cells.npz", tmp_path / "bricks.npz"
    run_cli("ingest", GERRIS, "-o", cells, check=0)
    run_cli("brick", cells, "-o", bricks, check=0)
    runs = {}
    for name, flags in (("default", []), ("exact", ["--exact"]),
                        ("zero", ["--visit-cost", "0"]),
                        ("tuned", ["--visit-cost", "4", "--brick-cost", "1", "--max-merged", "8",
                                   "--max-brick-cells", "64"])):
        out = tmp_path / f"{name}.npz"
        run_cli("regions", bricks, "-o", out, *flags, check=0)
        runs[name] = schema.load(out, "regions")
    n = {k: r.n_regions for k, r in runs.items()}
    assert n["default"] < n["tuned"] < n["exact"] == n["zero"]
    assert runs["default"].meta["parameters"]["merge"] == Merge().as_dict()
    assert runs["exact"].meta["parameters"]["merge"] == EXACT.as_dict()
    assert runs["tuned"].meta["parameters"]["merge"] == {
        "visit_cost": 4.0, "brick_cost": 1.0, "max_bricks": 8, "max_brick_cells": 64}
    for flags in (["--exact", "--visit-cost", "3"], ["--visit-cost", "nan"],
                  ["--brick-cost", "-1"], ["--max-merged", "-2"]):
        proc = run_cli("regions", bricks, "-o", tmp_path / "bad.npz", *flags)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, flags
    assert not (tmp_path / "bad.npz").exists()


def test_the_first_split_on_threads_gives_the_same_tree():
    """A BVH over 67,712 boxes (the Gerris plume's cell supports): its first split's
    passes run on numba's threads (bvh._split_root), the rest as before; the tree
    is array for array the one of a single thread."""
    from exabricks.builders.bvh import _build

    bricks = bricks_one_per_cell(gerris_cells())
    lo, hi = (np.ascontiguousarray(b, np.float32) for b in support_boxes_doubled(bricks))
    one, two = _build(lo, hi, 4, 16, 1), _build(lo, hi, 4, 16, 2)
    for a, b in zip(one[:3], two[:3]):
        np.testing.assert_array_equal(a, b)
