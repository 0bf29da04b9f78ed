"""`exabricks ingest`: ExaJet and raw readers, format detection, cell validation, errors.

Checks against independent references: the raw ExaJet bytes read with NumPy, a
brute-force pairwise overlap test, and a NumPy block-reshape version of the
uniform-to-AMR merge.
"""

from __future__ import annotations

import itertools
import re
import shutil
import time

import numpy as np
import pytest
from helpers import (AMREX, ATHENA, ENZO, GERRIS, LEAF_COUNTS, assert_one_error_line,
                      run_cli)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from amr_strategies import amr_cells
from exabricks import schema
from exabricks.util.errors import ExabricksError
from exabricks.readers import FORMATS, detect_format
from exabricks.readers.exajet import scalar_files
from exabricks.builders.uniform import amr_from_uniform
from exabricks.builders.cells import find_overlap, validate_cells
from exabricks.stages.ingest import ingest


from benchmarks import amrex_plotfile

GERRIS_FIELDS = ("P", "T", "U", "V", "W")


# ---------------------------------------------------------------------------
# helpers


def write_exajet(directory, stem, lower, level, fields):
    """Write STEM.cells and STEM.NAME.scalars; returns the .cells path."""
    directory.mkdir(parents=True, exist_ok=True)
    raw = np.empty((len(level), 4), "<i4")
    raw[:, :3] = lower
    raw[:, 3] = level
    path = directory / f"{stem}.cells"
    raw.tofile(path)
    for name, v in fields.items():
        np.asarray(v, "<f4").tofile(directory / f"{stem}.{name}.scalars")
    return path


def tiny_layout():
    """A level-1 cell at the origin and the 8 level-0 cells of the box [2,4)x[0,2)x[0,2)."""
    lower = [(0, 0, 0)] + [(2 + dx, dy, dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)]
    level = [1] + [0] * 8
    a = np.arange(9, dtype=np.float32) * 0.5
    b = -np.arange(9, dtype=np.float32)
    return np.array(lower, np.int32), np.array(level, np.int32), {"a": a, "b": b}


def brute_overlap(lower, level):
    """Whether any two cells' boxes intersect, by testing all pairs (float64-free, int64)."""
    lo = lower.astype(np.int64)
    hi = lo + (np.int64(1) << level.astype(np.int64))[:, None]
    inter = np.all(
        (lo[:, None, :] < hi[None, :, :]) & (lo[None, :, :] < hi[:, None, :]), axis=2
    )
    np.fill_diagonal(inter, False)
    return bool(inter.any())


def cells_of(lower, level, values=None):
    n = len(level)
    values = np.zeros((1, n), np.float32) if values is None else np.asarray(values, np.float32)
    return schema.Cells(
        fields=tuple(f"f{i}" for i in range(values.shape[0])),
        origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.asarray(lower, np.int32).reshape(-1, 3),
        level=np.asarray(level, np.int8), values=values,
    )


# ---------------------------------------------------------------------------
# the embedded Gerris plume through the CLI


def in_order_of(cells, lower, level):
    """`cells` (as `exabricks ingest` writes them: in piece order) permuted into the
    order of the cells `lower`, `level` (int arrays) read from the source."""
    mine = np.lexsort((cells.lower_lattice[:, 2], cells.lower_lattice[:, 1], cells.lower_lattice[:, 0],
                       cells.level))
    theirs = np.lexsort((lower[:, 2], lower[:, 1], lower[:, 0], level))
    order = np.empty_like(mine)
    order[theirs] = mine
    return cells.replace(lower_lattice=cells.lower_lattice[order], level=cells.level[order],
                         values=cells.values[:, order])


def test_gerris_plume_ingests_exactly(tmp_path):
    out = tmp_path / "cells.npz"
    run_cli("ingest", GERRIS, "-o", out, check=0)
    raw = np.fromfile(GERRIS, "<i4").reshape(-1, 4)
    cells = in_order_of(schema.load(out, "cells"), raw[:, :3], raw[:, 3])
    assert cells.n_cells == LEAF_COUNTS["gerris"] == 67_712
    assert cells.fields == GERRIS_FIELDS
    np.testing.assert_array_equal(cells.lower_lattice, raw[:, :3])
    np.testing.assert_array_equal(cells.level, raw[:, 3])
    for i, name in enumerate(GERRIS_FIELDS):
        expected = np.fromfile(GERRIS.with_name(f"plume7-1.{name}.scalars"), "<f4")
        np.testing.assert_array_equal(cells.values[i], expected)
    np.testing.assert_array_equal(cells.origin_world, [0, 0, 0])
    np.testing.assert_array_equal(cells.spacing_world, [1, 1, 1])
    inputs = [e["path"] for e in cells.meta["inputs"]]
    assert inputs[0] == str(GERRIS) and len(inputs) == 6
    assert cells.meta["piece_runs"]["starts"][0] == 0  # in piece order (test_pieces.py)
    assert all(e["sha256"] for e in cells.meta["inputs"])
    per_level = np.bincount(raw[:, 3])
    assert cells.meta["statistics"]["cells_per_level"] == {
        str(l): int(c) for l, c in enumerate(per_level) if c
    }
    # the plume's leaves tile its 128^3 lattice exactly
    assert int((8 ** raw[:, 3].astype(np.int64)).sum()) == 128 ** 3


def test_field_subset_keeps_requested_order(tmp_path):
    out = tmp_path / "cells.npz"
    run_cli("ingest", GERRIS, "-o", out, "--field", "T", "--field", "P", check=0)
    raw = np.fromfile(GERRIS, "<i4").reshape(-1, 4)
    cells = in_order_of(schema.load(out, "cells"), raw[:, :3], raw[:, 3])
    assert cells.fields == ("T", "P")
    np.testing.assert_array_equal(cells.values[0], np.fromfile(GERRIS.with_name("plume7-1.T.scalars"), "<f4"))
    np.testing.assert_array_equal(cells.values[1], np.fromfile(GERRIS.with_name("plume7-1.P.scalars"), "<f4"))


def test_magnitude_field(tmp_path):
    out = tmp_path / "cells.npz"
    run_cli("ingest", GERRIS, "-o", out, "--magnitude", "speed=U,V,W",
            "--field", "T", "--field", "speed", check=0)
    raw = np.fromfile(GERRIS, "<i4").reshape(-1, 4)
    cells = in_order_of(schema.load(out, "cells"), raw[:, :3], raw[:, 3])
    assert cells.fields == ("T", "speed")
    u, v, w = (np.fromfile(GERRIS.with_name(f"plume7-1.{c}.scalars"), "<f4").astype(np.float64)
               for c in "UVW")
    np.testing.assert_array_equal(cells.values[1], np.sqrt(u * u + v * v + w * w).astype(np.float32))


