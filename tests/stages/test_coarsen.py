"""`exabricks coarsen` and `stages.coarsen.coarsen_cells`: exact small cases, the
conservation of volume and volume integrals on real data, a reference on random
layouts, the CLI chain to a rendered image, and refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from exabricks import schema
from exabricks.util.constants import MAX_LEVEL
from exabricks.util.errors import ExabricksError
from exabricks.readers import read
from exabricks.stages.coarsen import coarsen_cells, coarsen_plotfile
from exabricks.builders.cells import validate_cells

from benchmarks import amrex_plotfile
from amr_strategies import amr_cells
from helpers import AMREX, GERRIS, assert_one_error_line, run_cli

OCTET = np.array([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.int32)


def make_cells(lower, level, values) -> schema.Cells:
    values = np.asarray(values, np.float32).reshape(-1, len(level))
    return schema.Cells(
        fields=tuple(f"f{i}" for i in range(values.shape[0])),
        origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.asarray(lower, np.int32).reshape(-1, 3),
        level=np.asarray(level, np.int8), values=values,
    )


def as_dict(cells: schema.Cells) -> dict:
    """{(i, j, k, level): tuple of field values} (order-free comparison)."""
    return {(*map(int, lo), int(lv)): tuple(cells.values[:, n].tolist())
            for n, (lo, lv) in enumerate(zip(cells.lower_lattice, cells.level))}


def volumes(cells: schema.Cells) -> np.ndarray:
    """float64 (N,) volume of each cell in finest-cell units, 8**level."""
    return np.exp2(3.0 * cells.level.astype(np.float64))


def integrals(cells: schema.Cells) -> tuple[np.ndarray, np.ndarray]:
    """float64 (F,) volume integral of each field and float64 (F,) of its magnitude."""
    v = cells.values.astype(np.float64)
    return (v * volumes(cells)).sum(axis=1), (np.abs(v) * volumes(cells)).sum(axis=1)


def check_conserved(fine: schema.Cells, coarse: schema.Cells) -> None:
    """Valid cells, same covered volume, same volume integrals.

    Each output value is a float64 mean rounded once to float32 (relative error at
    most 2**-24), so an integral moves by at most 2**-24 times the integral of |v|:
    1e-6 of it leaves ample room for float64 summation.  (Relative to the integral
    itself the bound would fail for fields whose positive and negative parts
    nearly cancel, like a velocity component.)
    """
    validate_cells(coarse, source="coarse", nan_policy="keep")
    assert coarse.fields == fine.fields
    assert volumes(coarse).sum() == volumes(fine).sum()
    before, magnitude = integrals(fine)
    after, _ = integrals(coarse)
    np.testing.assert_array_less(np.abs(after - before), 1e-6 * magnitude + 1e-300)


def reference_coarsen(cells: schema.Cells, levels: int) -> dict:
    """The rule of docs/coarsen.md written plainly over a dict (float64 means)."""
    leaves = {(*map(int, lo), int(lv)): cells.values[:, n].astype(np.float64)
              for n, (lo, lv) in enumerate(zip(cells.lower_lattice, cells.level))}
    finest = min(k[3] for k in leaves)
    for lv in range(finest, finest + levels):
        w = 1 << (lv + 1)
        groups: dict = {}
        for (i, j, k, l) in leaves:
            if l == lv:
                groups.setdefault((i // w * w, j // w * w, k // w * w), []).append((i, j, k, l))
        for parent, children in groups.items():
            if len(children) == 8:
                leaves[(*parent, lv + 1)] = np.mean([leaves.pop(c) for c in children], axis=0)
    return {key: tuple(v.astype(np.float32).tolist()) for key, v in leaves.items()}


# ---------------------------------------------------------------------------
# hand-built inputs with exact answers


def test_full_octet_merges_into_its_mean():
    cells = make_cells(OCTET + (2, 0, 0), [0] * 8, [np.arange(8), 10 * np.arange(8)])
    coarse = coarsen_cells(cells, levels=1)
    assert as_dict(coarse) == {(2, 0, 0, 1): (3.5, 35.0)}
    assert coarse.lower_lattice.dtype == np.int32 and coarse.level.dtype == np.int8
    assert coarse.values.dtype == np.float32
    stats = coarse.meta["statistics"]
    assert stats["cells_per_level_before"] == {"0": 8} and stats["cells_per_level_after"] == {"1": 1}
    assert coarse.meta["parameters"] == {"levels": 1, "finest_level": 0}


def test_octet_with_a_hole_stays():
    cells = make_cells(OCTET[:7], [0] * 7, np.arange(7))
    assert as_dict(coarsen_cells(cells, levels=3)) == as_dict(cells)


def test_two_levels_mixed():
    """A level-1 cell beside a full octet of level 0 and an incomplete one; then the
    level-1 cells merge at the second step when all 8 are present."""
    fine = OCTET  # level-0 octet in the level-1 cube at (0, 0, 0): merges
    coarse_sibs = [tuple(2 * o) for o in OCTET[1:]]  # the other 7 children of the level-2 cube
    lower = [*fine, *coarse_sibs]
    level = [0] * 8 + [1] * 7
    values = [*range(8), *[100.0 * (n + 1) for n in range(7)]]
    cells = make_cells(lower, level, values)
    one = coarsen_cells(cells, levels=1)
    assert as_dict(one) == {(0, 0, 0, 1): (3.5,), **{(*c, 1): (100.0 * (n + 1),)
                                                     for n, c in enumerate(coarse_sibs)}}
    two = coarsen_cells(cells, levels=2)  # a mean of means, in float64, rounded once
    assert as_dict(two) == {(0, 0, 0, 2): ((3.5 + 100 * 28) / 8,)}
    assert two.meta["statistics"]["merged_groups_per_level"] == {"0": 1, "1": 1}
    # drop one level-1 sibling: the level-1 group has a hole, only the first step merges
    holed = make_cells(lower[:-1], level[:-1], values[:-1])
    assert as_dict(coarsen_cells(holed, levels=2)) == {
        (0, 0, 0, 1): (3.5,), **{(*c, 1): (100.0 * (n + 1),) for n, c in enumerate(coarse_sibs[:-1])}}


def test_refined_child_blocks_the_group():
    """Seven level-1 siblings and one child refined into level-0 cells with a hole:
    the level-0 cells cannot merge, so neither can the level-1 group."""
    lower = [*OCTET[:7], *[tuple(2 * o) for o in OCTET[1:]]]
    cells = make_cells(lower, [0] * 7 + [1] * 7, np.arange(14))
    assert as_dict(coarsen_cells(cells, levels=2)) == as_dict(cells)


def test_negative_corners_and_finest_level_above_zero():
    """Parents are found by floor division (negative corners); levels count from the
    finest level present, here 2."""
    cells = make_cells(4 * OCTET - 8, [2] * 8, np.arange(8))
    coarse = coarsen_cells(cells, levels=1)
    assert as_dict(coarse) == {(-8, -8, -8, 3): (3.5,)}
    # straddling the aligned level-3 cubes: 8 cells, but not one parent's children
    shifted = make_cells(4 * OCTET - 4, [2] * 8, np.arange(8))
    assert as_dict(coarsen_cells(shifted, levels=1)) == as_dict(shifted)
    assert coarse.meta["parameters"]["finest_level"] == 2


def test_far_apart_octets():
    """Corners spanning more than 63 bits of parent keys (the three-key sort)."""
    far = np.int32(1 << 30)
    lower = [*(OCTET - far), *(OCTET + far - 2)]
    cells = make_cells(lower, [0] * 16, np.arange(16))
    assert as_dict(coarsen_cells(cells, levels=1)) == {
        (-far, -far, -far, 1): (3.5,), (far - 2, far - 2, far - 2, 1): (11.5,)}


def test_nan_propagates_per_field():
    values = np.ones((2, 8))
    values[1, 3] = np.nan
    coarse = coarsen_cells(make_cells(OCTET, [0] * 8, values), levels=1)
    assert coarse.values[0, 0] == 1.0 and np.isnan(coarse.values[1, 0])


def test_zero_levels_is_identity():
    cells = read(GERRIS)
    same = coarsen_cells(cells, levels=0)
    for name in ("lower_lattice", "level", "values"):
        np.testing.assert_array_equal(getattr(same, name), getattr(cells, name))
    s = same.meta["statistics"]
    assert s["cells_before"] == s["cells_after"] == cells.n_cells


def test_stage_refusals():
    cells = make_cells(OCTET, [0] * 8, np.arange(8))
    with pytest.raises(ExabricksError, match=">= 0"):
        coarsen_cells(cells, levels=-1)
    with pytest.raises(ExabricksError, match=f"above the largest level {MAX_LEVEL}"):
        coarsen_cells(cells, levels=MAX_LEVEL + 1)
    assert as_dict(coarsen_cells(cells, levels=MAX_LEVEL)) == {(0, 0, 0, 1): (3.5,)}
    high = make_cells([(0, 0, 0)], [MAX_LEVEL - 1], [1.0])
    with pytest.raises(ExabricksError, match=f"level {MAX_LEVEL + 1}"):
        coarsen_cells(high, levels=2)


# ---------------------------------------------------------------------------
# real data and random layouts


# Cells after coarsening (docs/coarsen.md): K = 1, 2, 3.
EXPECTED_CELLS = {"gerris": (14_792, 4_292, 1_464), "amrex": (176_128, 32_768, 4_096)}


@pytest.mark.parametrize("name, path", [("gerris", GERRIS), ("amrex", AMREX)])
def test_real_data_conserved(name, path):
    cells = read(path)
    for k, expected in zip((1, 2, 3), EXPECTED_CELLS[name]):
        coarse = coarsen_cells(cells, levels=k)
        assert coarse.n_cells == expected
        check_conserved(cells, coarse)
        assert coarse.meta["statistics"]["cells_after"] == expected
        assert int(coarse.level.min()) == int(cells.level.min()) + k  # no holes: all merged


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cells=amr_cells(max_cells=1500, max_level=4), levels=st.integers(0, 4))
def test_random_layouts_match_reference(cells, levels):
    coarse = coarsen_cells(cells, levels=levels)
    check_conserved(cells, coarse)
    assert as_dict(coarse) == reference_coarsen(cells, levels)


def sorted_cells(cells: schema.Cells):
    order = np.lexsort((*cells.lower_lattice.T, cells.level))
    return cells.lower_lattice[order], cells.level[order], cells.values[:, order]


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_plotfile_covered_data_equals_the_averages(levels):
    """plt00020 stores covered data averaged down from the finer levels: reading it
    gives the cells of coarsen_cells on the full read, values within float32 rounding."""
    from_file = coarsen_plotfile(AMREX, levels=levels)
    merged = coarsen_cells(read(AMREX), levels=levels)
    (lo_a, lv_a, v_a), (lo_b, lv_b, v_b) = sorted_cells(from_file), sorted_cells(merged)
    np.testing.assert_array_equal(lo_a, lo_b)
    np.testing.assert_array_equal(lv_a, lv_b)
    np.testing.assert_allclose(v_a, v_b, rtol=2.0**-22, atol=0)
    levels_read = {1: 2, 2: 1, 3: 1}[levels]
    assert from_file.meta["source"]["source"]["levels_read"] == levels_read
    assert from_file.meta["parameters"]["covered_level"] == {1: 1, 2: 2, 3: 2}[levels]
    assert from_file.meta["statistics"]["cells"] == merged.n_cells
    read_files = {entry["path"].split("/")[-2] for entry in from_file.meta["inputs"]}
    assert read_files == {"plt00020", *(f"Level_{L}" for L in range(levels_read))}


def _plotfile_with_marked_covered_data(root):
    """Level 0: one 8^3 box of 7.0; level 1 (ratio 4): one 8^3 box of random values
    covering the level-0 cells 0..1 per axis.  The covered level-0 cells hold 7.0,
    not the average of the fine cells, so a result shows which one it used."""
    rng = np.random.default_rng(3)

    def data(level, lo, hi):
        shape = (1, *(hi - lo + 1)[::-1])
        return np.full(shape, 7.0) if level == 0 else rng.random(shape)

    return amrex_plotfile.write_plotfile(root, [[((0, 0, 0), (7, 7, 7))],
                                                [((0, 0, 0), (7, 7, 7))]], [4], ["a"], data)


def test_plotfile_ratio_4_uses_covered_data_and_skips_the_fine_level(tmp_path):
    root = tmp_path / "plt"
    written = _plotfile_with_marked_covered_data(root)
    fine = written[1][0][2][0]  # (8, 8, 8), z y x
    # K = 1 falls between the AMReX levels (lattice levels 0 and 2): octets of the fine
    # level merge, their means replace the fine cells, and 7.0 appears only outside.
    one = coarsen_plotfile(root, levels=1)
    assert one.meta["parameters"]["covered_level"] == 0
    assert sorted(set(one.level.tolist())) == [1, 2]
    means = fine.reshape(4, 2, 4, 2, 4, 2).mean(axis=(1, 3, 5))
    at = one.level == 1
    got = {tuple(c // 2): v for c, v in zip(one.lower_lattice[at], one.values[0, at])}
    np.testing.assert_allclose([got[(x, y, z)] for z in range(4) for y in range(4)
                                for x in range(4)], means.ravel(), rtol=1e-6)
    assert np.all(one.values[0, ~at] == 7.0)
    # K = 2 is AMReX level 0: its stored values, covered ones included; level 1's data
    # is never read (a truncated Cell_D file would fail a full read).
    for f in (root / "Level_1").glob("Cell_D_*"):
        f.write_bytes(b"")
    two = coarsen_plotfile(root, levels=2)
    assert two.n_cells == 8**3 and np.all(two.level == 2) and np.all(two.values == 7.0)
    assert two.meta["source"]["source"]["levels_read"] == 1
    with pytest.raises(ExabricksError):
        coarsen_plotfile(root, levels=1)


# ---------------------------------------------------------------------------
# the command line


@pytest.mark.slow
def test_cli_chain_renders(tmp_path):
    """ingest -> coarsen --levels 2 -> brick -> regions -> bvh -> render."""
    p = {k: tmp_path / f"{k}.npz" for k in ("cells", "coarse", "bricks", "regions", "bvh")}
    run_cli("ingest", GERRIS, "-o", p["cells"], check=0)
    run_cli("coarsen", p["cells"], "--levels", "2", "-o", p["coarse"], check=0)
    coarse = schema.load(p["coarse"], "cells")
    assert coarse.n_cells == EXPECTED_CELLS["gerris"][1]
    assert coarse.meta["parameters"] == {"levels": 2, "finest_level": 0}
    assert coarse.meta["inputs"][0]["sha256"] == schema.sha256_file(p["cells"])
    check_conserved(schema.load(p["cells"], "cells"), coarse)
    run_cli("brick", p["coarse"], "-o", p["bricks"], check=0)
    run_cli("regions", p["bricks"], "-o", p["regions"], check=0)
    run_cli("bvh", p["regions"], "-o", p["bvh"], check=0)
    info = json.loads(run_cli("info", "--json", p["coarse"], check=0).stdout)
    assert info["kind"] == "cells"
    image = tmp_path / "image.exr"
    run_cli("render", p["bricks"], p["regions"], p["bvh"], "-o", image, "--size", "64", "64",
            "--field", "T", "--no-jitter", check=0)
    from exabricks.film.image_io import read_image

    rgba, _ = read_image(image)
    assert rgba.shape == (64, 64, 4) and rgba[..., 3].max() > 0.05


def test_cli_plotfile(tmp_path):
    out = tmp_path / "coarse.npz"
    run_cli("coarsen", AMREX, "--levels", "2", "--field", "phi", "-o", out, check=0)
    coarse = schema.load(out, "cells")
    assert coarse.fields == ("phi",) and coarse.n_cells == EXPECTED_CELLS["amrex"][1]
    assert coarse.meta["parameters"]["covered_level"] == 2
    assert_one_error_line(run_cli("coarsen", AMREX, "--levels", "1", "--field", "rho",
                                  "-o", out), "plt00020", "no field 'rho'")
    folder = tmp_path / "folder"
    folder.mkdir()
    assert_one_error_line(run_cli("coarsen", folder, "--levels", "1", "-o", out),
                          "not an AMReX plotfile")
    assert_one_error_line(run_cli("coarsen", folder, "--levels", "1", "-o", folder / "c.npz"),
                          "inside the input folder")
    proc = run_cli("coarsen", out, "--levels", "1", "--field", "phi", "-o", tmp_path / "x.npz")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


def test_cli_refusals(tmp_path):
    cells = tmp_path / "cells.npz"
    schema.save(cells, make_cells(OCTET, [0] * 8, np.arange(8)))
    out = tmp_path / "out.npz"
    proc = run_cli("coarsen", cells, "--levels", "-1", "-o", out)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    proc = run_cli("coarsen", cells, "-o", out)  # --levels is required
    assert proc.returncode == 2
    not_cells = tmp_path / "bricks.npz"
    run_cli("brick", cells, "-o", not_cells, check=0)
    assert_one_error_line(run_cli("coarsen", not_cells, "--levels", "1", "-o", out), "bricks.npz")
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file")
    assert_one_error_line(run_cli("coarsen", garbage, "--levels", "1", "-o", out), "garbage.npz")
    assert_one_error_line(run_cli("coarsen", cells, "--levels", "1", "-o", cells), "overwrite")
    assert_one_error_line(run_cli("coarsen", cells, "--levels", str(MAX_LEVEL + 1), "-o", out),
                          "cells.npz", "above the largest level")
    assert not out.exists()
    assert sorted(f.name for f in tmp_path.iterdir()) == ["bricks.npz", "cells.npz", "garbage.npz"]
    run_cli("coarsen", cells, "--levels", "1", "-o", out, check=0)
    assert schema.load(out, "cells").n_cells == 1
