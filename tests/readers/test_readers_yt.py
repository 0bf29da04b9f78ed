"""Readers of block-structured AMR (AMReX, Athena++, anything via yt), checked cell by cell.

The reference is yt 4.4.3 walking its own grid hierarchy (grid.child_mask, LeftEdge,
Level, raw on-disk fields), a path independent of our readers and of ds.all_data().
Synthetic plotfiles written here cover what the real data does not: 32-bit and
big-endian reals, refinement ratio 4, ghost cells, VisMF headers without FAB lines.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from exabricks import schema
from exabricks.util.errors import ExabricksError
from exabricks.readers import _blocks, amrex, athena, yt_bridge
from exabricks.builders.cells import validate_cells

from helpers import AMREX, ATHENA, ENZO, LEAF_COUNTS


from benchmarks import amrex_plotfile


# ---------------------------------------------------------------------------
# helpers


def _sorted(lattice: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Permutation sorting cells by (z, y, x, level)."""
    return np.lexsort((level, lattice[:, 0], lattice[:, 1], lattice[:, 2]))


def yt_leaves(path, ftype: str, names) -> tuple[object, np.ndarray, np.ndarray, dict]:
    """(ds, lattice int64 (N, 3), exabricks level (N,), {name: float64 (N,)}) from yt's grids."""
    yt = pytest.importorskip("yt")
    from yt.config import ytcfg

    yt.set_log_level(40)
    ytcfg.set("yt", "suppress_stream_logging", True)
    ds = yt.load(str(path))
    finest = ds.index.get_smallest_dx().to("code_length").d
    left = ds.domain_left_edge.to("code_length").d
    top = ds.index.max_level
    lattice, level, values = [], [], {n: [] for n in names}
    for g in ds.index.grids:
        keep = g.child_mask
        ijk = np.argwhere(keep)  # (i, j, k) index order, same as g[field][keep]
        width = int(round(g.dds.to("code_length").d[0] / finest))
        corner = np.rint((g.LeftEdge.to("code_length").d - left) / finest).astype(np.int64)
        lattice.append(corner + ijk * width)
        level.append(np.full(len(ijk), top - g.Level))
        assert width == 2 ** (top - g.Level)
        for n in names:
            values[n].append(g[ftype, n].d[keep])
    return (ds, np.concatenate(lattice), np.concatenate(level),
            {n: np.concatenate(v) for n, v in values.items()})


def assert_same_cells(cells: schema.Cells, ref_lattice, ref_level, ref_values) -> None:
    """Same leaf set (lattice, level) and float32(yt value) == our value for every cell."""
    assert cells.n_cells == ref_level.shape[0]
    np.testing.assert_array_equal(np.bincount(cells.level), np.bincount(ref_level))
    a = _sorted(cells.lower_lattice, cells.level)
    b = _sorted(ref_lattice, ref_level)
    np.testing.assert_array_equal(cells.lower_lattice[a], ref_lattice[b])
    np.testing.assert_array_equal(cells.level[a], ref_level[b])
    for i, name in enumerate(cells.fields):
        np.testing.assert_array_equal(cells.values[i][a], ref_values[name][b].astype(np.float32),
                                      err_msg=name)


# ---------------------------------------------------------------------------
# _blocks: leaf masks against a brute-force dense paint


def test_leaf_mask_matches_dense_paint(rng):
    n = 40
    for _ in range(20):
        def boxes(k, size):
            lo = rng.integers(0, n - size, (k, 3))
            return lo, lo + rng.integers(0, size, (k, 3))
        lo, hi = boxes(int(rng.integers(1, 30)), 12)
        cover_lo, cover_hi = boxes(int(rng.integers(0, 30)), int(rng.integers(1, 25)))
        mask = _blocks.leaf_mask(lo, hi, cover_lo, cover_hi)
        dense = np.ones((n, n, n), bool)  # (x, y, z)
        for c0, c1 in zip(cover_lo, cover_hi):
            dense[c0[0]:c1[0] + 1, c0[1]:c1[1] + 1, c0[2]:c1[2] + 1] = False
        expect = np.concatenate([
            dense[l[0]:h[0] + 1, l[1]:h[1] + 1, l[2]:h[2] + 1].ravel(order="F")
            for l, h in zip(lo, hi)
        ])
        np.testing.assert_array_equal(mask, expect)
        lattice = _blocks.leaf_lattice(lo, hi, mask, np.array([0, 0, 0]), 4)
        cells = np.concatenate([  # every box's cells, x fastest (Fortran order)
            np.stack([g.ravel(order="F") for g in np.meshgrid(
                *(np.arange(l[a], h[a] + 1) for a in range(3)), indexing="ij")], axis=1)
            for l, h in zip(lo, hi)
        ])
        np.testing.assert_array_equal(lattice, 4 * cells[expect])


