"""The hostile cases of issue 65 (round 4) that are not the viewer's: outputs that
land on a source's own files, options that do nothing, tiny and huge numbers. Each
case was reproduced once on the landed code and is kept as a regression test: it
ends in success or one `error:` line with exit 1 (2 for usage), and nothing of
the source changes."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from exabricks.util.errors import ExabricksError
from exabricks.util.output import check_output

from helpers import AMREX, GERRIS, assert_one_error_line
from helpers.hostile import run


def digest(folder: Path) -> dict:
    """sha256 of every file under `folder` (or of the file itself), by name."""
    files = [folder] if folder.is_file() else sorted(p for p in folder.rglob("*") if p.is_file())
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


@pytest.fixture
def plotfile(tmp_path) -> Path:
    out = tmp_path / "plt00020"
    shutil.copytree(AMREX, out)
    return out


@pytest.fixture
def gerris(tmp_path) -> Path:
    """The plume's cells file with the scalars of T beside it, in a folder of its own."""
    folder = tmp_path / "plume"
    folder.mkdir()
    for name in (GERRIS.name, GERRIS.with_suffix(".T.scalars").name):
        shutil.copy(GERRIS.parent / name, folder / name)
    return folder / GERRIS.name


@pytest.fixture
def points(tmp_path) -> Path:
    out = tmp_path / "points.npy"
    np.save(out, np.zeros((2, 3)))
    return out


# ---------------------------------------------------------------------------
# 1-3. outputs that land inside a source, directly or through a link


@pytest.mark.parametrize("member", ["Header", "Level_0/Cell_D_00000", "Level_0/new.npy"])
def test_an_output_inside_a_plotfile_is_refused(plotfile, points, member):
    before = digest(plotfile)
    target = plotfile / member
    for proc in (run("probe", plotfile, "--points", points, "-o", target),
                 run("coarsen", plotfile, "--levels", "1", "-o", target)):
        assert_one_error_line(proc, "inside the input folder")
    assert digest(plotfile) == before


def test_an_output_onto_a_cells_files_scalars_is_refused(gerris, points, tmp_path):
    scalars = gerris.with_suffix(".T.scalars")
    before = digest(gerris.parent)
    (tmp_path / "soft.npy").symlink_to(scalars)
    (tmp_path / "hard.npy").hardlink_to(scalars)
    for out in (scalars, tmp_path / "soft.npy", tmp_path / "hard.npy"):
        proc = run("probe", gerris, "--points", points, "-o", out)
        assert_one_error_line(proc, "would overwrite", "a file of the input")
    assert digest(gerris.parent) == before


def test_a_linked_image_into_a_source_is_refused(plotfile, gerris, tmp_path):
    before = digest(plotfile) | digest(gerris.parent)
    (tmp_path / "a.png").symlink_to(plotfile / "Level_0" / "Cell_D_00000")
    (tmp_path / "b.png").symlink_to(gerris.with_suffix(".T.scalars"))
    assert_one_error_line(run("render", plotfile, "--size", "8", "8", "-o", tmp_path / "a.png"),
                          "inside the input folder")
    assert_one_error_line(run("render", gerris, "--size", "8", "8", "-o", tmp_path / "b.png"),
                          "would overwrite")
    assert digest(plotfile) | digest(gerris.parent) == before


def test_a_link_inside_a_source_protects_what_it_names(plotfile, tmp_path):
    """A source folder whose file is a link to a file elsewhere: that file is the
    source's too."""
    outside = tmp_path / "elsewhere.png"
    data = plotfile / "Level_0" / "Cell_D_00000"
    shutil.move(data, outside)
    data.symlink_to(outside)
    with pytest.raises(ExabricksError, match="a file of the input"):
        check_output(outside, [plotfile])


def test_a_sources_own_picture_may_be_drawn_again(gerris):
    """Siblings of the kinds exabricks writes are not a source's files."""
    out = gerris.with_suffix(".png")
    out.write_bytes(b"an earlier picture")
    assert check_output(out, [gerris]) == out.resolve()


def test_scene_out_inside_a_source_is_refused(plotfile, gerris):
    before = digest(plotfile) | digest(gerris.parent)
    for source, out in ((plotfile, plotfile / "Header"),
                        (gerris, gerris.with_suffix(".T.scalars"))):
        proc = run("view", source, "--scene-out", out, "--port", "0", timeout=60)
        assert_one_error_line(proc, str(out))
    assert digest(plotfile) | digest(gerris.parent) == before


def test_the_viewers_save_refuses_a_sources_file(gerris):
    from exabricks.viewer.page import save_scene

    with pytest.raises(ExabricksError, match="would overwrite"):
        save_scene(gerris.with_suffix(".T.scalars"), {"a": 1}, [gerris])


def test_a_library_image_never_replaces_its_source(gerris, tmp_path):
    import exabricks as eb

    link = tmp_path / "frame.png"
    link.symlink_to(gerris.with_suffix(".T.scalars"))
    before = digest(gerris.parent)
    image = eb.render(eb.open(gerris, cache=False), field="T", size=(8, 8))
    with pytest.raises(ExabricksError, match="would overwrite"):
        image.save(link)
    assert digest(gerris.parent) == before


