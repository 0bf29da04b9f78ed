"""The one reader of small inputs (exabricks/util/jsonfile.py; issue 32): devices,
FIFOs and directories are refused without blocking or reading without bound,
and the size, nesting and list caps refuse a hostile file in one line before
the work after parsing grows with it."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from exabricks.util.constants import MAX_KNOTS
from exabricks.util.errors import ExabricksError
from exabricks.util.jsonfile import MAX_DEPTH, MAX_LIST, check_bounds, read_json
from exabricks.picture.transfer_function import TransferFunction

from helpers import assert_one_error_line
from helpers.hostile import run

CAMERA = {"position": [0.5, 0.5, 3.0], "look_at": [0.5, 0.5, 0.5], "up": [0, 1, 0], "fovy": 30}


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "fifo"
    os.mkfifo(path)
    return path


@pytest.fixture(params=["device", "fifo", "directory"])
def not_regular(request, tmp_path):
    """A path that is no regular file, and the word the message names it by."""
    if request.param == "device":
        return "/dev/zero", "character device"
    if request.param == "fifo":
        path = tmp_path / "fifo"
        os.mkfifo(path)
        return path, "FIFO"
    return tmp_path, "directory"


@pytest.mark.parametrize("option", ["--scene", "--camera", "--transfer-function", "--camera-path"])
def test_render_json_inputs_refuse_what_is_not_a_regular_file(option, not_regular, plume_trio, tmp_path):
    path, kind = not_regular
    extra = ["--frame", "0"] if option == "--camera-path" else []
    proc = run("render", *plume_trio, "-o", tmp_path / "x.png", option, path, *extra, timeout=60)
    if kind == "directory":  # click's own check of a file option: a usage error
        assert proc.returncode in (1, 2) and "Traceback" not in proc.stderr, proc.stderr
    else:
        assert_one_error_line(proc, str(path), kind)
    assert not (tmp_path / "x.png").exists()


def test_keyframes_and_points_refuse_devices_and_fifos(fifo, plume_trio, tmp_path):
    for path, kind in ((fifo, "FIFO"), ("/dev/zero", "character device")):
        assert_one_error_line(run("camera", "path", path, "--frames", "3", "-o",
                                  tmp_path / "p.json", timeout=60), str(path), kind)
        assert_one_error_line(run("probe", *plume_trio, "--points", path, "-o", tmp_path / "v.npy",
                                  timeout=60), str(path), kind)


@pytest.mark.parametrize("target, word", [("/dev/zero", "character device"), (".", "directory")])
def test_a_scene_naming_a_device_or_directory_says_so(target, word, plume_trio, tmp_path):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"camera": target}))
    proc = run("render", *plume_trio, "-o", tmp_path / "x.png", "--scene", scene)
    assert_one_error_line(proc, "scene.json", "camera", word)
    assert "no such file" not in proc.stderr


def test_a_file_past_the_cap_is_refused_without_reading_on(tmp_path):
    path = tmp_path / "huge.json"
    with open(path, "wb") as f:
        f.truncate((16 << 20) + 1)  # sparse: costs no disk
    with pytest.raises(ExabricksError, match="huge.json: camera file is too large"):
        read_json(path, "camera file")


@pytest.mark.parametrize("doc, needle", [
    ([0] * (MAX_LIST + 1), f"list of {MAX_LIST + 1:,} entries"),
    (json.loads("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1)), "nested more than"),
    ([[0] * 1000] * 1100, "more than"),
])
def test_lists_nesting_and_values_are_bounded(doc, needle):
    with pytest.raises(ExabricksError, match=needle):
        check_bounds(doc, "x.json: scene file")


def test_a_list_at_the_cap_parses(tmp_path):
    path = tmp_path / "ok.json"
    path.write_text(json.dumps({"RGBPoints": [0.0] * MAX_LIST}))
    assert len(read_json(path, "transfer function")["RGBPoints"]) == MAX_LIST


def test_an_iso_list_longer_than_the_schema_allows_is_refused_first(plume_trio, tmp_path):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"isosurfaces": [{"field": "T", "value": 0.1}] * 33}))
    assert_one_error_line(run("render", *plume_trio, "-o", tmp_path / "x.png", "--scene", scene),
                          "scene.json", "isosurfaces", "at most 32", "33")


def test_a_million_entry_scene_list_is_refused_in_one_line(plume_trio, tmp_path):
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"volumes": [{"field": "T", "transfer_function":
                                              {"RGBPoints": [0.0] * 1_000_000}}]}))
    assert_one_error_line(run("render", *plume_trio, "-o", tmp_path / "x.png", "--scene", scene),
                          "scene.json", "1,000,000 entries")


def test_presets_and_opacity_lists_are_bounded_in_knots(plume_trio, tmp_path):
    n = MAX_KNOTS + 1
    preset = tmp_path / "preset.json"
    preset.write_text(json.dumps({"RGBPoints": [v for i in range(n) for v in (i, 0.5, 0.5, 0.5)]}))
    assert_one_error_line(run("render", *plume_trio, "-o", tmp_path / "x.png", "--transfer-function",
                              preset), "preset.json", f"{4 * n:,} entries")
    rows = np.column_stack([np.arange(n), np.full((n, 3), 0.5)])
    with pytest.raises(ExabricksError, match=f"more than {MAX_KNOTS:,} knots"):
        TransferFunction(rows, np.array([[0.0, 1.0]]))
    opacity = ",".join(["0.5"] * n)
    assert_one_error_line(run("render", *plume_trio, "-o", tmp_path / "x.png", "--colormap", "viridis",
                              "--opacity", opacity), f"{n:,} opacity knots")
    assert not (tmp_path / "x.png").exists()


def test_a_preset_at_the_knot_cap_renders_with_bounded_metadata(plume_trio, tmp_path):
    preset = tmp_path / "preset.json"
    preset.write_text(json.dumps({"RGBPoints": [v for i in range(MAX_KNOTS)
                                                for v in (i / MAX_KNOTS, 0.5, 0.5, 0.5)]}))
    out = tmp_path / "x.png"
    proc = run("render", *plume_trio, "-o", out, "--size", "32", "32", "--transfer-function", preset)
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_size < 2 << 20


def test_keyframe_errors_name_the_file(tmp_path):
    keys = tmp_path / "keys.json"
    keys.write_text(json.dumps([{**CAMERA, "position": [1, 0, 0], "look_at": [0, 0, 0]},
                                {**CAMERA, "position": [-1, 0, 0], "look_at": [0, 0, 0]}]))
    assert_one_error_line(run("camera", "path", keys, "--frames", "3", "-o", tmp_path / "p.json"),
                          "keys.json", "look-at point")


def test_too_many_keyframes_are_refused(tmp_path):
    from exabricks.picture.camera_path import MAX_KEYFRAMES

    keys = tmp_path / "keys.json"
    keys.write_text(json.dumps([{**CAMERA, "time": i} for i in range(MAX_KEYFRAMES + 1)]))
    assert_one_error_line(run("camera", "path", keys, "--frames", "3", "-o", tmp_path / "p.json"),
                          "keys.json", "keyframes, at most")


@pytest.mark.parametrize("value", ["nan", "inf", "0"])
def test_a_sampling_rate_that_is_no_positive_number_is_a_usage_error(value, plume_trio, tmp_path):
    proc = run("render", *plume_trio, "-o", tmp_path / "x.png", "--sampling-rate", value)
    assert proc.returncode == 2 and "--sampling-rate" in proc.stderr, proc.stderr


def test_a_tiny_memory_budget_is_reported_in_bytes(plume_trio, tmp_path):
    proc = run("render", *plume_trio, "-o", tmp_path / "x.png", "--memory-budget", "1")
    assert_one_error_line(proc, "a memory budget of 1 byte ")