def test_explicit_scalars_and_sibling_discovery(tmp_path):
    lower, level, fields = tiny_layout()
    path = write_exajet(tmp_path / "in", "tiny", lower, level, fields)
    assert list(scalar_files(path)) == ["a", "b"]
    out = tmp_path / "cells.npz"
    run_cli("ingest", path, "-o", out, "--scalars", f"temp={path.with_name('tiny.b.scalars')}", check=0)
    cells = schema.load(out, "cells")
    assert cells.fields == ("temp",)
    np.testing.assert_array_equal(cells.values[0], fields["b"])
    assert [e["path"] for e in cells.meta["inputs"]] == [str(path), str(path.with_name("tiny.b.scalars"))]


# ---------------------------------------------------------------------------
# every error path: one `error:` line naming the file and the problem, exit 1, no output


def _case_missing(d):
    return [d / "nothere.cells"], [d / "nothere.cells", "no such file"]


def _case_missing_scalars(d):
    p = write_exajet(d, "t", *tiny_layout())
    return [p, "--scalars", f"a={d / 'gone.scalars'}"], [d / "gone.scalars", "no such file"]


def _case_no_scalars(d):
    lower, level, _ = tiny_layout()
    p = write_exajet(d, "t", lower, level, {})
    return [p], [p, "no scalar files"]


def _case_truncated_cells(d):
    p = write_exajet(d, "t", *tiny_layout())
    p.write_bytes(p.read_bytes()[:-3])
    return [p], [p, "truncated", "not a multiple of 16"]


def _case_truncated_scalars(d):
    p = write_exajet(d, "t", *tiny_layout())
    s = d / "t.b.scalars"
    s.write_bytes(s.read_bytes()[:-2])
    return [p], [s, "truncated"]


def _case_count_mismatch(d):
    lower, level, fields = tiny_layout()
    fields["b"] = np.append(fields["b"], 1.0)
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [d / "t.b.scalars", "10 values", p, "9 cells"]


def _case_negative_level(d):
    lower, level, fields = tiny_layout()
    level[3] = -1
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [p, "cell 3", "level -1"]


def _case_misaligned(d):
    lower, level, fields = tiny_layout()
    lower[0] = (0, 1, 0)
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [p, "cell 0", "[0, 1, 0]", "misaligned"]


def _case_duplicate(d):
    lower, level, fields = tiny_layout()
    lower, level = np.vstack([lower, lower[4:5]]), np.append(level, level[4])
    fields = {k: np.append(v, v[4]) for k, v in fields.items()}
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [p, "cell 9", "duplicates cell 4", str(lower[4].tolist())]


def _case_coarse_covers_fine(d):
    lower, level, fields = tiny_layout()
    lower, level = np.vstack([lower, [(2, 0, 0)]]), np.append(level, 1)
    fields = {k: np.append(v, 0.0) for k, v in fields.items()}
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [p, "cell 9 at [2, 0, 0] (level 1) overlaps cell"]


def _case_nan(d):
    lower, level, fields = tiny_layout()
    fields["a"][5] = np.nan
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [p, "field 'a'", "nan", "cell 5"]


def _case_inf(d):
    lower, level, fields = tiny_layout()
    fields["b"][2] = -np.inf
    p = write_exajet(d, "t", lower, level, fields)
    return [p], [p, "field 'b'", "-inf", "cell 2"]


def _case_empty(d):
    lower, level, fields = tiny_layout()
    p = write_exajet(d, "t", lower[:0], level[:0], {k: v[:0] for k, v in fields.items()})
    return [p], [p, "no cells"]


def _case_unknown_format(d):
    d.mkdir(parents=True)
    p = d / "mystery.dat"
    p.write_bytes(b"\0" * 64)
    return [p], [p, "cannot tell the format", "--format"]


def _case_unknown_field(d):
    p = write_exajet(d, "t", *tiny_layout())
    return [p, "--field", "c"], [p, "no field 'c'", "a, b"]


def _case_bad_dims(d):
    d.mkdir(parents=True)
    p = d / "v.raw"
    np.zeros(60, "<f4").tofile(p)
    return [p, "--dims", 4, 4, 4], [p, "240 bytes", "--dims 4 4 4", "256 bytes"]


def _case_raw_without_dims(d):
    d.mkdir(parents=True)
    p = d / "v.raw"
    np.zeros(64, "<f4").tofile(p)
    return [p], [p, "--dims"]


def _case_dims_for_exajet(d):
    p = write_exajet(d, "t", *tiny_layout())
    return [p, "--dims", 2, 2, 2], [p, "--dims", "raw"]


ERROR_CASES = {name[len("_case_"):]: f for name, f in globals().items() if name.startswith("_case_")}


@pytest.mark.parametrize("case", sorted(ERROR_CASES))
def test_error_paths(tmp_path, case):
    args, needles = ERROR_CASES[case](tmp_path / "in")
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    proc = run_cli("ingest", *args, "-o", out_dir / "cells.npz")
    assert_one_error_line(proc, *needles)
    assert list(out_dir.iterdir()) == []  # no output, not even a temporary


def test_unknown_format_name_is_a_usage_error(tmp_path):
    proc = run_cli("ingest", GERRIS, "--format", "vtk", "-o", tmp_path / "c.npz")
    assert proc.returncode == 2 and "vtk" in proc.stderr
    assert not (tmp_path / "c.npz").exists()


@pytest.mark.parametrize("policy", ["zero", "drop", "keep"])
def test_nan_policies(tmp_path, policy):
    lower, level, fields = tiny_layout()
    fields["a"][5] = np.nan
    fields["b"][2] = np.inf
    p = write_exajet(tmp_path, "t", lower, level, fields)
    out = tmp_path / "cells.npz"
    run_cli("ingest", p, "-o", out, "--nan", policy, check=0)
    cells = schema.load(out, "cells")
    a, b = fields["a"], fields["b"]
    if policy == "zero":
        assert cells.n_cells == 9
        np.testing.assert_array_equal(cells.values[0], np.where(np.isfinite(a), a, 0))
        np.testing.assert_array_equal(cells.values[1], np.where(np.isfinite(b), b, 0))
    elif policy == "drop":
        keep = np.array([i not in (2, 5) for i in range(9)])
        assert cells.n_cells == 7
        np.testing.assert_array_equal(cells.lower_lattice, lower[keep])
        np.testing.assert_array_equal(cells.values, np.stack([a[keep], b[keep]]))
        assert cells.meta["statistics"]["dropped_nonfinite_cells"] == 2
    else:
        np.testing.assert_array_equal(cells.values, np.stack([a, b]))


def test_nan_drop_of_every_cell_is_an_error(tmp_path):
    lower, level, fields = tiny_layout()
    fields["a"][:] = np.nan
    p = write_exajet(tmp_path / "in", "t", lower, level, fields)
    (tmp_path / "out").mkdir()
    proc = run_cli("ingest", p, "-o", tmp_path / "out" / "c.npz", "--nan", "drop")
    assert_one_error_line(proc, p, "no cells left")
    assert list((tmp_path / "out").iterdir()) == []