# ---------------------------------------------------------------------------
# 2, 4. a series' frames and movie


def test_steps_of_one_name_get_frames_of_their_own(gerris, tmp_path):
    from exabricks.series import frame_paths

    steps = [tmp_path / "run1" / "step.cells", tmp_path / "run2" / "step.cells"]
    frames = frame_paths(steps, tmp_path / "frames", ".png")
    assert [f.name for f in frames] == ["0000-step.cells.png", "0001-step.cells.png"]
    assert frame_paths(steps[:1], tmp_path, ".png")[0].name == "step.cells.png"


def test_series_frames_and_movie_never_replace_a_step(gerris, tmp_path):
    before = digest(gerris.parent)
    frames = tmp_path / "frames"
    frames.mkdir()
    (frames / f"{gerris.name}.png").symlink_to(gerris.with_suffix(".T.scalars"))
    proc = run("series", gerris, "-o", frames, "--size", "8", "8")
    assert_one_error_line(proc, "would overwrite")
    movie = tmp_path / "m.gif"
    movie.symlink_to(gerris.with_suffix(".T.scalars"))
    proc = run("series", gerris, "-o", tmp_path / "f2", "--size", "8", "8", "--movie", movie)
    assert_one_error_line(proc, "would overwrite")
    assert digest(gerris.parent) == before


# ---------------------------------------------------------------------------
# 5. options that would draw the same frame as without them


@pytest.mark.parametrize("args, flag", [
    (["--light", "1", "0", "0"], "--light"),
    (["--ambient", "0.3"], "--ambient"),
    (["--light-intensity", "2"], "--light-intensity"),
    (["--light-color", "1,0,0"], "--light-color"),
    (["--integrator", "shadow", "--bounces", "2"], "--bounces"),
    (["--integrator", "shadow", "--anisotropy", "0.5"], "--anisotropy"),
    (["--integrator", "shadow", "--shading", "none"], "--shading"),
    (["--integrator", "path", "--max-opacity", "0.5"], "--max-opacity"),
    (["--integrator", "path", "--no-jitter"], "--no-jitter"),
    (["--integrator", "shadow", "--gradient", "central"], "--gradient"),
    (["--shading", "none", "--gradient", "central"], "--gradient"),
    (["--specular", "0.5"], "--specular"),
    (["--ao-samples", "4"], "--ao-samples"),
])
def test_an_option_that_does_not_act_is_refused(tmp_path, args, flag):
    out = tmp_path / "x.png"
    proc = run("render", GERRIS, "--size", "8", "8", *args, "-o", out)
    assert_one_error_line(proc, flag, "does not apply")
    assert not out.exists()


def test_the_option_table_says_where_each_option_acts():
    from exabricks.scene.applies import CONDITIONS
    from exabricks.scene.options import SCENE_OPTIONS

    given = {o.name: o.applies for o in SCENE_OPTIONS if o.applies}
    assert set(given) >= {"light", "ambient", "light_intensity", "light_color", "bounces",
                          "anisotropy", "shading", "max_opacity", "jitter", "gradient",
                          "specular"}
    assert all(name in CONDITIONS for names in given.values() for name in names)


def test_the_same_options_act_where_they_apply(tmp_path):
    """Where each condition holds, the option changes the frame."""
    import exabricks as eb

    ds = eb.open(GERRIS, cache=False)
    base = dict(field="T", size=(16, 16), seed=1)
    for extra, option in ((dict(integrator="shadow"), dict(light=(1, 0, 0))),
                          (dict(integrator="path", spp=2), dict(anisotropy=0.8)),
                          (dict(iso=0.45), dict(specular=1.0))):
        a = eb.render(ds, **base, **extra).rgba
        b = eb.render(ds, **base, **extra, **option).rgba
        assert np.abs(a - b).max() > 1e-3, option


# ---------------------------------------------------------------------------
# 6. directions of any magnitude


def test_unit_vectors_of_tiny_and_huge_directions():
    from exabricks.util.vectors import unit

    for v in ([1e-300, 0, 0], [1e300, 0, 0], [1e200, 1e200, 0], [5e-324, 5e-324, 0], [3, 4, 0]):
        u = unit(v)
        assert np.isfinite(u).all() and abs(np.dot(u, u) - 1) < 1e-15
        np.testing.assert_allclose(u, np.asarray(v) / np.max(np.abs(v)) / np.linalg.norm(
            np.asarray(v) / np.max(np.abs(v))), rtol=1e-15)
    with pytest.raises(ExabricksError):
        unit([0, 0, 0])