# ---------------------------------------------------------------------------
# AMReX


@pytest.fixture(scope="module")
def amrex_cells():
    return amrex.read(AMREX)


def test_amrex_matches_yt_cell_by_cell(amrex_cells):
    ds, lattice, level, values = yt_leaves(AMREX, "boxlib", ["phi"])
    assert amrex_cells.n_cells == LEAF_COUNTS["amrex"]
    assert amrex_cells.fields == ("phi",)
    assert_same_cells(amrex_cells, lattice, level, values)
    np.testing.assert_array_equal(amrex_cells.origin_world, ds.domain_left_edge.d)
    np.testing.assert_array_equal(amrex_cells.spacing_world,
                                  ds.index.get_smallest_dx().d * np.ones(3))
    assert amrex_cells.meta["source"]["format"] == "amrex"
    schema.validate(amrex_cells)


def test_amrex_field_selection(amrex_cells):
    again = amrex.read(AMREX, fields=["phi"])
    np.testing.assert_array_equal(again.values, amrex_cells.values)
    with pytest.raises(ExabricksError, match="no field 'rho'.*phi"):
        amrex.read(AMREX, fields=["rho"])
    with pytest.raises(ExabricksError, match="listed twice"):
        amrex.read(AMREX, fields=["phi", "phi"])


def write_plotfile(root: Path, boxes, ratios, names, rng, **options):
    """workflows/amrex_plotfile.write_plotfile with standard-normal data from `rng`."""
    return amrex_plotfile.write_plotfile(
        root, boxes, ratios, names,
        lambda L, glo, ghi: rng.standard_normal((len(names), *(ghi - glo + 1)[::-1])), **options)


def brute_force_leaves(written, ratios):
    """Leaves of a written plotfile by checking every cell against every finer box."""
    finest = len(written) - 1
    widths = [int(np.prod(ratios[L:])) for L in range(finest + 1)]
    lattice, level, values = [], [], []
    for L, entries in written.items():
        for lo, hi, data in entries:
            for k in range(lo[2], hi[2] + 1):
                for j in range(lo[1], hi[1] + 1):
                    for i in range(lo[0], hi[0] + 1):
                        fine_lo = np.array([i, j, k]) * widths[L]
                        covered = any(
                            np.all(fine_lo >= flo * widths[F]) and np.all(fine_lo <= fhi * widths[F]
                                                                         + widths[F] - 1)
                            for F in range(L + 1, finest + 1) for flo, fhi, _ in written[F]
                        )
                        if not covered:
                            lattice.append(fine_lo)
                            level.append(int(np.log2(widths[L])))
                            values.append(data[:, k - lo[2], j - lo[1], i - lo[0]])
    return np.array(lattice), np.array(level), np.array(values).T


_TWO_LEVEL = ([((0, 0, 0), (7, 7, 3)), ((0, 0, 4), (7, 7, 7))],
              [((2, 2, 2), (9, 5, 9)), ((10, 2, 2), (13, 9, 5))],
              [((8, 8, 8), (15, 15, 11)), ((40, 8, 20), (43, 15, 23))])


@pytest.mark.parametrize("real", ["<f8", ">f8", "<f4", ">f4"])
@pytest.mark.parametrize("vismf, ngrow", [(1, 0), (1, 2), (2, 0), (3, 1), (4, 0)])
def test_amrex_synthetic_formats(tmp_path, rng, real, vismf, ngrow):
    ratios = [2, 4]
    written = write_plotfile(tmp_path / "plt", _TWO_LEVEL, ratios, ["a", "b", "c"], rng,
                             real=real, ngrow=ngrow, vismf=vismf, prob_lo=(-1.0, 0.0, 2.0),
                             prob_hi=(1.0, 0.5, 6.0))
    cells = amrex.read(tmp_path / "plt", fields=["c", "a"])
    schema.validate(cells)
    lattice, level, values = brute_force_leaves(written, ratios)
    assert cells.fields == ("c", "a")
    ref = {"a": values[0].astype(np.dtype(real)), "c": values[2].astype(np.dtype(real))}
    assert_same_cells(cells, lattice, level, ref)
    assert set(np.unique(cells.level).tolist()) == {0, 2, 3}
    np.testing.assert_array_equal(cells.origin_world, [-1.0, 0.0, 2.0])
    np.testing.assert_array_equal(cells.spacing_world, [2.0 / 64, 0.5 / 64, 4.0 / 64])