# ---------------------------------------------------------------------------
# validate_cells / find_overlap against brute force


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cells=amr_cells(max_cells=400), data=st.data())
def test_valid_layouts_pass_and_added_overlaps_are_found(cells, data):
    assert find_overlap(cells.lower_lattice, cells.level) is None
    assert validate_cells(cells, source="x") is cells
    # add a cell that duplicates one, or that covers one from a coarser level
    i = data.draw(st.integers(0, cells.n_cells - 1))
    up = data.draw(st.integers(0, 2))
    l = int(cells.level[i]) + up
    corner = (cells.lower_lattice[i] >> l) << l
    lower = np.vstack([cells.lower_lattice, corner[None]]).astype(np.int32)
    level = np.append(cells.level, np.int8(l))
    pair = find_overlap(lower, level)
    assert pair is not None and pair[1] == cells.n_cells
    a, b = pair
    assert brute_overlap(lower[[a, b]], level[[a, b]])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 7), st.integers(0, 7), st.integers(0, 7),
                          st.integers(0, 3)), min_size=1, max_size=12),
       st.sampled_from([0, 1 << 29]))
def test_find_overlap_matches_brute_force(raw, shift):
    # shift 2**29 on one axis forces the 96-bit Morton path (too many bits for one key)
    level = np.array([r[3] for r in raw], np.int8)
    lower = np.array([[(r[a] >> r[3]) << r[3] for a in range(3)] for r in raw], np.int32)
    lower[0, 0] += shift
    lower[1:, 0] += shift * (np.arange(1, len(raw)) % 2)
    pair = find_overlap(lower, level)
    assert (pair is not None) == brute_overlap(lower, level)
    if pair is not None:
        assert pair[0] < pair[1] and brute_overlap(lower[list(pair)], level[list(pair)])


def test_validate_cells_errors_directly():
    with pytest.raises(ExabricksError, match="src: cell 1 at \\[2, 0, 0\\] has level -1"):
        validate_cells(cells_of([(0, 0, 0), (2, 0, 0)], [0, -1]), source="src")
    with pytest.raises(ExabricksError, match="src: no cells"):
        validate_cells(cells_of(np.zeros((0, 3)), []), source="src")
    with pytest.raises(ExabricksError, match="unknown NaN policy"):
        validate_cells(cells_of([(0, 0, 0)], [0]), source="src", nan_policy="ignore")


# ---------------------------------------------------------------------------
# raw volumes -> AMR


def merge_reference(volume, max_level, threshold):
    """NumPy reference: set of (x, y, z, level) -> float64 mean, from block reshapes of voxels."""
    nz, ny, nx = volume.shape
    top = min(max_level, int(min(volume.shape)).bit_length() - 1)
    v = volume.astype(np.float64)
    finite = np.isfinite(v)
    ok = {0: np.ones(v.shape, bool)}  # every voxel is a cell; only finite ones merge
    mean = {0: v}
    for l in range(1, top + 1):
        w = 1 << l
        shape = (nz >> l, ny >> l, nx >> l)
        blk = v[: shape[0] * w, : shape[1] * w, : shape[2] * w].reshape(
            shape[0], w, shape[1], w, shape[2], w)
        fin = finite[: shape[0] * w, : shape[1] * w, : shape[2] * w].reshape(blk.shape)
        children = ok[l - 1][: shape[0] * 2, : shape[1] * 2, : shape[2] * 2].reshape(
            shape[0], 2, shape[1], 2, shape[2], 2)
        rng = blk.max(axis=(1, 3, 5)) - blk.min(axis=(1, 3, 5))
        ok[l] = children.all(axis=(1, 3, 5)) & fin.all(axis=(1, 3, 5)) & (rng <= threshold)
        mean[l] = blk.mean(axis=(1, 3, 5))
    out = {}
    for l in range(top + 1):
        for k, j, i in zip(*np.nonzero(ok[l])):
            parent = l < top and all(c >> 1 < s for c, s in zip((k, j, i), ok[l + 1].shape)) \
                and ok[l + 1][k >> 1, j >> 1, i >> 1]
            if not parent:
                out[(int(i) << l, int(j) << l, int(k) << l, l)] = mean[l][k, j, i]
    return out


def as_dict(lower, level, values):
    return {(*map(int, c), int(l)): v for c, l, v in zip(lower, level, values)}


def test_hand_built_volume_merges_exactly():
    v = np.zeros((4, 4, 4), np.float32)
    v[3, 3, 3] = 5.0  # voxel x=3, y=3, z=3
    lower, level, values = amr_from_uniform(v, threshold=0)
    got = as_dict(lower, level, values)
    expected = {(x, y, z, 1): 0.0 for x, y, z in itertools.product((0, 2), repeat=3) if (x, y, z) != (2, 2, 2)}
    expected.update({(x, y, z, 0): (5.0 if (x, y, z) == (3, 3, 3) else 0.0)
                     for x, y, z in itertools.product((2, 3), repeat=3)})
    assert got == expected and len(level) == 15
    # a threshold of 5 merges the whole volume into one level-2 cell holding the mean
    lower, level, values = amr_from_uniform(v, threshold=5.0)
    assert lower.tolist() == [[0, 0, 0]] and level.tolist() == [2]
    assert values.tolist() == [5.0 / 64]


def test_constant_volume_merges_to_coarsest_and_respects_max_level():
    v = np.full((8, 8, 8), 2.5, np.float32)
    lower, level, values = amr_from_uniform(v, threshold=0)
    assert lower.tolist() == [[0, 0, 0]] and level.tolist() == [3] and values.tolist() == [2.5]
    lower, level, values = amr_from_uniform(v, max_level=1, threshold=0)
    assert len(level) == 64 and set(level.tolist()) == {1} and set(values.tolist()) == {2.5}


def test_ragged_edge_stays_fine():
    v = np.ones((4, 4, 5), np.float32)  # X = 5: the column x = 4 cannot form a group
    lower, level, values = amr_from_uniform(v, threshold=0)
    got = as_dict(lower, level, values)
    expected = {(0, 0, 0, 2): 1.0}
    expected.update({(4, y, z, 0): 1.0 for y in range(4) for z in range(4)})
    assert got == expected


def test_threshold_zero_on_noise_keeps_every_voxel():
    v = np.random.default_rng(3).random((6, 8, 10)).astype(np.float32)
    lower, level, values = amr_from_uniform(v, threshold=0)
    assert len(level) == v.size and not level.any()
    np.testing.assert_array_equal(values, v[lower[:, 2], lower[:, 1], lower[:, 0]])


