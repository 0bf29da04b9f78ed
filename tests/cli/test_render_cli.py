"""`exabricks render` and `exabricks devices` through the command line: outputs and every refusal."""

from __future__ import annotations

import json

import numpy as np
import pytest

from exabricks.film.image_io import read_depth, read_image

from helpers import GERRIS, assert_one_error_line, run_cli


@pytest.fixture(scope="module")
def plume(tmp_path_factory):
    """The Gerris plume through ingest, brick, regions, bvh (paths)."""
    d = tmp_path_factory.mktemp("plume")
    run_cli("ingest", GERRIS, "-o", d / "cells.npz", check=0)
    run_cli("brick", d / "cells.npz", "-o", d / "bricks.npz", check=0)
    run_cli("regions", d / "bricks.npz", "-o", d / "regions.npz", check=0)
    run_cli("bvh", d / "regions.npz", "-o", d / "bvh.npz", check=0)
    return d


def scene(d):
    return [d / "bricks.npz", d / "regions.npz", d / "bvh.npz"]


SMALL = ["--size", "48", "32", "--field", "T"]


@pytest.mark.slow
def test_render_exr_png_and_metadata(plume, tmp_path):
    exr, png = tmp_path / "a.exr", tmp_path / "a.png"
    fixed = (*SMALL, "--no-auto-exposure")  # the radiance as integrated: premultiplied, <= 1
    run_cli("render", *scene(plume), "-o", exr, *fixed, "--depth", "--no-jitter", check=0)
    run_cli("render", *scene(plume), "-o", png, *fixed, "--no-jitter", check=0)
    rgba, meta = read_image(exr)
    assert rgba.shape == (32, 48, 4) and rgba[..., 3].max() > 0.05
    assert np.all(rgba[..., :3] <= rgba[..., 3:] + 1e-6)  # premultiplied
    assert meta["settings"]["field"] == "T" and meta["settings"]["jitter"] is False
    assert set(meta["camera"]) == {"position", "look_at", "up", "fovy"}
    assert "RGBPoints" in meta["transfer_function"]
    depth = read_depth(exr)
    hit = rgba[..., 3] >= 0.5
    assert np.all(np.isfinite(depth[hit])) and np.all(np.isinf(depth[rgba[..., 3] < 0.5]))
    # A .png is the frame over black (premultiplied colour, opaque) unless --transparent.
    png_rgba, _ = read_image(png)
    assert (png_rgba[..., 3] == 1).all() and np.abs(png_rgba[..., :3] - rgba[..., :3]).max() <= 1.5 / 255
    run_cli("render", *scene(plume), "-o", png, *fixed, "--no-jitter", "--transparent", check=0)
    png_rgba, _ = read_image(png)
    assert np.abs(png_rgba - rgba).max() <= 1.5 / 255


def test_camera_flags_override_file(plume, tmp_path):
    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps({"position": [150, 75, 175], "look_at": [64, 36, 64],
                               "up": [0, 1, 0], "fovy": 30}))
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    run_cli("render", *scene(plume), "-o", a, *SMALL, "--camera", cam, "--no-jitter", check=0)
    run_cli("render", *scene(plume), "-o", b, *SMALL, "--camera", cam, "--fovy", "60", "--no-jitter", check=0)
    ia, ma = read_image(a)
    ib, mb = read_image(b)
    assert ma["camera"]["fovy"] == 30 and mb["camera"]["fovy"] == 60
    assert ib[..., 3].sum() < ia[..., 3].sum()  # a wider view makes the plume smaller


@pytest.mark.parametrize("content, needle", [
    ("{not json", "not valid JSON"),
    ('{"position": [0, 0, 10], "look_at": [0, 0, 0], "up": [0, 0, 1], "fovy": 30}', "parallel"),
    ('{"position": [0, 0, 10], "look_at": [0, 0, 0], "up": [0, 1, 0]}', "fovy"),
])
def test_bad_camera_file(plume, tmp_path, content, needle):
    cam = tmp_path / "cam.json"
    cam.write_text(content)
    out = tmp_path / "x.png"
    assert_one_error_line(run_cli("render", *scene(plume), "-o", out, *SMALL, "--camera", cam),
                          str(cam), needle)
    assert not out.exists() and list(tmp_path.iterdir()) == [cam]


