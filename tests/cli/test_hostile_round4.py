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