@settings(max_examples=80, deadline=None)
@given(dims=st.tuples(st.integers(1, 11), st.integers(1, 11), st.integers(1, 11)),
       n_values=st.integers(1, 3), threshold=st.sampled_from([0.0, 1.0, 2.0]),
       max_level=st.integers(0, 4), seed=st.integers(0, 2**32 - 1), nan=st.booleans())
def test_merge_covers_volume_once_with_block_means(dims, n_values, threshold, max_level, seed, nan):
    rng = np.random.default_rng(seed)
    x, y, z = dims
    # few distinct small integers: merges happen, and float64 sums of them are exact
    v = rng.integers(0, n_values + 1, (z, y, x)).astype(np.float32)
    if rng.random() < 0.5:  # two constant halves: large merged patches
        v[:] = rng.integers(0, 2) + (np.arange(x) >= x // 2)
    if nan:
        v[tuple(rng.integers(0, s) for s in v.shape)] = np.nan
    lower, level, values = amr_from_uniform(v, max_level=max_level, threshold=threshold)
    # covers every voxel exactly once
    count = np.zeros(v.shape, np.int64)
    for (cx, cy, cz), l in zip(lower, level):
        w = 1 << int(l)
        count[cz:cz + w, cy:cy + w, cx:cx + w] += 1
    assert (count == 1).all() and int((8 ** level.astype(np.int64)).sum()) == v.size
    # each value is the mean of the voxels it covers; the set equals the NumPy reference
    ref = merge_reference(v, max_level, threshold)
    got = as_dict(lower, level, values)
    assert got.keys() == ref.keys()
    for key, val in got.items():
        cx, cy, cz, l = key
        w = 1 << l
        block = v[cz:cz + w, cy:cy + w, cx:cx + w].astype(np.float64)
        np.testing.assert_array_equal(val, np.float32(block.mean()))
        if l:
            assert block.max() - block.min() <= threshold
    cells = cells_of(lower, level, values[None])
    validate_cells(cells, source="x", nan_policy="keep")


def test_raw_volume_through_cli(tmp_path):
    v = np.zeros((4, 4, 6), np.float32)  # X = 6, Y = 4, Z = 4, x fastest
    v[:, :, 4:] = np.arange(32, dtype=np.float32).reshape(4, 4, 2)
    path = tmp_path / "v.raw"
    v.astype(">f4").tofile(path)
    out = tmp_path / "cells.npz"
    run_cli("ingest", path, "-o", out, "--dims", 6, 4, 4, "--byte-order", "big",
            "--name", "rho", "--threshold", 0, check=0)
    cells = schema.load(out, "cells")
    lower, level, values = amr_from_uniform(v, threshold=0)
    assert cells.fields == ("rho",)
    assert as_dict(cells.lower_lattice, cells.level, cells.values[0]) == as_dict(lower, level, values)
    # [0,4)^3 merges to one level-2 cell; x in [4,6) stays at level 0 (32 voxels)
    assert sorted(np.bincount(cells.level).tolist()) == [0, 1, 32]
    assert cells.meta["parameters"]["dims"] == [6, 4, 4]


@pytest.mark.parametrize("flags, needles", [
    (["--field", "value", "--field", "value"], ["--fields", "'value' is given twice"]),
    (["--fields", "value,value"], ["--fields", "'value' is given twice"]),
    (["--name", ""], ["--name", "empty"]),
    (["--name", "v\nerror: forged line"], ["--name", "control character"]),
    (["--derive", "a\tb=value"], ["--derive", "control character"]),
    (["--magnitude", "m\x1b[31m=value"], ["--magnitude", "control character"]),
], ids=["field-twice", "fields-twice", "empty-name", "newline-name", "tab-derive", "escape-magnitude"])
def test_bad_field_names_are_one_error_line_naming_the_option(tmp_path, flags, needles):
    """Field names given twice (once "internal error: StopIteration"), empty, or with
    a control character (a newline forged an output line) are refused before
    anything is read; the library refuses them too."""
    path = tmp_path / "v.raw"
    np.arange(8, dtype="<f4").tofile(path)
    out = tmp_path / "cells.npz"
    assert_one_error_line(run_cli("ingest", path, "--dims", 2, 2, 2, *flags, "-o", out),
                          str(path), *needles)
    assert not out.exists()
    with pytest.raises(ExabricksError, match="given twice"):
        ingest(path, dims=(2, 2, 2), fields=["value", "value"])
    with pytest.raises(ExabricksError, match="given twice"):
        from exabricks.readers import raw
        raw.read(path, dims=(2, 2, 2), fields=["value", "value"])


# ---------------------------------------------------------------------------
# format detection, and the other readers through `--format auto`


def test_detect_format_of_shared_datasets(tmp_path):
    assert detect_format(AMREX) == "amrex"
    assert detect_format(ATHENA) == "athena"
    assert detect_format(GERRIS) == "exajet"
    assert detect_format(ENZO) == "yt"
    raw = tmp_path / "v.raw"
    raw.write_bytes(b"")
    assert detect_format(raw, dims=(1, 1, 1)) == "raw"
    with pytest.raises(ExabricksError, match="--dims"):
        detect_format(raw)
    flash = tmp_path / "sedov_hdf5_plt_cnt_0001"
    flash.write_bytes(b"")
    assert detect_format(flash) == "yt"
    with pytest.raises(ExabricksError, match="no such file"):
        detect_format(tmp_path / "none.cells")
    assert set(FORMATS) == {"exajet", "amrex", "athena", "ramses", "raw", "yt"}


@pytest.mark.parametrize("name, path", [("amrex", AMREX), ("athena", ATHENA),
                                        pytest.param("enzo", ENZO, marks=pytest.mark.slow)])
def test_auto_format_ingests_shared_datasets(tmp_path, name, path):
    out = tmp_path / "cells.npz"
    run_cli("ingest", path, "-o", out, check=0)
    cells = schema.load(out, "cells")
    assert cells.n_cells == LEAF_COUNTS[name]
    assert cells.meta["parameters"]["format"] == {"enzo": "yt"}.get(name, name)
    assert len(cells.meta["inputs"]) >= 1


# ---------------------------------------------------------------------------
# the stage function


def test_ingest_stage_returns_checked_cells_with_meta():
    cells = ingest(GERRIS, fields=["T"], magnitude=[("speed", "U,V,W")])
    assert cells.fields == ("T",) and cells.n_cells == LEAF_COUNTS["gerris"]
    params = cells.meta["parameters"]
    assert params["format"] == "exajet" and params["magnitude"] == {"speed": "U,V,W"}
    assert params["mask"] is None and params["mask_auto"] is False
    assert cells.meta["statistics"]["masked_cells"] == 0
    with pytest.raises(ExabricksError, match="--dims only apply to raw volumes"):
        ingest(GERRIS, dims=(2, 2, 2))


# ---------------------------------------------------------------------------
# derived fields: derive=[(NAME, EXPR)], expressions in numexpr's language


def gerris_field(name):
    """A Gerris plume field as float64, straight from its .scalars file."""
    return np.fromfile(GERRIS.with_name(f"plume7-1.{name}.scalars"), "<f4").astype(np.float64)


def test_derive_equals_numpy_in_float64():
    cells = ingest(GERRIS, derive=[("mix", "(T - P) * V / (1 + U * U) + sqrt(T * T + P * P) / 3")])
    assert cells.fields == (*GERRIS_FIELDS, "mix")
    t, p, u, v = (gerris_field(n) for n in "TPUV")
    expected = ((t - p) * v / (1 + u * u) + np.sqrt(t * t + p * p) / 3).astype(np.float32)
    np.testing.assert_array_equal(cells.values[-1], expected)
    assert cells.meta["parameters"]["derive"] == {
        "mix": "(T - P) * V / (1 + U * U) + sqrt(T * T + P * P) / 3"}


def test_derive_with_field_selection_and_mask():
    # `hot` (a comparison: 1 or 0) masks, `ratio` reads U and W, and only T and ratio are
    # kept: U, W and hot are read or made, used, then dropped.
    cells = ingest(GERRIS, fields=["T", "ratio"], mask="hot",
                   derive={"hot": "T > 0.25", "ratio": "U / W"})
    t, u, w = (gerris_field(n) for n in "TUW")
    keep = t > 0.25
    assert 0 < keep.sum() < len(t)
    assert cells.fields == ("T", "ratio") and cells.n_cells == keep.sum()
    np.testing.assert_array_equal(cells.values[0], t[keep].astype(np.float32))
    np.testing.assert_array_equal(cells.values[1], (u / w)[keep].astype(np.float32))
    params = cells.meta["parameters"]
    assert params["derive"] == {"hot": "T > 0.25", "ratio": "U / W"} and params["mask"] == "hot"
    assert cells.meta["statistics"]["masked_cells"] == len(t) - keep.sum()


def test_derive_uses_magnitudes_earlier_fields_functions_and_constants():
    # a constant is the same at every cell; a name that is no identifier goes in backticks
    cells = ingest(GERRIS, magnitude={"speed": "U,V,W"}, fields=["k", "k2", "up", "one", "x-y"],
                   derive=[("k", "0.5 * speed**2"), ("k2", "where(k > 1e-4, log10(k), -4)"),
                           ("up", "(V > 0) & ~(abs(U) > 0.05)"), ("one", "1"),
                           ("x-y", "`one` + 1")])
    u, v, w = (gerris_field(n) for n in "UVW")
    speed = np.sqrt(u * u + v * v + w * w).astype(np.float32).astype(np.float64)
    k = (0.5 * speed**2).astype(np.float32)
    assert cells.fields == ("k", "k2", "up", "one", "x-y")
    np.testing.assert_allclose(cells.values[0], k, rtol=1e-7)
    k64 = k.astype(np.float64)  # a derived field reads the earlier ones as stored (float32)
    np.testing.assert_allclose(cells.values[1], np.where(k64 > 1e-4, np.log10(k64), -4), rtol=1e-6)
    np.testing.assert_array_equal(cells.values[2], ((v > 0) & ~(np.abs(u) > 0.05)).astype(np.float32))
    np.testing.assert_array_equal(cells.values[3], np.ones(len(u), np.float32))  # broadcast
    np.testing.assert_array_equal(cells.values[4], np.full(len(u), 2, np.float32))


def test_derive_division_by_zero_meets_the_nan_policy():
    with pytest.raises(ExabricksError, match=r"field 'r' is -?inf at cell \d+"):
        ingest(GERRIS, derive=[("r", "1 / (T - T)")])
    cells = ingest(GERRIS, derive=[("r", "T / 0"), ("z", "0 / 0")], nan_policy="zero",
                   fields=["r", "z"])
    assert not cells.values.any()
    cells = ingest(GERRIS, derive=[("r", "1 / (T - T)")], nan_policy="keep", fields=["r"])
    assert np.isposinf(cells.values[0]).all()


DERIVE_ERRORS = {
    "unknown field": (("s", "T + x"), "unknown field 'x' (fields: P, T, U, V, W, speed)"),
    "syntax": (("s", "T +"), "syntax error"),
    "attribute": (("s", "T.__class__"), "attribute access 'T.__class__' is not allowed"),
    "attribute call": (("s", "().__class__.__bases__[0]()"), "only functions can be called"),
    "import": (("s", "__import__('os').system('true')"), "attribute access"),
    "unknown function": (("s", "foo(T)"), "unknown function 'foo' (functions: abs,"),
    "builtin": (("s", "eval('1')"), "unknown function 'eval'"),
    "reduction": (("s", "sum(T)"), "sum is a reduction over all cells"),
    "arity": (("s", "sqrt(T, U)"), "sqrt takes 1 argument, not 2"),
    "keywords": (("s", "hypot(T, y=U)"), "hypot takes plain positional arguments"),
    "input name": (("T", "U * 2"), "a field named 'T' exists already"),
    "magnitude name": (("speed", "U"), "a field named 'speed' exists already"),
    "derived twice": (("s", "U"), "a field named 's' exists already"),
    "string": (("s", "'abc'"), "only real numbers can be constants"),
    "complex": (("s", "1j * T"), "only real numbers can be constants"),
    "indexing": (("s", "T[0]"), "indexing 'T[0]' is not allowed"),
    "lambda": (("s", "(lambda: T)()"), "only functions can be called"),
    "conditional": (("s", "T if U else V"), "use where(condition, a, b)"),
    "and": (("s", "(T > 0) and (U > 0)"), "use & and |"),
    "chained": (("s", "0 < T < 1"), "chained comparisons are not supported"),
    "floor division": (("s", "T // U"), "operator '//' is not supported"),
    "xor": (("s", "T ^ 2"), "operator '^' is not supported (** is the power)"),
    "bitwise on numbers": (("s", "T & U"), "numexpr cannot evaluate it"),
    "backtick": (("s", "`T + U"), "unmatched backtick"),
    "empty": (("s", "  "), "empty expression"),
    "no name": (("", "T"), "the field needs a name"),
    "newline": (("s", "T\n+ U"), "syntax error"),
    "nested": (("s", "(" * 300 + "T" + ")" * 300), "derived field 's'"),
}


@pytest.mark.parametrize("fields", [(), ("T",)], ids=["all", "subset"])
@pytest.mark.parametrize("case", sorted(DERIVE_ERRORS))
def test_derive_errors_name_the_file_field_and_problem(case, fields):
    pair, needle = DERIVE_ERRORS[case]
    derive = [("s", "T")] if case == "derived twice" else []
    with pytest.raises(ExabricksError) as info:
        ingest(GERRIS, fields=fields, magnitude={"speed": "U,V,W"}, derive=[*derive, pair])
    message = str(info.value)
    assert message.startswith(f"{GERRIS}: derived field {pair[0]!r} = ") and needle in message
    assert "\n" not in message


def test_derive_must_be_name_expression_pairs():
    for bad in (["s=T"], [("s", "T", "U")], [("s", 1)]):
        with pytest.raises(ExabricksError, match=r"a derived field is a \(NAME, EXPRESSION\) pair"):
            ingest(GERRIS, derive=bad)


def test_derive_is_checked_before_reading(monkeypatch):
    from exabricks import readers

    def no_read(*args, **kwargs):
        raise AssertionError("read")

    monkeypatch.setattr(readers, "read", no_read)
    with pytest.raises(ExabricksError, match="syntax error"):
        ingest(GERRIS, derive=[("s", "T +")])
    with pytest.raises(ExabricksError, match=r"unknown field 'x' \(fields: P, T, U, V, W, speed\)"):
        ingest(GERRIS, fields=["s"], magnitude={"speed": "U,V,W"}, derive=[("s", "x * speed")])


# ---------------------------------------------------------------------------
# --mask FIELD and the automatic volFrac rule (embedded-boundary bodies become holes)


def test_mask_drops_cells_where_the_field_is_zero(tmp_path):
    lower, level, fields = tiny_layout()  # b = -arange(9): b is 0 at cell 0 only
    fields["b"][4] = -0.0                 # -0 is zero too
    p = write_exajet(tmp_path, "t", lower, level, fields)
    out = tmp_path / "cells.npz"
    run_cli("ingest", p, "-o", out, "--mask", "b", check=0)
    cells = schema.load(out, "cells")
    keep = np.array([i not in (0, 4) for i in range(9)])
    np.testing.assert_array_equal(cells.lower_lattice, lower[keep])
    np.testing.assert_array_equal(cells.values, np.stack([fields["a"][keep], fields["b"][keep]]))
    assert cells.meta["parameters"]["mask"] == "b" and not cells.meta["parameters"]["mask_auto"]
    assert cells.meta["statistics"]["masked_cells"] == 2
    # the mask field is read even when --field leaves it out, and then not kept
    run_cli("ingest", p, "-o", out, "--mask", "b", "--field", "a", check=0)
    cells = schema.load(out, "cells")
    assert cells.fields == ("a",)
    np.testing.assert_array_equal(cells.values[0], fields["a"][keep])


@pytest.mark.parametrize("field_args", [[], ["--field", "a"]])
def test_volfrac_masks_automatically_unless_no_mask(tmp_path, field_args):
    lower, level, fields = tiny_layout()
    vf = np.ones(9, np.float32)
    vf[[1, 7]] = 0.0
    vf[2] = 0.25
    p = write_exajet(tmp_path, "t", lower, level, {"a": fields["a"], "volFrac": vf})
    out = tmp_path / "cells.npz"
    run_cli("ingest", p, "-o", out, *field_args, check=0)
    cells = schema.load(out, "cells")
    keep = vf != 0
    assert cells.fields == (("a",) if field_args else ("a", "volFrac"))
    np.testing.assert_array_equal(cells.lower_lattice, lower[keep])
    np.testing.assert_array_equal(cells.values[0], fields["a"][keep])
    assert cells.meta["parameters"]["mask"] == "volFrac"
    assert cells.meta["parameters"]["mask_auto"] is True
    assert cells.meta["statistics"]["masked_cells"] == 2
    run_cli("ingest", p, "-o", out, "--no-mask", *field_args, check=0)
    cells = schema.load(out, "cells")
    assert cells.n_cells == 9 and cells.meta["parameters"]["mask"] is None
    assert cells.meta["parameters"]["no_mask"] is True


def test_mask_errors(tmp_path):
    lower, level, fields = tiny_layout()
    p = write_exajet(tmp_path / "in", "t", lower, level, fields)
    (tmp_path / "out").mkdir()
    out = tmp_path / "out" / "c.npz"
    for extra in ([], ["--field", "a"]):
        proc = run_cli("ingest", p, "-o", out, "--mask", "volFrac", *extra)
        assert_one_error_line(proc, p, "no field 'volFrac' for --mask", "a, b")
    proc = run_cli("ingest", p, "-o", out, "--mask", "a", "--no-mask")
    assert proc.returncode == 2 and "--no-mask" in proc.stderr
    fields["a"][:] = 0
    p = write_exajet(tmp_path / "in", "t", lower, level, fields)
    proc = run_cli("ingest", p, "-o", out, "--mask", "a")
    assert_one_error_line(proc, p, "every cell has a == 0")
    assert list((tmp_path / "out").iterdir()) == []


def _volfrac(lower, width):
    """A sphere body (volFrac 0) with a cut-cell shell (0.5) in the unit cube, from lattice
    corners (N, 3) and widths (N,) on the 128^3 finest lattice of the AMReX dataset."""
    centre = (np.asarray(lower, np.float64) + 0.5 * np.asarray(width, np.float64)[:, None]) / 128
    r = np.linalg.norm(centre - [0.3, 0.4, 0.55], axis=1)
    return np.where(r < 0.2, 0.0, np.where(r < 0.23, 0.5, 1.0))


def add_component(src, dst, name, values):
    """Copy the VisMF-v1 plotfile `src` to `dst` with one more component `name`, whose
    FAB values are values(lattice corners (N, 3), widths (N,)) of each FAB's cells."""
    shutil.copytree(src, dst)
    header = (dst / "Header").read_text().split("\n")
    ncomp = int(header[1])
    header[1] = str(ncomp + 1)
    header.insert(2 + ncomp, name)
    finest = int(header[ncomp + 5])
    (dst / "Header").write_text("\n".join(header))
    for L in range(finest + 1):
        width = 2 ** (finest - L)
        cell_h = (dst / f"Level_{L}" / "Cell_H").read_text().split("\n")
        assert cell_h[0] == "1" and int(cell_h[2]) == ncomp
        cell_h[2] = str(ncomp + 1)
        fods = [i for i, line in enumerate(cell_h) if line.startswith("FabOnDisk:")]
        old = (src / f"Level_{L}" / cell_h[fods[0]].split()[1]).read_bytes()
        new = bytearray()
        lo_hi = []
        for i in fods:
            _, fname, offset = cell_h[i].split()
            offset = int(offset)
            end = old.index(b"\n", offset) + 1
            line = old[offset:end].decode()
            box = [list(map(int, t.split(","))) for t in re.findall(r"\(([-\d,]+)\)", line)[-3:-1]]
            lo, hi = np.array(box[0]), np.array(box[1])
            n = int(np.prod(hi - lo + 1))
            cell_h[i] = f"FabOnDisk: {fname} {len(new)}"
            new += line.rsplit(" ", 1)[0].encode() + f" {ncomp + 1}\n".encode()
            new += old[end:end + 8 * n * ncomp]
            z, y, x = np.meshgrid(*(np.arange(lo[a], hi[a] + 1) for a in (2, 1, 0)), indexing="ij")
            corner = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) * width
            v = values(corner, np.full(n, width))
            new += v.astype("<f8").tobytes()
            lo_hi.append((v.min(), v.max()))
        (dst / f"Level_{L}" / fname).write_bytes(bytes(new))
        # the per-FAB minima and maxima that follow: one more column each
        rest, k = cell_h[fods[-1] + 1:], 0
        for s in (0, 1):
            while not rest[k]:
                k += 1
            assert rest[k] == f"{len(fods)},{ncomp}"
            rest[k] = f"{len(fods)},{ncomp + 1}"
            for b in range(len(fods)):
                rest[k + 1 + b] += f"{lo_hi[b][s]:.17e},"
            k += 1 + len(fods)
        (dst / f"Level_{L}" / "Cell_H").write_text("\n".join(cell_h[:fods[-1] + 1] + rest))
    return dst