def test_a_tiny_light_direction_is_the_light_of_its_unit_vector():
    import exabricks as eb

    ds = eb.open(GERRIS, cache=False)
    base = dict(field="T", size=(16, 16), seed=1)
    for integrator in ("shadow", "path"):
        want = eb.render(ds, **base, integrator=integrator, light=(1, 0, 0)).rgba
        for tiny in (1e-200, 1e-300):
            got = eb.render(ds, **base, integrator=integrator, light=(tiny, 0, 0)).rgba
            np.testing.assert_array_equal(got, want)


def test_huge_normals_and_axes_draw_the_frames_of_their_unit_vectors():
    import exabricks as eb

    ds = eb.open(GERRIS, cache=False)
    (lo, hi) = ds.bounds
    mid = [(a + b) / 2 for a, b in zip(lo, hi)]

    def frame(normal, axis):
        scene = {"slices": [{"point": mid, "normal": normal, "field": "T", "opacity": 0.5}],
                 "clip": {"planes": [[*mid, *normal]]},
                 "instances": [{"rotate": [*axis, 30]}]}
        return eb.render(ds, scene, field="T", size=(16, 16), seed=1).rgba

    want = frame([1, 0, 0], [1, 0, 0])
    for normal, axis in (([1e300, 0, 0], [1e300, 0, 0]), ([1e160, 0, 0], [1e-300, 0, 0])):
        np.testing.assert_array_equal(frame(normal, axis), want)
    np.testing.assert_array_equal(frame([1e200, 1e200, 0], [1, 0, 0]),
                                  frame([1, 1, 0], [1, 0, 0]))


# ---------------------------------------------------------------------------
# 8, 9. lights, exposures and fields at float32's limit


@pytest.mark.parametrize("args", [
    ["--integrator", "shadow", "--light-intensity", "3e38"],
    ["--integrator", "shadow", "--ambient", "3e38"],
    ["--integrator", "path", "--ambient", "3e38"],
    ["--integrator", "shadow", "--light-intensity", "1e36", "--exposure", "24"],
])
def test_lights_that_overflow_are_refused_before_the_frame(tmp_path, args):
    out = tmp_path / "x.png"
    proc = run("render", GERRIS, "--size", "8", "8", *args, "-o", out)
    assert_one_error_line(proc, "--exposure", "beyond")
    assert "non-finite" not in proc.stderr and not out.exists()


@pytest.mark.parametrize("value", [3e38, -3e38])
def test_a_constant_field_at_float32s_limit_is_drawn(tmp_path, value):
    raw = tmp_path / "c.raw"
    np.full((8, 8, 8), value, np.float32).tofile(raw)
    proc = run("render", raw, "--dims", "8", "8", "8", "--size", "16", "16", "-o", tmp_path / "c.png")
    assert proc.returncode == 0, proc.stderr


# ---------------------------------------------------------------------------
# 7. fields of very small and very large values


@pytest.fixture(scope="module")
def blob_volumes(tmp_path_factory):
    """A smooth blob as raw volumes, times 1 and times tiny and huge factors
    (stored in float32, so 1e-39 is subnormal on disk already)."""
    folder = tmp_path_factory.mktemp("magnitudes")
    x = np.linspace(-1, 1, 24)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    blob = np.exp(-4 * (X ** 2 + Y ** 2 + Z ** 2)) + 0.01
    out = {}
    for k in (1.0, 1e-36, 1e-37, 1e-39, 1e30, 3e38 / 1.02):
        out[k] = folder / f"v{k:g}.raw"
        (blob * k).astype(np.float32).tofile(out[k])
    return out


@pytest.mark.parametrize("k", [1e-36, 1e-37, 1e-39, 1e30, 3e38 / 1.02])
def test_a_scaled_field_draws_the_fields_picture(blob_volumes, k):
    import exabricks as eb

    def frame(factor, **options):
        ds = eb.open(blob_volumes[factor], dims=(24, 24, 24), cache=False)
        return eb.render(ds, size=(48, 48), jitter=False, **options).rgba

    # Stored in float32: 1e-39's values keep about 16 of their 24 bits.
    tolerance = 1e-4 if k < 1e-38 else 1e-5
    given = dict(colormap="viridis", scale="linear", opacity=(0, 0.5))
    want = frame(1.0, range=(0, 1), **given)
    got = frame(k, range=(0, k), **given)
    assert np.sqrt(np.mean((got - want) ** 2)) < tolerance
    want, got = frame(1.0), frame(k)  # the defaults: the same picture
    assert np.sqrt(np.mean((got - want) ** 2)) < 1e-3 and np.abs(got - want).max() < 0.02


@pytest.mark.parametrize("k", [1e-39, 1e30])
def test_a_scaled_field_probes_its_values(blob_volumes, k):
    import exabricks as eb

    points = np.random.default_rng(0).uniform(2, 20, (64, 3))
    want = eb.probe(eb.open(blob_volumes[1.0], dims=(24, 24, 24), cache=False), points)
    got = eb.probe(eb.open(blob_volumes[k], dims=(24, 24, 24), cache=False), points)
    np.testing.assert_allclose(got / k, want, rtol=1e-4 if k < 1e-38 else 1e-6)