def test_up_flag_parallel_to_view(plume, tmp_path):
    proc = run_cli("render", *scene(plume), "-o", tmp_path / "x.png", *SMALL,
                   "--position", "64", "64", "300", "--look-at", "64", "64", "0", "--up", "0", "0", "1")
    assert_one_error_line(proc, "parallel")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("content, needle", [
    ("[]", "ParaView colour-map preset"),
    ('{"RGBPoints": [0, 1, 0]}', "RGBPoints"),
    ('{"RGBPoints": [1, 1, 0, 0, 0, 0, 1, 0], "Points": [0, 0.5, 0.5, 0]}', "increasing"),
])
def test_bad_transfer_function(plume, tmp_path, content, needle):
    tf = tmp_path / "tf.json"
    tf.write_text(content)
    assert_one_error_line(run_cli("render", *scene(plume), "-o", tmp_path / "x.png", *SMALL,
                                  "--transfer-function", tf), str(tf), needle)
    assert list(tmp_path.iterdir()) == [tf]


def test_unknown_colormap_and_field(plume, tmp_path):
    assert_one_error_line(run_cli("render", *scene(plume), "-o", tmp_path / "x.png", *SMALL,
                                  "--colormap", "nosuchmap"), "nosuchmap")
    assert_one_error_line(run_cli("render", *scene(plume), "-o", tmp_path / "x.png",
                                  "--field", "rho"), "rho")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_mismatched_and_wrong_kind_inputs(plume, tmp_path):
    # A bvh built from other regions: a dataset with one field only.
    other = tmp_path / "other"
    other.mkdir()
    run_cli("ingest", GERRIS, "--field", "T", "-o", other / "cells.npz", check=0)
    run_cli("brick", other / "cells.npz", "-o", other / "bricks.npz", "--max-brick-width", "4", check=0)
    run_cli("regions", other / "bricks.npz", "-o", other / "regions.npz", check=0)
    run_cli("bvh", other / "regions.npz", "-o", other / "bvh.npz", check=0)
    out = tmp_path / "x.png"
    proc = run_cli("render", plume / "bricks.npz", plume / "regions.npz", other / "bvh.npz", "-o", out)
    assert_one_error_line(proc, "bvh")
    proc = run_cli("render", plume / "bricks.npz", plume / "bvh.npz", plume / "regions.npz", "-o", out)
    assert_one_error_line(proc, "expected a regions file, found a bvh file")
    assert not out.exists()


def test_output_kinds(plume, tmp_path):
    proc = run_cli("render", *scene(plume), "-o", tmp_path / "x.tiff", *SMALL)
    assert proc.returncode == 2 and ".exr or .png" in proc.stderr
    assert_one_error_line(run_cli("render", *scene(plume), "-o", tmp_path / "x.png", *SMALL, "--depth"),
                          "depth")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_devices_and_device_choice(plume, tmp_path):
    listing = json.loads(run_cli("devices", "--json", check=0).stdout)
    assert listing and all({"spec", "name", "platform", "type", "version"} <= set(d) for d in listing)
    assert sum(d["default"] for d in listing) == 1
    out = tmp_path / "x.png"
    run_cli("render", *scene(plume), "-o", out, *SMALL, "--device", listing[0]["spec"], check=0)
    assert_one_error_line(run_cli("render", *scene(plume), "-o", tmp_path / "y.png", *SMALL,
                                  "--device", "no-such-device"), "no-such-device")
    proc = run_cli("render", *scene(plume), "-o", tmp_path / "z.png", *SMALL,
                   env={"EXABRICKS_DEVICE": "no-such-device"})
    assert_one_error_line(proc, "no-such-device")