@pytest.fixture(scope="module")
def eb_plotfile(tmp_path_factory):
    """The AMReX advection plotfile with a volFrac component: a sphere of volFrac 0."""
    return add_component(AMREX, tmp_path_factory.mktemp("eb") / "plt", "volFrac", _volfrac)


def test_eb_body_of_a_real_plotfile_becomes_holes(tmp_path, eb_plotfile):
    from exabricks.readers import amrex

    original = amrex.read(AMREX)
    vf = _volfrac(original.lower_lattice, 1 << original.level.astype(np.int64))
    keep = vf != 0
    assert 0 < np.count_nonzero(~keep) < original.n_cells and np.any(vf == 0.5)
    out = tmp_path / "cells.npz"
    run_cli("ingest", eb_plotfile, "-o", out, check=0)
    cells = in_order_of(schema.load(out, "cells"), original.lower_lattice[keep], original.level[keep])
    assert cells.fields == ("phi", "volFrac")
    np.testing.assert_array_equal(cells.lower_lattice, original.lower_lattice[keep])
    np.testing.assert_array_equal(cells.level, original.level[keep])
    np.testing.assert_array_equal(cells.values[0], original.values[0][keep])
    np.testing.assert_array_equal(cells.values[1], vf[keep])
    assert cells.meta["parameters"]["mask"] == "volFrac" and cells.meta["parameters"]["mask_auto"]
    assert cells.meta["statistics"]["masked_cells"] == int(np.count_nonzero(~keep))
    # --no-mask: every cell, the body included; --field phi: still masked, volFrac not kept
    everything = ingest(eb_plotfile, auto_mask=False)
    assert everything.n_cells == LEAF_COUNTS["amrex"]
    np.testing.assert_array_equal(everything.values[1], vf)
    phi = ingest(eb_plotfile, fields=["phi"])
    assert phi.fields == ("phi",) and phi.n_cells == int(keep.sum())
    np.testing.assert_array_equal(phi.values[0], original.values[0][keep])


