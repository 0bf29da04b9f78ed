"""Time series on a fixed hierarchy: `exabricks values` and `render|probe --values`
(docs/time-series.md). A step drawn through the structures of another step of the
same cells equals a full rebuild of it: the structures array for array (random
layouts, and the Gerris plume with its cells in another order), and the image and
the probe pixel for pixel, in memory, under a memory budget and from Python."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from amr_strategies import amr_cells
from helpers import FUZZ_EXAMPLES, GERRIS, assert_one_error_line, build, run_cli
from exabricks import schema
from exabricks.util.errors import ExabricksError
from exabricks.builders.values import step_values, with_values


def another_step(cells: schema.Cells, rng, *, shuffle=True) -> schema.Cells:
    """The same leaf cells with other values (and, with `shuffle`, in another order,
    as a reader of another output may list them)."""
    n = cells.n_cells
    order = rng.permutation(n) if shuffle else np.arange(n)
    values = np.asarray(cells.values, np.float32) * np.float32(1.7) \
        + np.sin(np.arange(n, dtype=np.float32))[None, :] * np.float32(0.1)
    return cells.replace(lower_lattice=np.ascontiguousarray(cells.lower_lattice[order]),
                         level=np.ascontiguousarray(cells.level[order]),
                         values=np.ascontiguousarray(values[:, order]), meta={})


def assert_same_structures(a, b):
    for x, y in zip(a, b):
        assert type(x) is type(y)
        for name in x.SPECS:
            assert np.array_equal(getattr(x, name), getattr(y, name), equal_nan=True), (x.KIND, name)


def digested(obj):
    obj.meta["content_sha256"] = schema.content_sha256(obj)
    return obj


@settings(max_examples=FUZZ_EXAMPLES * 4, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cells=amr_cells(max_cells=1500), seed=st.integers(0, 2**32 - 1))
def test_a_step_on_the_structures_of_another_equals_its_rebuild(cells, seed):
    rng = np.random.default_rng(seed)
    first = build(cells)
    later = another_step(cells, rng)
    step = step_values(later, digested(first.bricks))
    step.meta["built_from"] = {"content_sha256": first.bricks.meta["content_sha256"]}
    rebuilt = build(later)
    assert_same_structures(with_values(first.bricks, first.regions, first.bvh, step),
                           (rebuilt.bricks, rebuilt.regions, rebuilt.bvh))


def test_cells_that_differ_are_named(rng):
    cells = build_gerris_cells()
    bricks = digested(build(cells).bricks)
    fewer = cells.replace(lower_lattice=cells.lower_lattice[1:], level=cells.level[1:],
                          values=cells.values[:, 1:])
    with pytest.raises(ExabricksError, match="67,711 leaf cells.*67,712"):
        step_values(fewer, bricks)
    moved = cells.replace(lower_lattice=cells.lower_lattice + (1 << int(cells.level.max())))
    with pytest.raises(ExabricksError, match=r"is not a cell of the bricks: the cells differ"):
        step_values(moved, bricks)
    with pytest.raises(ExabricksError, match="fields"):
        step_values(cells.replace(fields=("a", "b", "c", "d", "e")), bricks)


def build_gerris_cells():
    from exabricks.readers import read

    return read(GERRIS)


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    """Step 0 of the Gerris plume staged (cells, bricks, regions, bvh), and step 1
    (the same cells in another order with other values) as a cells file, its
    values file for step 0's bricks, and its own full rebuild."""
    from exabricks.readers import read
    from exabricks.structures import build as build_files

    d = tmp_path_factory.mktemp("series")
    first = read(GERRIS)
    for step, cells in (("0", first), ("1", another_step(first, np.random.default_rng(7)))):
        schema.save(d / f"c{step}.npz", cells)
        for name, obj in zip("brh", build_files(cells)):  # as the staged commands write them
            schema.save(d / f"{name}{step}.npz", obj)
    run_cli("values", d / "c1.npz", "--bricks", d / "b0.npz", "-o", d / "v1.npz", check=0)
    return d


def structures(d, step):
    return [d / f"b{step}.npz", d / f"r{step}.npz", d / f"h{step}.npz"]


VIEW = ("--field", "T", "--size", "96", "80", "--spp", "2", "--iso", "0.6", "--range", "0", "1.5")


def exr_pixels(path):
    from exabricks.film.image_io import read_image

    return read_image(path)[0]


@pytest.mark.slow
def test_render_with_values_equals_a_full_rebuild(series, tmp_path):
    d = series
    run_cli("render", *structures(d, 0), "--values", d / "v1.npz", "-o", tmp_path / "a.exr", *VIEW, check=0)
    run_cli("render", *structures(d, 1), "-o", tmp_path / "b.exr", *VIEW, check=0)
    run_cli("render", *structures(d, 0), "-o", tmp_path / "c.exr", *VIEW, check=0)
    a, b, c = (exr_pixels(tmp_path / f"{k}.exr") for k in "abc")
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)  # the step's values are drawn, not the bricks' own


