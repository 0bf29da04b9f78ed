"""`probe` against the independent float64 reconstruction of tests/reference.py.

Error measure: |probe - reference| / max |field value over all cells|, required
<= 1e-5 wherever the reference is finite; probe must be NaN exactly where the
reference is NaN (no cell's hat is positive). The device receives float32
world points, so the reference is evaluated at exactly those float32 points
(converted to lattice units in float64); with the power-of-two spacings of the
datasets the device's world -> lattice conversion is then exact or nearly so,
and what is measured is the reconstruction itself. Every test runs on every
OpenCL device present.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
import pytest

from exabricks import schema
from exabricks.readers import read
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.stages.probe import probe
from exabricks.builders.regions import build_regions

import reference
from helpers import AMREX, ATHENA, ENZO, GERRIS, assert_one_error_line, run_cli, device_param

TOLERANCE = 1e-5



# Dataset, file and the field probed (Enzo: a velocity component, whose values
# are all of one magnitude; its density spans six decades, which would make an
# error relative to the maximum meaningless in most of the volume).
DATASETS = {
    "gerris": (GERRIS, "T"),
    "amrex": (AMREX, "phi"),
    "athena": (ATHENA, "rho"),
    "enzo": (ENZO, "x-velocity"),
}


@dataclass(frozen=True)
class Dataset:
    name: str
    field: str
    cells: schema.Cells
    bricks: schema.Bricks
    regions: schema.Regions
    bvh: schema.Bvh

    @property
    def scale(self) -> float:
        """max |value| of the probed field over all cells (the error normalisation)."""
        return float(np.abs(self.cells.values[self.cells.field_index(self.field)]).max())


def build(name, cells, field) -> Dataset:
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    return Dataset(name, field, cells, bricks, regions, build_bvh(regions))


@functools.lru_cache(maxsize=2)
def load(name: str) -> Dataset:
    """A dataset read and built once, with an extra field "random" (uniform in [0, 1)).

    The random field makes every cell's value matter: the real fields are often
    constant where levels meet (refinement follows features), so a missing or
    wrongly weighted cell would go unnoticed there.
    """
    path, field = DATASETS[name]
    cells = read(path)
    noise = np.random.default_rng(sorted(DATASETS).index(name)).random(cells.n_cells)
    cells = cells.replace(fields=(*cells.fields, "random"),
                          values=np.vstack([cells.values, noise[None].astype(np.float32)]))
    return build(name, cells, field)


@functools.lru_cache(maxsize=2)
def level_boundary_pool(name: str) -> np.ndarray:
    """Lattice points (M, 3) of dataset `name` where hats of two or more levels are positive.

    Candidates: corners, edge midpoints and face centres of up to 20000
    coarser cells, some moved by a small dyadic offset (1/64 of the cell
    width) -- the places where a coarse cell meets finer ones.
    """
    rng = np.random.default_rng(2024)
    cells = load(name).cells
    coarse = np.flatnonzero(cells.level > cells.level.min())
    pick = rng.choice(coarse, size=min(coarse.size, 20000), replace=False)
    width = np.ldexp(1.0, cells.level[pick].astype(np.int32))[:, None, None]
    grid = np.array([[i, j, k] for i in (0, 0.5, 1) for j in (0, 0.5, 1)
                     for k in (0, 0.5, 1) if (i, j, k) != (0.5, 0.5, 0.5)])
    points = cells.lower_lattice[pick][:, None, :] + width * grid[None]
    offset = rng.choice([-1.0, 0.0, 0.0, 1.0], size=points.shape) * width / 64
    points = (points + offset).reshape(-1, 3)
    return points[reference.contributing_levels(cells, points) >= 2]


@pytest.fixture(scope="module", params=[(name, which) for name in DATASETS
                                        for which in ("data", "random")],
                ids=lambda p: f"{p[0]}-{p[1]}")
def dataset(request) -> Dataset:
    """A real dataset and the field probed: its own ("data") or the random one."""
    name, which = request.param
    ds = load(name)
    return ds if which == "data" else dataclasses.replace(ds, field="random")


def compare(ds: Dataset, points_lattice, device) -> tuple[np.ndarray, np.ndarray]:
    """probe and reference at the float32 world points of `points_lattice`: (got, want)."""
    world32 = reference.to_world(ds.cells, points_lattice).astype(np.float32)
    got = probe(ds.bricks, ds.regions, ds.bvh, world32, field=ds.field, device=device)
    want = reference.reconstruct(ds.cells, reference.to_lattice(ds.cells, world32), ds.field)
    return got, want


def assert_matches(ds: Dataset, got, want) -> float:
    """NaN pattern equal and max relative error <= TOLERANCE; returns the error."""
    assert got.dtype == np.float32 and got.shape == want.shape
    nan_got, nan_want = np.isnan(got), np.isnan(want)
    bad = np.flatnonzero(nan_got != nan_want)
    assert bad.size == 0, (f"{ds.name}: {bad.size} points NaN in only one of probe/reference, "
                           f"e.g. index {bad[0]}: probe {got[bad[0]]}, reference {want[bad[0]]}")
    finite = ~nan_want
    error = float(np.max(np.abs(got[finite] - want[finite]), initial=0.0)) / ds.scale
    assert error <= TOLERANCE, f"{ds.name}: max relative error {error:.3g}"
    return error


def support_box(ds: Dataset):
    index = reference.cell_index(ds.cells)
    return index.support_lower, index.support_upper


# ---------------------------------------------------------------------------------------
# the reference itself


def brute_force(cells: schema.Cells, points_lattice, field) -> np.ndarray:
    """eq. 1-2 summed over every cell: float64 (N,), NaN where the weight sum is 0."""
    width = np.ldexp(1.0, cells.level.astype(np.int32))[:, None]
    centre = cells.lower_lattice + 0.5 * width
    values = cells.values[cells.field_index(field)].astype(np.float64)
    out = np.full(len(points_lattice), np.nan)
    for i, p in enumerate(points_lattice):
        h = np.prod(np.maximum(0.0, 1.0 - np.abs(centre - p) / width), axis=1)
        if h.sum() > 0:
            out[i] = h @ values / h.sum()
    return out


def test_reference_equals_brute_force_over_all_cells(dataset, rng):
    lo, hi = support_box(dataset)
    points = np.concatenate([rng.uniform(lo, hi, size=(24, 3)),
                             level_boundary_points(dataset, rng, 24),
                             support_edge_points(dataset, rng, 16)])
    want = brute_force(dataset.cells, points, dataset.field)
    got = reference.reconstruct(dataset.cells, points, dataset.field)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * dataset.scale)


def test_reference_sorted_key_lookup_equals_the_dense_tables(dataset, rng, monkeypatch):
    lo, hi = support_box(dataset)
    points = np.concatenate([rng.uniform(lo, hi, size=(2000, 3)),
                             level_boundary_points(dataset, rng, 500)])
    values = reference.field_values(dataset.cells, dataset.field)
    dense = reference.CellIndex(dataset.cells)
    monkeypatch.setattr(reference, "DENSE_TABLE_LIMIT", 0)
    sparse = reference.CellIndex(dataset.cells)
    assert all(level.table is None for level in sparse.levels)
    np.testing.assert_array_equal(sparse.reconstruct(points, values),
                                  dense.reconstruct(points, values))


# ---------------------------------------------------------------------------------------
# point sets


def level_boundary_points(ds: Dataset, rng, n: int) -> np.ndarray:
    """n lattice points drawn from `level_boundary_pool`."""
    pool = level_boundary_pool(ds.name)
    assert pool.shape[0] >= n, f"{ds.name}: only {pool.shape[0]} level-boundary points"
    return pool[rng.choice(pool.shape[0], size=n, replace=False)]


def support_edge_points(ds: Dataset, rng, n: int) -> np.ndarray:
    """n lattice points on or just beside the boundary of some cell's support.

    The support of a cell is its box grown by w/2; points exactly on, and 2**-10 w
    inside or outside, a support corner of random cells. On the data's outer
    boundary these are where the field starts to be NaN.
    """
    cells = ds.cells
    pick = rng.choice(cells.n_cells, size=n)
    width = np.ldexp(1.0, cells.level[pick].astype(np.int32))[:, None]
    corner = rng.integers(0, 2, size=(n, 3)) * 2.0 - 0.5       # -1/2 or 3/2 of a width
    step = rng.choice([-1.0, 0.0, 1.0], size=(n, 3)) * 2.0 ** -10
    return cells.lower_lattice[pick] + width * (corner + step)


# ---------------------------------------------------------------------------------------
# real data


@device_param
def test_probe_random_points_match_the_reference(dataset, device, rng):
    lo, hi = support_box(dataset)
    margin = 0.05 * (hi - lo)
    inside = rng.uniform(lo - margin, hi + margin, size=(6000, 3))
    far = rng.uniform(-1, 1, size=(200, 3)) * 1e3 * (hi - lo)
    far += np.sign(far) * 2 * (hi - lo) + 0.5 * (lo + hi)       # well outside on every axis
    got, want = compare(dataset, np.concatenate([inside, far]), device)
    assert np.isfinite(want[:6000]).mean() > 0.5
    assert np.isnan(got[6000:]).all()
    assert_matches(dataset, got, want)


@device_param
def test_probe_at_level_boundaries_matches_the_reference(dataset, device, rng):
    points = level_boundary_points(dataset, rng, 3000)
    got, want = compare(dataset, points, device)
    assert np.isfinite(want).all()
    assert_matches(dataset, got, want)


@device_param
def test_probe_at_support_edges_is_nan_exactly_where_the_reference_is(dataset, device, rng):
    points = support_edge_points(dataset, rng, 3000)
    got, want = compare(dataset, points, device)
    assert 0 < np.isnan(want).sum() < want.size  # both outcomes occur
    assert_matches(dataset, got, want)


# ---------------------------------------------------------------------------------------
# linear fields are reproduced inside one level

LINEAR = np.array([0.75, -1.25, 0.5])  # df/dx, df/dy, df/dz per world unit
LINEAR_OFFSET = 3.0
ORIGIN = np.array([1.5, -2.0, 0.25])
SPACING = np.array([0.5, 0.25, 1.0])  # anisotropic: lattice -> world differs per axis


def box_cells(lower, upper, level) -> tuple[np.ndarray, np.ndarray]:
    """Lower corners (M, 3) and levels (M,) of the level-`level` cells tiling [lower, upper)."""
    w = 1 << level
    axes = [np.arange(lower[a], upper[a], w) for a in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    corners = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    return corners, np.full(len(corners), level)


def linear_cells(blocks) -> schema.Cells:
    """Cells of the blocks [(lower, upper, level)], valued by the linear field at their centres."""
    parts = [box_cells(*b) for b in blocks]
    lower = np.concatenate([p[0] for p in parts]).astype(np.int32)
    level = np.concatenate([p[1] for p in parts]).astype(np.int8)
    centre = lower + 0.5 * np.ldexp(1.0, level.astype(np.int32))[:, None]
    values = (ORIGIN + SPACING * centre) @ LINEAR + LINEAR_OFFSET
    return schema.Cells(fields=("f",), origin_world=ORIGIN, spacing_world=SPACING,
                        lower_lattice=lower, level=level, values=values[None].astype(np.float32))


def linear_exact(points_lattice) -> np.ndarray:
    return (ORIGIN + SPACING * points_lattice) @ LINEAR + LINEAR_OFFSET


def check_linear(ds: Dataset, points_lattice, device):
    want = linear_exact(points_lattice)
    # The reference reproduces the field too (to float32 rounding of the cell values).
    np.testing.assert_allclose(reference.reconstruct(ds.cells, points_lattice, "f"), want,
                               rtol=0, atol=1e-6 * ds.scale)
    world32 = reference.to_world(ds.cells, points_lattice).astype(np.float32)
    got = probe(ds.bricks, ds.regions, ds.bvh, world32, field="f", device=device)
    exact = linear_exact(reference.to_lattice(ds.cells, world32))
    error = np.max(np.abs(got - exact)) / ds.scale
    assert error <= TOLERANCE, error


@device_param
def test_linear_field_is_reproduced_inside_a_single_level(device, rng):
    # 12 x 10 x 8 cells of width 2 at a negative offset; exact inside the hull of
    # the cell centres (nearer the boundary only some hats exist).
    ds = build("linear", linear_cells([((-8, 2, 0), (16, 22, 16), 1)]), "f")
    points = rng.uniform([-7, 3, 1], [15, 21, 15], size=(4000, 3))
    check_linear(ds, points, device)


@device_param
def test_linear_field_is_reproduced_away_from_a_level_boundary(device, rng):
    # x < 8: cells of width 2, x >= 8: cells of width 1. Coarse hats reach x < 9
    # and fine ones x > 7.5, so [1, 7] (coarse centres' hull) and [9, 15.5] x
    # [0.5, 7.5]^2 (fine centres' hull) each see one level only.
    ds = build("linear2", linear_cells([((0, 0, 0), (8, 8, 8), 1),
                                        ((8, 0, 0), (16, 8, 8), 0)]), "f")
    coarse = rng.uniform([1, 1, 1], [7, 7, 7], size=(2000, 3))
    fine = rng.uniform([9, 0.5, 0.5], [15.5, 7.5, 7.5], size=(2000, 3))
    check_linear(ds, np.concatenate([coarse, fine]), device)
    assert (reference.contributing_levels(ds.cells, np.concatenate([coarse, fine])) == 1).all()


# ---------------------------------------------------------------------------------------
# command line


@pytest.fixture(scope="module")
def gerris_files(tmp_path_factory):
    ds = dataclasses.replace(load("gerris"), field="T")
    folder = tmp_path_factory.mktemp("gerris")
    paths = [folder / f"{kind}.npz" for kind in ("bricks", "regions", "bvh")]
    for path, obj in zip(paths, (ds.bricks, ds.regions, ds.bvh)):
        schema.save(path, obj)
    return ds, paths


@device_param
def test_cli_probe_writes_the_stage_values(gerris_files, device, tmp_path, rng):
    ds, paths = gerris_files
    lo, hi = support_box(ds)
    points_world = reference.to_world(ds.cells, rng.uniform(lo - 4, hi + 4, size=(2000, 3)))
    np.save(tmp_path / "points.npy", points_world)
    out = tmp_path / "values.npy"
    run_cli("probe", *paths, "--points", tmp_path / "points.npy", "--field", "T",
            "-o", out, "--device", device, check=0)
    values = np.load(out, allow_pickle=False)
    assert values.shape == (2000,) and values.dtype == np.float32
    stage = probe(ds.bricks, ds.regions, ds.bvh, points_world, field="T", device=device)
    np.testing.assert_array_equal(values, stage)
    want = reference.reconstruct(
        ds.cells, reference.to_lattice(ds.cells, points_world.astype(np.float32)), "T")
    assert_matches(ds, values, want)


@pytest.mark.parametrize("name, content", [
    ("flat.npy", lambda p: np.save(p, np.zeros(6))),
    ("two_columns.npy", lambda p: np.save(p, np.zeros((4, 2)))),
    ("text.npy", lambda p: p.write_text("1 2 3\n")),
    ("points.txt", lambda p: p.write_text("1 2 3\n")),
])
def test_cli_probe_refuses_bad_points_files(gerris_files, tmp_path, name, content):
    _, paths = gerris_files
    points = tmp_path / name
    content(points)
    out = tmp_path / "values.npy"
    proc = run_cli("probe", *paths, "--points", points, "-o", out)
    assert_one_error_line(proc, name)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [name]