# ---------------------------------------------------------------------------
# sizes claimed by headers are checked against the files before anything is allocated


RESOURCE_TIMEOUT = 60  # s; the claims below would take minutes and gigabytes if trusted


@pytest.fixture
def run_cli_limited(monkeypatch):
    """conftest's run_cli with a wall-clock limit (a hang fails the test) and a 4 GiB
    address-space limit (an allocation of what a header claims fails instead of swapping)."""
    import resource
    import subprocess

    real = subprocess.run

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    def run(*args, **kw):
        kw.setdefault("timeout", RESOURCE_TIMEOUT)
        kw.setdefault("preexec_fn", limit)
        return real(*args, **kw)

    monkeypatch.setattr(subprocess, "run", run)
    return run_cli


def write_plotfile(root, boxes, ratios, names=("a",), **options):
    rng = np.random.default_rng(1)
    root.parent.mkdir(parents=True, exist_ok=True)
    return amrex_plotfile.write_plotfile(
        root, boxes, ratios, list(names),
        lambda L, glo, ghi: rng.random((len(names), *(ghi - glo + 1)[::-1])), **options)


def _claim_1024_cubed(d, vismf=1):
    """A 24 KB plotfile whose headers claim one 1024^3 box (8 GiB of float64)."""
    p = d / "plt"
    write_plotfile(p, [[((0, 0, 0), (7, 7, 7))]], [], vismf=vismf)
    big = "(1023,1023,1023)"
    for f in (p / "Header", p / "Level_0" / "Cell_H"):
        f.write_text(f.read_text().replace("(7,7,7)", big))
    data = p / "Level_0" / "Cell_D_00000"
    raw = data.read_bytes().replace(b"(7,7,7)", big.encode())
    data.write_bytes(raw + bytes(24 * 1024 - len(raw)))
    return p, [p / "Level_0" / "Cell_H", "box 0", "claims 85899", data, "holds only 24576"]


