"""Camera paths (exabricks/picture/camera_path.py, `exabricks camera orbit|path`) and
`render --camera-path --frame/--frames` (issue 12)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from exabricks.picture import camera_path
from exabricks import schema
from exabricks.picture.camera import Camera, default_camera
from exabricks.util.errors import ExabricksError
from exabricks.film.image_io import read_image

from helpers import GERRIS, assert_one_error_line

LO, HI = np.zeros(3), np.array([2.0, 1.0, 4.0])


def test_orbit_starts_at_the_default_view_and_turns_at_a_fixed_distance():
    frames = camera_path.orbit(LO, HI, 12)
    start = default_camera(LO, HI)
    np.testing.assert_allclose(frames[0].position, start.position, rtol=1e-12)
    assert frames[0].look_at == start.look_at and frames[0].fovy == start.fovy
    centre = np.asarray(start.look_at)
    d = [np.linalg.norm(np.subtract(f.position, centre)) for f in frames]
    np.testing.assert_allclose(d, d[0], rtol=1e-12)
    heights = [f.position[1] for f in frames]  # turning about +y: constant height
    np.testing.assert_allclose(heights, heights[0], rtol=1e-12)
    # equal steps, a full turn: the step after the last frame is the first frame
    angles = np.unwrap([np.arctan2(f.position[0] - centre[0], f.position[2] - centre[2])
                        for f in frames])
    np.testing.assert_allclose(np.diff(angles), np.diff(angles)[0], atol=1e-12)
    assert abs(abs(np.diff(angles)[0]) * 12 - 2 * np.pi) < 1e-9


def test_orbit_options():
    frames = camera_path.orbit(LO, HI, 5, look_at=(1, 1, 1), axis=(0, 0, 2), elevation=45,
                               fovy=40, degrees=90)
    for f in frames:
        v = np.subtract(f.position, (1, 1, 1))
        assert f.up == (0.0, 0.0, 1.0) and f.fovy == 40 and f.look_at == (1.0, 1.0, 1.0)
        np.testing.assert_allclose(np.degrees(np.arcsin(v[2] / np.linalg.norm(v))), 45)
    # not a full turn: both ends are frames, 90 degrees apart
    a, b = (np.subtract(f.position, (1, 1, 1))[:2] for f in (frames[0], frames[-1]))
    np.testing.assert_allclose(np.dot(a, b), 0, atol=1e-9)
    for bad in (dict(axis=(0, 0, 0)), dict(elevation=90), dict(look_at=(0, np.nan, 0))):
        with pytest.raises(ExabricksError):
            camera_path.orbit(LO, HI, 4, **bad)


def keys():
    return [Camera((5, 0, 0), (0, 0, 0), (0, 1, 0), 30), Camera((0, 1, 5), (0, 0, 0), (0, 1, 0), 40),
            Camera((-5, 0, 1), (0, 1, 0), (0, 0, 1), 30), Camera((0, -2, -5), (0, 0, 0), (0, 1, 0), 20)]


def test_keyframe_path_passes_through_the_keyframes_smoothly():
    times = [0.0, 1.0, 3.0, 4.0]
    frames = camera_path.interpolate(keys(), times, 41)  # a frame every 0.1
    for k, t in zip(keys(), times):
        f = frames[int(round(t * 10))]
        np.testing.assert_allclose(f.position, k.position, atol=1e-9)
        np.testing.assert_allclose(f.look_at, k.look_at, atol=1e-9)
        assert f.fovy == pytest.approx(k.fovy)
        # up: the keyframe's, made perpendicular to the view
        view = np.subtract(k.look_at, k.position)
        up = np.asarray(k.up) - np.dot(k.up, view) / np.dot(view, view) * view
        np.testing.assert_allclose(f.up, up / np.linalg.norm(up), atol=1e-9)
    p = np.array([f.position for f in frames])
    v = np.diff(p, axis=0)
    # C1 (Catmull-Rom): the velocity changes by O(step^2) at the keyframes, as elsewhere
    dv = np.linalg.norm(np.diff(v, axis=0), axis=1)
    assert dv.max() < 0.2 * np.linalg.norm(v, axis=1).max()
    for f in frames:
        forward = np.subtract(f.look_at, f.position)
        assert abs(np.dot(f.up, forward)) < 1e-9 * np.linalg.norm(forward)


def test_loop_closes_and_one_keyframe_holds_still():
    frames = camera_path.interpolate(keys(), [0, 1, 2, 3], 40, loop=True)
    np.testing.assert_allclose(frames[0].position, keys()[0].position)
    step = np.linalg.norm(np.subtract(frames[1].position, frames[0].position))
    back = np.linalg.norm(np.subtract(frames[-1].position, frames[0].position))
    assert back < 3 * step  # the last frame is one step before the first
    one = camera_path.interpolate(keys()[:1], [0.0], 3)
    assert all(f == keys()[0] for f in one)
    with pytest.raises(ExabricksError, match="increase"):
        camera_path.interpolate(keys()[:2], [1.0, 1.0], 3)


def test_frame_ranges():
    assert list(camera_path.parse_frame_range("3", 10, "--frame")) == [3]
    assert list(camera_path.parse_frame_range("-1", 10, "--frame")) == [9]
    assert list(camera_path.parse_frame_range("2:5", 10, "--frames")) == [2, 3, 4]
    assert list(camera_path.parse_frame_range("8:", 10, "--frames")) == [8, 9]
    for bad in ("10", "x", "5:2", "1:2:3", ""):
        with pytest.raises(ExabricksError):
            camera_path.parse_frame_range(bad, 10, "--frames")


@pytest.fixture(scope="module")
def gerris_files(tmp_path_factory):
    from exabricks.readers import read
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions

    d = tmp_path_factory.mktemp("gerris")
    bricks = build_bricks(read(GERRIS, fields=["T"]))
    regions = build_regions(bricks)
    for name, obj in (("bricks", bricks), ("regions", regions), ("bvh", build_bvh(regions))):
        schema.save(d / f"{name}.npz", obj)
    return d


@pytest.mark.slow
def test_orbit_and_render_frames(cli, gerris_files, tmp_path):
    d = gerris_files
    path = tmp_path / "orbit.json"
    cli("camera", "orbit", d / "bricks.npz", "--frames", 6, "-o", path, check=0)
    doc = json.loads(path.read_text())
    assert doc["kind"] == camera_path.KIND and len(doc["frames"]) == 6
    files = [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    common = ["--size", 48, 32, "--field", "T"]
    cli("render", *files, "--camera-path", path, "--frames", "1:4", "-o",
        tmp_path / "f_%03d.exr", *common, check=0)
    assert sorted(p.name for p in tmp_path.glob("f_*.exr")) == ["f_001.exr", "f_002.exr", "f_003.exr"]
    # frame 2 of the path is the render of that camera, bit for bit
    camera = tmp_path / "camera2.json"
    camera.write_text(json.dumps(doc["frames"][2]))
    cli("render", *files, "--camera", camera, "-o", tmp_path / "single.exr", *common, check=0)
    a, meta = read_image(tmp_path / "f_002.exr")
    b, _ = read_image(tmp_path / "single.exr")
    np.testing.assert_array_equal(a, b)
    assert meta["camera_path"] == {"file": str(path), "frame": 2}
    # --frame I with a plain name writes that name
    cli("render", *files, "--camera-path", path, "--frame", -1, "-o", tmp_path / "last.png",
        *common, check=0)
    assert (tmp_path / "last.png").exists()


def test_keyframes_command(cli, tmp_path):
    src = tmp_path / "keys.json"
    src.write_text(json.dumps({"keyframes": [{**k.to_dict(), "time": t}
                                             for k, t in zip(keys(), [0, 1, 3, 4])], "loop": True}))
    out = tmp_path / "path.json"
    cli("camera", "path", src, "--frames", 9, "-o", out, check=0)
    doc = json.loads(out.read_text())
    assert doc["loop"] is True and len(doc["frames"]) == 9 and len(doc["keyframes"]) == 4
    assert camera_path.read_frames(out)[0] == Camera.from_dict(doc["frames"][0])


@pytest.mark.parametrize("content, needle", [
    ("[]", "non-empty"),
    ('{"keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 1], "up": [0, 1, 0]}]}',
     "same point"),
    ('{"keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0], "up": [0, 1, 0], "time": 1},'
     ' {"position": [0, 0, 2], "look_at": [0, 0, 0], "up": [0, 1, 0], "time": 0}]}', "increase"),
    ('{"keyframes": [], "extra": 1}', "unknown key"),
    ("{", "not valid JSON"),
])
def test_bad_keyframes_give_one_error_line(cli, tmp_path, content, needle):
    src = tmp_path / "keys.json"
    src.write_text(content)
    proc = cli("camera", "path", src, "--frames", 3, "-o", tmp_path / "p.json")
    assert_one_error_line(proc, str(src), needle)
    assert not (tmp_path / "p.json").exists()


def test_render_path_errors(cli, gerris_files, tmp_path):
    files = [gerris_files / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    path = tmp_path / "orbit.json"
    cli("camera", "orbit", files[0], "--frames", 3, "-o", path, check=0)
    out = tmp_path / "x.png"
    proc = cli("render", *files, "--camera-path", path, "--frame", 3, "-o", out)
    assert_one_error_line(proc, "--frame", "3 frames")
    proc = cli("render", *files, "--camera-path", path, "--frames", "0:2", "-o", out)
    assert proc.returncode == 2 and "printf field" in proc.stderr
    proc = cli("render", *files, "--camera-path", path, "-o", out)
    assert proc.returncode == 2 and "--frame" in proc.stderr
    proc = cli("render", *files, "--camera-path", path, "--frame", 0, "--fovy", 20, "-o", out)
    assert proc.returncode == 2 and "--fovy" in proc.stderr
    proc = cli("render", *files, "--frame", 0, "-o", out)
    assert proc.returncode == 2 and "--camera-path" in proc.stderr
    not_a_path = tmp_path / "cam.json"
    not_a_path.write_text(json.dumps(default_camera(LO, HI).to_dict()))
    proc = cli("render", *files, "--camera-path", not_a_path, "--frame", 0, "-o", out)
    assert_one_error_line(proc, str(not_a_path), "not a camera path")
    assert not out.exists()