@pytest.mark.slow
def test_a_budget_and_probe_with_values_equal_a_full_rebuild(series, tmp_path):
    d = series
    # a memory budget streams the values file's pages by domains (a volume; 3M: the
    # transfer function's table counts in the budget, budget_bytes.fixed_bytes)
    volume = [*VIEW[:7], "--range", "0", "1.5"]
    proc = run_cli("-v", "render", *structures(d, 0), "--values", d / "v1.npz", "-o", tmp_path / "m.exr",
                   *volume, "--memory-budget", "3M", check=0)
    assert int(re.search(r"(\d+) domain\(s\)", proc.stderr).group(1)) > 1
    run_cli("render", *structures(d, 1), "-o", tmp_path / "n.exr", *volume, check=0)
    assert np.allclose(exr_pixels(tmp_path / "m.exr"), exr_pixels(tmp_path / "n.exr"), atol=1e-6)
    points = np.random.default_rng(3).uniform(0, 128, (500, 3))
    np.save(tmp_path / "pts.npy", points)
    run_cli("probe", *structures(d, 0), "--values", d / "v1.npz", "--points", tmp_path / "pts.npy",
            "--field", "T", "-o", tmp_path / "p.npy", check=0)
    run_cli("probe", *structures(d, 1), "--points", tmp_path / "pts.npy", "--field", "T",
            "-o", tmp_path / "q.npy", check=0)
    assert np.array_equal(np.load(tmp_path / "p.npy"), np.load(tmp_path / "q.npy"), equal_nan=True)


def test_the_library_takes_a_values_file(series):
    import exabricks as eb

    d = series
    scene = {"size": [64, 48], "volumes": [{"field": "T", "transfer_function": "default", "range": [0, 1.5]}]}
    a = eb.render(eb.open(structures(d, 0), values=d / "v1.npz"), scene)
    b = eb.render(eb.open(structures(d, 1)), scene)
    assert np.array_equal(a.rgba, b.rgba)
    with pytest.raises(ExabricksError, match="three structure files"):
        eb.open(GERRIS, values=d / "v1.npz")


def test_values_refused_with_one_error_line(series, tmp_path):
    d = series
    # made for other bricks: step 1's own
    assert_one_error_line(run_cli("render", *structures(d, 1), "--values", d / "v1.npz", "-o",
                                  tmp_path / "x.png"), "v1.npz", "made for other bricks", "b1.npz")
    assert_one_error_line(run_cli("render", *structures(d, 0), "--values", d / "r0.npz", "-o",
                                  tmp_path / "x.png"), "r0.npz", "expected a values file")
    # cells that differ: a step of another hierarchy
    other = tmp_path / "other.npz"
    c = schema.load(d / "c0.npz")
    schema.save(other, c.replace(lower_lattice=c.lower_lattice[1:], level=c.level[1:],
                                 values=c.values[:, 1:]))
    assert_one_error_line(run_cli("values", other, "--bricks", d / "b0.npz", "-o", tmp_path / "v.npz"),
                          "other.npz", "the cells differ")
    assert_one_error_line(run_cli("values", d / "c1.npz", "--bricks", d / "r0.npz", "-o",
                                  tmp_path / "v.npz"), "r0.npz", "expected a bricks file")
    assert_one_error_line(run_cli("values", d / "c1.npz", "--bricks", d / "b0.npz", "-o",
                                  d / "c1.npz"), "overwrite the input")
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "v.npz").exists()
    proc = run_cli("render", d / "c1.npz", "--values", d / "v1.npz", "-o", tmp_path / "x.png")
    assert proc.returncode == 2 and "--values" in proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["data", "image"])
def test_values_under_mpi_equal_one_process(series, tmp_path, mode):
    """`mpiexec -n 2 render --values`: every rank takes the step's values (and its
    value ranges) on its share, as one process of the full rebuild draws them."""
    from helpers.mpi import mpirun, same_image

    d = series
    flags = ["--field", "T", "--size", "96", "80", "--spp", "2", "--range", "0", "1.5", "--max-opacity", "1",
             *(["--iso", "0.6"] if mode == "image" else [])]
    proc = mpirun(2, "render", *structures(d, 0), "--values", d / "v1.npz", "-o", tmp_path / "mpi.exr",
                  "--mpi-mode", mode, *flags)
    assert proc.returncode == 0, proc.stderr
    run_cli("render", *structures(d, 1), "-o", tmp_path / "one.exr", *flags, check=0)
    same_image(tmp_path / "mpi.exr", tmp_path / "one.exr", exact=mode == "image")