def _edit_fod(p, level, box, offset):
    h = p / f"Level_{level}" / "Cell_H"
    lines = h.read_text().split("\n")
    fods = [i for i, line in enumerate(lines) if line.startswith("FabOnDisk:")]
    lines[fods[box]] = f"FabOnDisk: Cell_D_00000 {offset}"
    h.write_text("\n".join(lines))
    return h


def _small_plotfile(d, **options):
    return write_plotfile(d / "plt", [[((0, 0, 0), (3, 7, 7)), ((4, 0, 0), (7, 7, 7))],
                                      [((2, 2, 2), (9, 9, 9))]], [2], **options) and d / "plt"


def _res_amrex_box(d):
    return _claim_1024_cubed(d)


def _res_amrex_box_vismf2(d):
    p, needles = _claim_1024_cubed(d, vismf=2)
    return p, [*needles[:2], "claims 85899345", needles[3]]


def _res_amrex_offset_past_end(d):
    p = _small_plotfile(d)
    h = _edit_fod(p, 0, 1, 10**12)
    return p, [h, "box 1", "starts at byte 1000000000000", "Cell_D_00000 holds only"]


def _res_amrex_offsets_overlap(d):
    p = _small_plotfile(d, vismf=2)  # no FAB header lines: only the offsets tell
    h = _edit_fod(p, 0, 1, 0)
    return p, [h, "box 1 starts at byte 0", "inside the data of box 0"]


def _res_athena_block(d):
    import h5py

    d.mkdir()
    p = d / "huge.athdf"
    with h5py.File(p, "w") as f:
        for k, v in {"RootGridSize": [1024] * 3, "MeshBlockSize": [1024] * 3,
                     "RootGridX1": [0.0, 1.0, 1.0], "RootGridX2": [0.0, 1.0, 1.0],
                     "RootGridX3": [0.0, 1.0, 1.0], "VariableNames": [b"rho"],
                     "DatasetNames": [b"prim"], "NumVariables": [1]}.items():
            f.attrs[k] = np.array(v)
        f["Levels"] = np.zeros(1, np.int32)
        f["LogicalLocations"] = np.zeros((1, 3), np.int64)
        f.create_dataset("prim", shape=(1, 1, 1024, 1024, 1024), dtype="f4")  # nothing stored
    return p, [p, "dataset 'prim' of shape (1, 1, 1024, 1024, 1024)", "claims 4294967296 bytes",
               "the file holds only"]