def test_amrex_improper_nesting_never_overlaps(tmp_path, rng):
    """A level-2 box outside every level-1 box still hides the level-0 cell under it."""
    boxes = (_TWO_LEVEL[0], _TWO_LEVEL[1], [*_TWO_LEVEL[2], ((0, 0, 0), (3, 3, 3))])
    written = write_plotfile(tmp_path / "plt", boxes, [2, 4], ["a"], rng)
    cells = amrex.read(tmp_path / "plt")
    lattice, level, values = brute_force_leaves(written, [2, 4])
    assert_same_cells(cells, lattice, level, {"a": values[0]})
    # No overlap: the leaves fill the domain except the rest of that level-0 cell (a
    # hole of 8^3 - 4^3 finest cells, as nothing at level 1 is there to fill it).
    volume = (1 << (3 * cells.level.astype(np.int64))).sum()
    assert volume == 64**3 - (8**3 - 4**3)


def test_amrex_pure_python_matches_compiled(tmp_path, rng):
    """NUMBA_DISABLE_JIT=1 runs the leaf masking as plain Python: identical cells."""
    write_plotfile(tmp_path / "plt", _TWO_LEVEL, [2, 4], ["a"], rng, ngrow=1)
    script = ("import sys; from exabricks import schema; from exabricks.readers import amrex;"
              "schema.save(sys.argv[2], amrex.read(sys.argv[1]))")
    subprocess.run([sys.executable, "-c", script, tmp_path / "plt", tmp_path / "py.npz"],
                   check=True, env={**os.environ, "NUMBA_DISABLE_JIT": "1"})
    python = schema.load(tmp_path / "py.npz", "cells")
    compiled = amrex.read(tmp_path / "plt")
    for name in schema.Cells.SPECS:
        np.testing.assert_array_equal(getattr(python, name), getattr(compiled, name))


def test_amrex_synthetic_matches_yt(tmp_path, rng):
    """Our writer is a real plotfile: yt reads it to the same leaves (32-bit big-endian)."""
    write_plotfile(tmp_path / "plt", _TWO_LEVEL[:2], [2], ["a", "b"], rng, real=">f4")
    _, lattice, level, values = yt_leaves(tmp_path / "plt", "boxlib", ["a", "b"])
    assert_same_cells(amrex.read(tmp_path / "plt"), lattice, level, values)


