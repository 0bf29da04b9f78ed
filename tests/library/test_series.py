"""Time series from Python (exabricks.series, issue 53 item 3): the steps of a
run in natural order, those on the first step's hierarchy as its values and the
others built through the cache, one colour range over the series, and frames
that `exabricks render STEP --scene scene.json` draws again pixel for pixel."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import exabricks as eb
from exabricks.describe import field_range as files_range
from exabricks.film.image_io import read_image

WORKFLOWS = Path(__file__).resolve().parents[2] / "workflows"


def _series(d: Path, *flags) -> Path:
    subprocess.run([sys.executable, WORKFLOWS / "make_series.py", d, "--steps", "3", "--size", "16",
                    *flags], check=True, capture_output=True)
    return d


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("series")
    return _series(d / "fixed", "--fixed-hierarchy"), _series(d / "moving"), d / "cache"


def test_steps_on_one_hierarchy_take_its_structures(runs):
    fixed, moving, cache = runs
    series = eb.open_series(str(fixed / "plt*"), cache=cache)
    assert [p.name for p in series.steps] == ["plt00000", "plt00010", "plt00020"]
    first, *rest = list(series)
    assert first.values is None and all(d.values is not None and d.paths == first.paths for d in rest)
    for step, dataset in zip(series.steps[1:], rest):  # equal to the step built on its own
        own = eb.open(step, cache=cache)
        np.testing.assert_array_equal(dataset.bricks.values, own.bricks.values)
        np.testing.assert_array_equal(dataset.structures()[1].value_range, own.structures()[1].value_range)
    assert series.field_range("phi") == pytest.approx(files_range(series.steps, "phi"), rel=1e-6)
    moved = eb.open_series([moving / "plt00000", moving / "plt00010"], cache=cache)
    assert [d.values for d in moved] == [None, None]  # other cells: its own structures
    assert moved[1].paths != moved[0].paths


def test_series_errors(runs, tmp_path):
    with pytest.raises(eb.ExabricksError, match="no steps match"):
        eb.open_series(str(tmp_path / "plt*"))
    with pytest.raises(eb.ExabricksError, match="at least one step"):
        eb.open_series([])
    (tmp_path / "file").write_text("")
    with pytest.raises(eb.ExabricksError, match="not a directory"):
        eb.render_series([runs[0] / "plt00000"], tmp_path / "file", size=(8, 8))


def test_a_step_without_the_first_steps_field_is_named(tmp_path):
    """A step whose plotfile holds another field: the step and the missing field are
    named, not --field (the flag of `exabricks values`), by the library and by
    `series`, with or without the drawn --field."""
    from helpers import assert_one_error_line, run_cli

    run = _series(tmp_path / "run", "--fixed-hierarchy")
    header = run / "plt00010" / "Header"
    lines = header.read_text().splitlines(keepends=True)
    assert lines[2] == "phi\n"
    header.write_text("".join([*lines[:2], "psi\n", *lines[3:]]))
    series = eb.open_series(str(run / "plt*"), cache=tmp_path / "cache")
    with pytest.raises(eb.ExabricksError, match=r"plt00010: no field 'phi' .*first step .*plt00000"):
        series[1]
    for drawn in ([], ["--field", "phi"]):
        proc = run_cli("series", run / "plt*", "-o", tmp_path / "frames", "--size", "8", "8",
                       "--cache", tmp_path / "cache", *drawn)
        assert_one_error_line(proc, "plt00010: no field 'phi'", "plt00000")
        assert "--field" not in proc.stderr


def test_series_into_a_dangling_link_makes_the_folder_it_names(tmp_path):
    """`series -o LINK`, a dangling symbolic link: followed as a link to an output
    file is (exabricks.util.output), not "internal error: FileExistsError"; a link
    to a folder it cannot make is one error line."""
    from helpers import GERRIS, assert_one_error_line, run_cli

    link = tmp_path / "frames"
    link.symlink_to("made")
    run_cli("series", GERRIS, "-o", link, "--size", "8", "8", check=0)
    assert (tmp_path / "made" / "plume7-1.cells.png").is_file() and link.is_symlink()
    (tmp_path / "file").write_text("")
    link.unlink()
    link.symlink_to("file/below")
    assert_one_error_line(run_cli("series", GERRIS, "-o", link, "--size", "8", "8"),
                          str(link), "cannot make the folder")


@pytest.mark.slow
def test_render_series_frames_are_the_command_lines(runs, tmp_path):
    fixed, _, cache = runs
    out = tmp_path / "frames"
    frames = eb.render_series(eb.open_series(str(fixed / "plt*"), cache=cache), out,
                              movie=tmp_path / "phi.gif", size=(48, 32))
    assert [f.name for f in frames] == ["plt00000.png", "plt00010.png", "plt00020.png"]
    lo, hi = files_range(sorted(fixed.glob("plt*")), "phi")
    for frame, step in zip(frames, sorted(fixed.glob("plt*"))):
        again = tmp_path / f"cli_{step.name}.png"
        subprocess.run([sys.executable, "-m", "exabricks.cli.main", "render", step, "--scene",
                        out / "scene.json", "-o", again, "--cache", cache], check=True)
        a, meta = read_image(frame)
        b, _ = read_image(again)
        np.testing.assert_array_equal(a, b)
        tf = meta["transfer_function"]
        xs = tf["RGBPoints"][::4]
        assert xs[0] == pytest.approx(lo, rel=1e-6) and xs[-1] == pytest.approx(hi, rel=1e-6)
    assert a.shape == (32, 48, 4) and (tmp_path / "phi.gif").stat().st_size > 0
    first = read_image(frames[0])[1]["camera"]
    assert all(read_image(f)[1]["camera"] == first for f in frames)
    command = tmp_path / "command"  # the series command draws the same frames
    subprocess.run([sys.executable, "-m", "exabricks.cli.main", "series", fixed / "plt*", "-o", command,
                    "--movie", command / "phi.mp4", "--size", "48", "32", "--cache", cache],
                   check=True)
    for frame in frames:
        np.testing.assert_array_equal(read_image(command / frame.name)[0], read_image(frame)[0])
    assert (command / "phi.mp4").stat().st_size > 0


@pytest.mark.slow
def test_the_default_series_shows_the_travelling_blob(runs, tmp_path):
    """docs/time-series.md's example as written (no scale, no range): every frame
    is brightest where the blob is (its centre projected by the frame's camera),
    not at the tails' corners, and one exposure serves every frame."""
    from exabricks.picture.camera import Camera
    from workflows.make_series import centre

    fixed, _, cache = runs
    frames = eb.render_series(eb.open_series(str(fixed / "plt*"), cache=cache), tmp_path / "f",
                              field="phi", size=(64, 48))
    scene = (tmp_path / "f" / "scene.json").read_text()
    assert '"auto_exposure": false' in scene
    for k, frame in enumerate(frames):
        rgba, meta = read_image(frame)
        camera = Camera.from_dict(meta["camera"])
        origin, forward, du, dv = camera.frame(64, 48)
        d = centre(k, 3) - origin
        x = ((d @ du) / (du @ du) / (d @ forward) + 1) * 32
        y = (1 - (d @ dv) / (dv @ dv) / (d @ forward)) * 24
        lum = rgba[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        row, col = np.unravel_index(np.argmax(lum), lum.shape)
        assert abs(col + 0.5 - x) <= 4 and abs(row + 0.5 - y) <= 4, (k, row, col, x, y)
        assert lum.max() > 0.5 and (lum > 0.05).mean() < 0.5