def _res_athena_levels(d):
    p, _ = _res_athena_block(d)
    import h5py

    with h5py.File(p, "r+") as f:
        del f["Levels"], f["LogicalLocations"]
        f.create_dataset("Levels", shape=(10**9,), dtype="i4")
        f.create_dataset("LogicalLocations", shape=(10**9, 3), dtype="i8")
    return p, [p, "dataset 'Levels' of shape (1000000000,)", "claims 4000000000 bytes"]


def _res_exajet_scalars(d):
    """A sparse 16 GiB .cells file next to a 4-value .scalars: refused before reading."""
    d.mkdir()
    p = d / "big.cells"
    with open(p, "wb") as f:
        f.truncate(16 << 30)
    np.zeros(4, "<f4").tofile(d / "big.v.scalars")
    return p, [d / "big.v.scalars", "4 values for field 'v'", p, f"{1 << 30} cells"]


def _res_raw_dims_overflow(d):
    """--dims whose product wraps around int64 to 0 bytes must not match an empty file."""
    d.mkdir()
    p = d / "v.raw"
    p.write_bytes(b"")
    return [p, "--dims", 1 << 21, 1 << 21, 1 << 22], [p, "size 0 bytes", "73786976294838206464 bytes"]


RESOURCE_CASES = {n[len("_res_"):]: f for n, f in globals().items() if n.startswith("_res_")}


@pytest.mark.parametrize("case", sorted(RESOURCE_CASES))
def test_claimed_sizes_fail_fast(tmp_path, run_cli_limited, case):
    args, needles = RESOURCE_CASES[case](tmp_path / "in")
    args = args if isinstance(args, list) else [args]
    (tmp_path / "out").mkdir()
    t0 = time.perf_counter()
    proc = run_cli_limited("ingest", *args, "-o", tmp_path / "out" / "c.npz")
    assert_one_error_line(proc, *needles)
    assert list((tmp_path / "out").iterdir()) == []
    assert time.perf_counter() - t0 < RESOURCE_TIMEOUT


def test_claimed_box_fails_before_allocating(tmp_path):
    """The claim is refused from the header: what the refusal allocated is bounded, not
    the 8 GiB the box claims (numpy's allocations are traced by tracemalloc)."""
    import tracemalloc

    from exabricks.readers import amrex

    p, _ = _claim_1024_cubed(tmp_path)
    amrex.read(_small_plotfile(tmp_path / "warm"))  # imports and compiled code are loaded
    tracemalloc.start()
    try:
        with pytest.raises(ExabricksError, match="claims 85899"):
            ingest(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20, peak


# ---------------------------------------------------------------------------
# world frames: finite origin, finite, positive, normal spacing (one error line, no warnings)


def _header_line(p, index, text):
    lines = (p / "Header").read_text().split("\n")
    lines[index] = text
    (p / "Header").write_text("\n".join(lines))
    return p / "Header"


# Header lines of a 1-field plotfile: 6 prob_lo, 7 prob_hi, 11.. cell sizes per level.
AMREX_BAD_VALUES = {
    "prob_hi_inf": (7, "1.0 inf 1.0", ["prob_lo and prob_hi must be finite", "inf"]),
    "prob_hi_nan": (7, "1.0 1.0 nan", ["must be finite", "nan"]),
    "prob_lo_minus_inf": (6, "-inf 0 0", ["must be finite"]),
    "prob_hi_equal": (7, "1.0 0.0 1.0", ["prob_hi must exceed prob_lo"]),
    "prob_hi_below": (7, "1.0 1.0 -2.0", ["prob_hi must exceed prob_lo"]),
    "extent_overflow": (7, "1.7e308 1 1", ["axis x", "inf", "not a finite, positive, normal"]),
    "spacing_denormal": (7, "1e-307 1 1", ["axis x", "not a finite, positive, normal"]),
    "cell_size_zero": (11, "0.125 0 0.125", ["line 12", "level-0 cell size 0.0"]),
    "cell_size_negative": (12, "0.0625 -0.0625 0.0625", ["line 13", "level-1 cell size -0.0625"]),
    "cell_size_denormal": (11, "1e-310 0.125 0.125", ["level-0 cell size 1e-310"]),
    "cell_size_inf": (12, "inf 0.0625 0.0625", ["level-1 cell size inf"]),
}


@pytest.mark.parametrize("case", sorted(AMREX_BAD_VALUES))
def test_amrex_bad_world_values(tmp_path, case):
    index, text, needles = AMREX_BAD_VALUES[case]
    p = _small_plotfile(tmp_path)
    if case == "extent_overflow":
        _header_line(p, 6, "-1.7e308 0 0")
    header = _header_line(p, index, text)
    proc = run_cli("ingest", p, "-o", tmp_path / "c.npz")
    assert_one_error_line(proc, header, *needles)  # one line: no RuntimeWarning before it


ATHENA_BAD_VALUES = {
    "inf": ("RootGridX2", [-0.5, np.inf, 1.0], "min and max must be finite"),
    "nan": ("RootGridX3", [np.nan, 0.5, 1.0], "min and max must be finite"),
    "equal": ("RootGridX1", [0.5, 0.5, 1.0], "max must exceed min"),
    "denormal": ("RootGridX1", [0.0, 1e-306, 1.0], "not a finite, positive, normal"),
    "overflow": ("RootGridX1", [-1.7e308, 1.7e308, 1.0], "not a finite, positive, normal"),
}


@pytest.mark.parametrize("case", sorted(ATHENA_BAD_VALUES))
def test_athena_bad_world_values(tmp_path, case):
    import h5py

    name, value, needle = ATHENA_BAD_VALUES[case]
    p = tmp_path / "copy.athdf"
    shutil.copy(ATHENA, p)
    with h5py.File(p, "r+") as f:
        f.attrs[name] = np.array(value, np.float64)
    proc = run_cli("ingest", p, "-o", tmp_path / "c.npz")
    assert_one_error_line(proc, p, needle)


def test_values_beyond_float32_give_one_error_line(tmp_path):
    """float64 data beyond float32's range: inf, reported by --nan error with no warning."""
    p = tmp_path / "plt"
    amrex_plotfile.write_plotfile(p, [[((0, 0, 0), (7, 7, 7))]], [], ["a"],
                                  lambda L, lo, hi: np.full((1, 8, 8, 8), 1e300))
    proc = run_cli("ingest", p, "-o", tmp_path / "c.npz")
    assert_one_error_line(proc, p, "field 'a' is inf")