def test_make_big_amrex_plotfile(tmp_path):
    """benchmarks/make_big.py --amrex (on 64^3, 8^3 boxes): a properly nested 3-level plotfile
    whose leaves tile the domain and hold the field averaged to their level."""
    from benchmarks import make_big

    n, box = 64, 8
    make_big.generate(tmp_path / "v.raw", n, 7)
    volume = np.fromfile(tmp_path / "v.raw", "<f4").reshape(n, n, n)  # (z, y, x)
    groups = volume.reshape(n // box, box, n // box, box, n // box, box)
    r2 = np.ptp(groups, axis=(1, 3, 5))
    t2 = float(np.quantile(r2, 0.85))
    boxes = make_big.write_amrex(volume, tmp_path / "plt", t1=t2, t2=t2, box=box)
    sizes = [len(b) for b in boxes]
    assert sizes[0] == (n // 4 // box) ** 3 and 0 < sizes[2] < (n // box) ** 3 and sizes[1] > 0
    for L, level_boxes in enumerate(boxes):
        for lo, hi in level_boxes:
            assert np.all(hi - lo + 1 == box) and lo.min() >= 0 and hi.max() < n >> (2 - L)
    # Proper nesting: a level-2 box grown by one level-1 cell lies inside level 1.
    painted = np.zeros((n // 2,) * 3, bool)  # (x, y, z) level-1 cells
    for lo, hi in boxes[1]:
        painted[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = True
    for lo, hi in boxes[2]:
        a, b = np.maximum(lo // 2 - 1, 0), np.minimum(hi // 2 + 1, n // 2 - 1)
        assert painted[a[0]:b[0] + 1, a[1]:b[1] + 1, a[2]:b[2] + 1].all()
    cells = amrex.read(tmp_path / "plt")
    validate_cells(cells, source="plt")  # no overlaps
    assert int((8 ** cells.level.astype(np.int64)).sum()) == n**3  # and no holes
    for level in range(3):  # exabricks level: 0 = voxels, 1 = means of 2^3, 2 = of 4^3
        w = 1 << level
        mean = volume.astype(np.float64).reshape(
            n // w, w, n // w, w, n // w, w).mean(axis=(1, 3, 5))
        x, y, z = (cells.lower_lattice[cells.level == level] // w).T
        # float64 means rounded to float32; numpy may sum the w^3 voxels in another order
        # than the writer did, which can move the rounding by one float32 ulp (1.2e-7).
        np.testing.assert_allclose(cells.values[0, cells.level == level],
                                   mean[z, y, x].astype(np.float32), rtol=1.2e-7, atol=0)


def _copy_amrex(tmp_path) -> Path:
    dest = tmp_path / "plt"
    shutil.copytree(AMREX, dest)
    return dest


def test_amrex_truncated_cell_d(tmp_path):
    p = _copy_amrex(tmp_path)
    data = p / "Level_2" / "Cell_D_00000"
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    # caught by the size check of every FAB before anything is allocated
    with pytest.raises(ExabricksError, match=r"Level_2/Cell_H: box \d+ .* claims \d+ bytes "
                                             r"from byte \d+ but .*Cell_D_00000 holds only \d+"):
        amrex.read(p)


def test_amrex_missing_cell_h(tmp_path):
    p = _copy_amrex(tmp_path)
    (p / "Level_1" / "Cell_H").unlink()
    with pytest.raises(ExabricksError, match=r"Level_1/Cell_H: missing"):
        amrex.read(p)


def test_amrex_missing_cell_d(tmp_path):
    p = _copy_amrex(tmp_path)
    (p / "Level_0" / "Cell_D_00000").unlink()
    with pytest.raises(ExabricksError, match=r"Level_0/Cell_D_00000: missing"):
        amrex.read(p)


def test_amrex_corrupt_fab_header(tmp_path):
    p = _copy_amrex(tmp_path)
    data = p / "Level_1" / "Cell_D_00000"
    raw = bytearray(data.read_bytes())
    raw[0:3] = b"BAF"
    data.write_bytes(bytes(raw))
    with pytest.raises(ExabricksError, match=r"Cell_D_00000: byte 0: no FAB header"):
        amrex.read(p)


def test_amrex_unknown_byte_order(tmp_path):
    p = _copy_amrex(tmp_path)
    data = p / "Level_0" / "Cell_D_00000"
    raw = data.read_bytes().replace(b"(8 7 6 5 4 3 2 1)", b"(2 1 4 3 6 5 8 7)", 1)
    data.write_bytes(raw)
    with pytest.raises(ExabricksError, match="neither big- nor little-endian"):
        amrex.read(p)


def test_amrex_truncated_and_missing_header(tmp_path):
    p = _copy_amrex(tmp_path)
    header = p / "Header"
    text = header.read_text().splitlines()
    header.write_text("\n".join(text[:12]) + "\n")
    with pytest.raises(ExabricksError, match=r"Header: ends early"):
        amrex.read(p)
    header.unlink()
    with pytest.raises(ExabricksError, match=r"not an AMReX plotfile \(no Header"):
        amrex.read(p)
    with pytest.raises(ExabricksError, match="not an AMReX plotfile directory"):
        amrex.read(tmp_path / "nothing")


def _with_ratio_line(tmp_path, line: str) -> Path:
    """A copy of the real plotfile whose Header ratio line (now "2 2 ") is `line`."""
    p = _copy_amrex(tmp_path)
    header = p / "Header"
    lines = header.read_text().split("\n")
    assert lines[8].split() == ["2", "2"]
    lines[8] = line
    header.write_text("\n".join(lines))
    return p


def test_amrex_ratio_line_with_the_finest_level_matches_yt(tmp_path, amrex_cells):
    """Embedded-boundary and PeleLMeX-family writers list a ratio for the finest level
    too (3 for 3 levels): the same cells as the original, and as yt reads them."""
    p = _with_ratio_line(tmp_path, "2 2 2 ")
    cells = amrex.read(p)
    for name in schema.Cells.SPECS:
        np.testing.assert_array_equal(getattr(cells, name), getattr(amrex_cells, name))
    ds, lattice, level, values = yt_leaves(p, "boxlib", ["phi"])
    assert list(ds.ref_factors) == [2, 2, 2]
    assert_same_cells(cells, lattice, level, values)


@pytest.mark.parametrize("line", ["2 2 4", "(2,2,2) (2,2,2)", "(2,2,2) (2,2,2) (4,4,4)"])
def test_amrex_ratio_line_forms(tmp_path, amrex_cells, line):
    """The extra finest-level ratio is ignored whatever it is; per-axis IntVects as well."""
    cells = amrex.read(_with_ratio_line(tmp_path, line))
    np.testing.assert_array_equal(cells.lower_lattice, amrex_cells.lower_lattice)
    np.testing.assert_array_equal(cells.level, amrex_cells.level)


@pytest.mark.parametrize("line, needle", [
    ("2", r"refinement ratios \(expected 2, or 3 with the finest level's, found 1\)"),
    ("2 2 2 2", "found 4"),
    ("(2,2,2)", "expected 2 or 3 IntVects"),
    ("(2,2,4) (2,2,2)", "anisotropic"),
    ("2 3 2", "ratio 3 is not a power of two"),
])
def test_amrex_bad_ratio_lines(tmp_path, line, needle):
    with pytest.raises(ExabricksError, match=r"plt/Header: .*" + needle):
        amrex.read(_with_ratio_line(tmp_path, line))


def test_amrex_non_power_of_two_ratio(tmp_path, rng):
    write_plotfile(tmp_path / "plt", _TWO_LEVEL[:2], [3], ["a"], rng)
    with pytest.raises(ExabricksError, match="ratio 3 is not a power of two"):
        amrex.read(tmp_path / "plt")


# ---------------------------------------------------------------------------
# Athena++


@pytest.fixture(scope="module")
def athena_cells():
    return athena.read(ATHENA)


def test_athena_matches_yt_cell_by_cell(athena_cells):
    names = ["rho", "press", "vel1", "vel2", "vel3"]
    ds, lattice, level, values = yt_leaves(ATHENA, "athena_pp", names)
    assert athena_cells.n_cells == LEAF_COUNTS["athena"]
    assert athena_cells.fields == tuple(names)
    assert_same_cells(athena_cells, lattice, level, values)
    np.testing.assert_array_equal(athena_cells.origin_world, ds.domain_left_edge.d)
    np.testing.assert_array_equal(athena_cells.spacing_world,
                                  ds.index.get_smallest_dx().d * np.ones(3))
    schema.validate(athena_cells)


def test_athena_field_selection(athena_cells):
    sub = athena.read(ATHENA, fields=["vel2", "rho"])
    assert sub.fields == ("vel2", "rho")
    np.testing.assert_array_equal(sub.values, athena_cells.values[[3, 0]])
    with pytest.raises(ExabricksError, match="no variable 'phi'"):
        athena.read(ATHENA, fields=["phi"])
    with pytest.raises(ExabricksError, match="listed twice"):
        athena.read(ATHENA, fields=["rho", "rho"])


def _edit_athena(tmp_path, edit) -> Path:
    p = tmp_path / "copy.athdf"
    shutil.copy(ATHENA, p)
    with h5py.File(p, "r+") as f:
        edit(f)
    return p


def test_athena_missing_dataset(tmp_path):
    p = _edit_athena(tmp_path, lambda f: f.__delitem__("prim"))
    with pytest.raises(ExabricksError, match=r"copy.athdf: dataset 'prim' is missing"):
        athena.read(p)
    p = _edit_athena(tmp_path, lambda f: f.__delitem__("LogicalLocations"))
    with pytest.raises(ExabricksError, match="'LogicalLocations' is missing"):
        athena.read(p)


def test_athena_not_hdf5_and_truncated(tmp_path):
    p = tmp_path / "text.athdf"
    p.write_text("not an HDF5 file\n")
    with pytest.raises(ExabricksError, match=r"text.athdf: not a readable HDF5 file"):
        athena.read(p)
    p = tmp_path / "cut.athdf"
    p.write_bytes(ATHENA.read_bytes()[: ATHENA.stat().st_size // 2])
    with pytest.raises(ExabricksError, match=r"cut.athdf"):
        athena.read(p)
    with pytest.raises(ExabricksError, match="no such file"):
        athena.read(tmp_path / "absent.athdf")


def test_athena_overlapping_blocks(tmp_path):
    def nest(f):  # move a finest block onto the children of its level-1 ancestor
        levels, loc = f["Levels"][()], f["LogicalLocations"][()]
        fine = int(np.flatnonzero(levels == levels.max())[0])
        coarse = int(np.flatnonzero(levels == levels.max() - 1)[0])
        loc[fine] = loc[coarse] * 2
        f["LogicalLocations"][...] = loc
    with pytest.raises(ExabricksError, match="mesh blocks overlap"):
        athena.read(_edit_athena(tmp_path, nest))

    def twice(f):
        loc = f["LogicalLocations"][()]
        levels = f["Levels"][()]
        same = np.flatnonzero(levels == levels[0])
        loc[same[1]] = loc[same[0]]
        f["LogicalLocations"][...] = loc
    with pytest.raises(ExabricksError, match="appears twice"):
        athena.read(_edit_athena(tmp_path, twice))


def test_athena_non_uniform_mesh(tmp_path):
    def stretch(f):
        f.attrs["RootGridX1"] = np.array([-0.5, 0.5, 1.05])
    with pytest.raises(ExabricksError, match="non-uniform mesh.*x1rat"):
        athena.read(_edit_athena(tmp_path, stretch))


def test_athena_faces_must_match_locations(tmp_path):
    def shift(f):
        x = f["x1f"][()]
        x[7] += 0.125
        f["x1f"][...] = x
    with pytest.raises(ExabricksError, match="block 7: x1f faces"):
        athena.read(_edit_athena(tmp_path, shift))


# ---------------------------------------------------------------------------
# yt bridge


def test_yt_bridge_enzo_matches_yt_grids():
    pytest.importorskip("yt")
    cells = yt_bridge.read(ENZO)
    names = list(cells.fields)
    assert names == ["Dark_Matter_Density", "Density", "Temperature", "TotalEnergy",
                     "x-velocity", "y-velocity", "z-velocity"]
    ds, lattice, level, values = yt_leaves(ENZO, "enzo", names)
    assert cells.n_cells == LEAF_COUNTS["enzo"]
    assert np.unique(cells.level).tolist() == list(range(8))
    assert_same_cells(cells, lattice, level, values)
    np.testing.assert_array_equal(cells.origin_world, ds.domain_left_edge.d)
    np.testing.assert_array_equal(cells.spacing_world, ds.index.get_smallest_dx().d * np.ones(3))
    schema.validate(cells)


def test_yt_bridge_agrees_with_native_amrex_reader(amrex_cells):
    pytest.importorskip("yt")
    cells = yt_bridge.read(AMREX, fields=["phi"])
    a = _sorted(cells.lower_lattice, cells.level)
    b = _sorted(amrex_cells.lower_lattice, amrex_cells.level)
    np.testing.assert_array_equal(cells.lower_lattice[a], amrex_cells.lower_lattice[b])
    np.testing.assert_array_equal(cells.values[:, a], amrex_cells.values[:, b])


def test_yt_bridge_is_quiet(capfd):
    pytest.importorskip("yt")
    yt_bridge.read(ENZO, fields=["Density"])
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_yt_bridge_errors(tmp_path, monkeypatch):
    pytest.importorskip("yt")
    with pytest.raises(ExabricksError, match="no field 'rho'.*Density"):
        yt_bridge.read(ENZO, fields=["rho"])
    junk = tmp_path / "junk.dat"
    junk.write_text("nothing yt knows\n")
    with pytest.raises(ExabricksError, match=r"junk.dat: yt cannot load it"):
        yt_bridge.read(junk)
    with pytest.raises(ExabricksError, match="no such file"):
        yt_bridge.read(tmp_path / "absent")
    monkeypatch.setitem(__import__("sys").modules, "yt", None)
    with pytest.raises(ExabricksError, match=r"yt is not installed: pip install 'exabricks\[yt\]'"):
        yt_bridge.read(ENZO)


# ---------------------------------------------------------------------------
# fields yt derives, through the bridge (cells_from_dataset) and through ingest


@pytest.fixture(scope="module")
def enzo_ds():
    pytest.importorskip("yt")
    return yt_bridge.load(ENZO)


def test_yt_derived_fields_match_yt(enzo_ds):
    cells = yt_bridge.cells_from_dataset(
        enzo_ds, [("gas", "velocity_magnitude"), ("gas", "vorticity_magnitude"), ("enzo", "Density")])
    assert cells.fields == ("velocity_magnitude", "vorticity_magnitude", "Density")
    assert cells.meta["source"]["units"] == {"velocity_magnitude": "cm/s", "vorticity_magnitude": "1/s",
                                             "Density": "code_mass/code_length**3"}
    # |v| from the on-disk components in float64 (converted to cm/s by yt), cell by cell
    ad = enzo_ds.all_data()
    vx, vy, vz = (ad["enzo", f"{a}-velocity"].to("cm/s").d for a in "xyz")
    np.testing.assert_array_equal(cells.values[0], np.sqrt(vx * vx + vy * vy + vz * vz).astype(np.float32))
    # the vorticity (finite differences with ghost zones) as yt computes it on its own grids
    _, lattice, level, values = yt_leaves(ENZO, "gas", ["vorticity_magnitude"])
    a, b = _sorted(cells.lower_lattice, cells.level), _sorted(lattice, level)
    np.testing.assert_array_equal(cells.lower_lattice[a], lattice[b])
    reference = values["vorticity_magnitude"][b]
    assert np.count_nonzero(reference) > 0.9 * len(reference)
    np.testing.assert_array_equal(cells.values[1][a], reference.astype(np.float32))
    # and at a few cells, against the float64 values of ds.all_data()
    w = ad["gas", "vorticity_magnitude"].d
    for i in (0, 1000, len(w) // 2, len(w) - 1):
        assert cells.values[1][i] == np.float32(w[i])


def test_yt_derived_field_names(enzo_ds):
    cells = yt_bridge.cells_from_dataset(
        enzo_ds, [("gas", "density"), "Density", "gas:velocity_magnitude", ("gas", "x"), ("index", "x")])
    assert cells.fields == ("density", "Density", "gas:velocity_magnitude", "gas:x", "index:x")
    units = cells.meta["source"]["units"]
    assert units["gas:x"] == "cm" and units["index:x"] == "code_length"  # yt's units for each
    np.testing.assert_allclose(cells.values[3], cells.values[4] * enzo_ds.length_unit.to("cm").d,
                               rtol=1e-6)
    assert yt_bridge.field_names(enzo_ds, also=["gas:density", "gas:nope", "Density"])[-1] == "gas:density"


def test_yt_derived_field_errors(enzo_ds):
    with pytest.raises(ExabricksError, match=r"moving7_0010: no field \('gas', 'nope'\) on disk or "
                                             r"derived by yt \(on disk: Dark_Matter_Density, Density"):
        yt_bridge.cells_from_dataset(enzo_ds, [("gas", "nope")])
    with pytest.raises(ExabricksError, match=r"no field 'gas:nope' .*TYPE:NAME"):
        yt_bridge.cells_from_dataset(enzo_ds, ["gas:nope"])
    with pytest.raises(ExabricksError, match=r"field 'particle_mass': yt gives \(9233,\) values for "
                                             r"27077 cells, not one per cell"):
        yt_bridge.cells_from_dataset(enzo_ds, [("all", "particle_mass")])
    with pytest.raises(ExabricksError, match="field listed twice"):
        yt_bridge.cells_from_dataset(enzo_ds, ["Density", ("enzo", "Density")])


def test_ingest_derives_from_yt_fields(capfd):
    from exabricks.stages.ingest import ingest

    expression = "`gas:velocity_magnitude` / abs(`x-velocity`)"
    cells = ingest(ENZO, fields=["Density", "ratio"], derive=[("ratio", expression)])
    assert cells.fields == ("Density", "ratio")
    assert cells.meta["parameters"]["derive"] == {"ratio": expression}
    ref = yt_bridge.read(ENZO, fields=["gas:velocity_magnitude", "x-velocity", "Density"])
    speed, vx, density = ref.values.astype(np.float64)
    np.testing.assert_array_equal(cells.values[0], density.astype(np.float32))
    np.testing.assert_array_equal(cells.values[1], (speed / np.abs(vx)).astype(np.float32))
    # every field: the on-disk ones, then the derived one; the yt field it reads is not kept
    every = ingest(ENZO, derive=[("ratio", expression)])
    assert every.fields == (*yt_bridge.read(ENZO, fields=None).fields, "ratio")
    np.testing.assert_array_equal(every.values[-1], cells.values[1])
    out, err = capfd.readouterr()
    assert out == "" and err == ""
