"""Camera rays, transfer functions and image files against analytic or brute-force answers."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from exabricks.film import image_io
from exabricks.picture.camera import Camera, default_camera
from exabricks.util.errors import ExabricksError
from exabricks.film.image_io import read_depth, read_image, write_image
from exabricks.picture.transfer_function import (
    TransferFunction, builtin_presets, default_transfer_function, opacity_correct, preset_path
)

# ---------------------------------------------------------------------------------------
# camera


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def test_pixel_rays_follow_the_design_convention_analytically():
    # Looking down -z with +y up and fovy 90: right = +x, up' = +y, tan(45) = 1, aspect 2.
    cam = Camera((1.0, 2.0, 3.0), (1.0, 2.0, -7.0), (0.0, 1.0, 0.0), 90.0)
    origin, forward, du, dv = cam.frame(4, 2)
    np.testing.assert_allclose(origin, [1, 2, 3])
    np.testing.assert_allclose(forward, [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(du, [2, 0, 0], atol=1e-15)
    np.testing.assert_allclose(dv, [0, 1, 0], atol=1e-15)
    origins, dirs = cam.rays(4, 2)
    assert origins.shape == dirs.shape == (2, 4, 3)
    # top-left pixel centre: u = 2 * 0.5 / 4 - 1 = -0.75, v = 1 - 2 * 0.5 / 2 = 0.5
    np.testing.assert_allclose(dirs[0, 0], _unit([-0.75 * 2, 0.5, -1]), atol=1e-15)
    # bottom-right pixel centre: u = 0.75, v = -0.5
    np.testing.assert_allclose(dirs[1, 3], _unit([0.75 * 2, -0.5, -1]), atol=1e-15)
    np.testing.assert_allclose(origins, np.broadcast_to([1, 2, 3], (2, 4, 3)))


def test_centre_pixel_of_an_odd_image_looks_at_the_target():
    cam = Camera((3.0, -1.0, 2.0), (-2.0, 0.5, 1.0), (0.2, 0.1, 1.0), 40.0)
    _, dirs = cam.rays(7, 5)
    np.testing.assert_allclose(dirs[2, 3], _unit(np.subtract(cam.look_at, cam.position)), atol=1e-15)


def test_ray_directions_match_the_pinhole_projection_of_any_camera(rng):
    for _ in range(20):
        position, look_at, up = rng.normal(size=(3, 3)) * 10
        fovy = rng.uniform(5, 170)
        width, height = rng.integers(1, 40, size=2)
        cam = Camera(tuple(position), tuple(look_at), tuple(up), fovy)
        _, dirs = cam.rays(width, height)
        f = _unit(look_at - position)
        r = _unit(np.cross(f, up))
        u_ = np.cross(r, f)
        t = math.tan(math.radians(fovy) / 2)
        # Perspective division of each ray onto the image plane at distance 1.
        x = (dirs @ r) / (dirs @ f) / (t * width / height)
        y = (dirs @ u_) / (dirs @ f) / t
        cols, rows = np.meshgrid(np.arange(width), np.arange(height))
        np.testing.assert_allclose(x, 2 * (cols + 0.5) / width - 1, atol=1e-9)
        np.testing.assert_allclose(y, 1 - 2 * (rows + 0.5) / height, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)


def test_jitter_moves_rays_within_the_pixel():
    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0)
    _, centre = cam.rays(6, 4)
    _, half = cam.rays(6, 4, jitter=(0.5, 0.5))
    np.testing.assert_array_equal(centre, half)
    _, corner = cam.rays(6, 4, jitter=np.zeros((4, 6, 2)))
    origin, forward, du, dv = cam.frame(6, 4)
    # offset (0, 0) is the top-left corner of the pixel: u = 2 col / W - 1, v = 1 - 2 row / H
    np.testing.assert_allclose(corner[0, 0], _unit(forward - du + dv), atol=1e-15)
    np.testing.assert_allclose(corner[3, 5], _unit(forward + (2 * 5 / 6 - 1) * du + (1 - 2 * 3 / 4) * dv),
                               atol=1e-15)


def test_camera_json_round_trip_and_overrides(tmp_path):
    cam = Camera((1, 2, 3), (0, 0, 0), (0, 0, 1), 45)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(cam.to_dict()))
    assert Camera.from_json(path) == cam
    moved = cam.with_overrides(position=(4, 5, 6), fovy=20)
    assert moved == Camera((4.0, 5.0, 6.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 20.0)
    assert cam.with_overrides() == cam


@pytest.mark.parametrize(
    "change, needles",
    [
        ({"up": [0, 0, -2]}, ["is parallel to the view direction", "[0, 0, -2]"]),
        ({"look_at": [1, 2, 3]}, ["same point"]),
        ({"fovy": 180}, ["fovy"]),
        ({"fovy": 0}, ["fovy"]),
        ({"position": [1, 2]}, ["'position'", "3 numbers"]),
        ({"position": [1, "a", 3]}, ["'position'"]),
        ({"up": [0, 0, 0]}, ["zero length"]),
        ({"lookat": [0, 0, 0]}, ["unknown camera key", "'lookat'"]),
    ],
)
def test_bad_camera_files_name_the_file_and_the_problem(tmp_path, change, needles):
    d = {"position": [1, 2, 3], "look_at": [1, 2, 0], "up": [0, 1, 0], "fovy": 30}
    d.update(change)
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ExabricksError) as e:
        Camera.from_json(path)
    for n in [str(path), *needles]:
        assert n in str(e.value)


def test_camera_file_errors_missing_key_nan_not_json_missing_file(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text('{"position": [1, 2, 3], "look_at": [0, 0, 0], "fovy": 30}')
    with pytest.raises(ExabricksError, match=r"cam\.json: camera is missing 'up'"):
        Camera.from_json(path)
    path.write_text('{"position": [NaN, 2, 3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fovy": 30}')
    with pytest.raises(ExabricksError, match="non-finite"):
        Camera.from_json(path)
    path.write_text('{"position": [1, 2, 3],')
    with pytest.raises(ExabricksError, match=r"cam\.json: camera file is not valid JSON"):
        Camera.from_json(path)
    with pytest.raises(ExabricksError, match="nope.json: cannot read camera file"):
        Camera.from_json(tmp_path / "nope.json")
    with pytest.raises(ExabricksError, match="parallel"):
        Camera((0, 0, 0), (0, 1, 0), (0, 3, 0), 30)


@pytest.mark.parametrize("width, height", [(64, 64), (160, 90), (100, 50)])
def test_default_camera_shows_the_whole_box(width, height):
    lower, upper = np.array([-3.0, 10.0, 0.5]), np.array([5.0, 12.0, 40.0])
    cam = default_camera(lower, upper)
    origin, forward, du, dv = cam.frame(width, height)
    np.testing.assert_allclose(cam.look_at, (lower + upper) / 2)
    corners = np.array([[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1])
                        for z in (lower[2], upper[2])])
    rel = corners - origin
    depth = rel @ forward
    assert (depth > 0).all()
    u = (rel @ du) / np.dot(du, du) / depth
    v = (rel @ dv) / np.dot(dv, dv) / depth
    assert (np.abs(u) <= 1).all() and (np.abs(v) <= 1).all()
    # The bounding sphere exactly fills the vertical field of view.
    radius = np.linalg.norm(upper - lower) / 2
    distance = np.linalg.norm(origin - (lower + upper) / 2)
    assert math.isclose(math.asin(radius / distance), math.radians(cam.fovy) / 2, rel_tol=1e-12)


# ---------------------------------------------------------------------------------------
# transfer function

PRESET = {
    "Name": "test",
    "ColorSpace": "RGB",
    "RGBPoints": [-1.0, 0.0, 0.0, 1.0, 0.5, 1.0, 1.0, 1.0, 2.0, 1.0, 0.0, 0.0],
    "Points": [-0.5, 0.0, 0.5, 0.0, 0.0, 0.8, 0.5, 0.0, 1.5, 0.2, 0.5, 0.0],
}


def _write(tmp_path, obj, name="tf.json"):
    path = tmp_path / name
    path.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return path


def test_paraview_preset_object_and_list_forms(tmp_path):
    a = TransferFunction.from_paraview(_write(tmp_path, PRESET, "a.json"))
    b = TransferFunction.from_paraview(_write(tmp_path, [PRESET, {"Name": "ignored"}], "b.json"))
    assert a == b and a.name == "test"
    np.testing.assert_array_equal(a.rgb_points, np.reshape(PRESET["RGBPoints"], (-1, 4)))
    np.testing.assert_array_equal(a.alpha_points, [[-0.5, 0.0], [0.0, 0.8], [1.5, 0.2]])
    # piecewise linear between knots, clamped outside
    rgba = a.evaluate([-5.0, -1.0, -0.25, 0.0, 0.75, 2.0, 9.0])
    expected = [
        [0, 0, 1, 0.0],
        [0, 0, 1, 0.0],
        [0.5, 0.5, 1, 0.4],
        [2 / 3, 2 / 3, 1, 0.8],
        [1, 5 / 6, 5 / 6, 0.8 - 0.6 * 0.75 / 1.5],
        [1, 0, 0, 0.2],
        [1, 0, 0, 0.2],
    ]
    np.testing.assert_allclose(rgba, expected, atol=1e-15)
    assert a.evaluate(np.zeros((2, 3))).shape == (2, 3, 4)
    assert TransferFunction.from_paraview_dict(a.to_paraview_dict()) == a


def test_preset_without_points_gets_an_opacity_ramp_over_the_colours(tmp_path):
    preset = {k: v for k, v in PRESET.items() if k != "Points"}
    tf = TransferFunction.from_paraview(_write(tmp_path, preset))
    np.testing.assert_array_equal(tf.alpha_points, [[-1.0, 0.0], [2.0, 1.0]])


@pytest.mark.parametrize(
    "text, needle",
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"Name": "x", "Points": [0, 0, 0.5, 0]}), "no 'RGBPoints'"),
        (json.dumps({**PRESET, "RGBPoints": [0, 1, 1, 1, 1, 0, 0]}), "length 7 is not a positive multiple of 4"),
        (json.dumps({**PRESET, "Points": [0, 1, 0.5]}), "length 3 is not a positive multiple of 4"),
        (json.dumps({**PRESET, "RGBPoints": [1, 1, 1, 1, 0, 0, 0, 0]}), "strictly increasing"),
        (json.dumps({**PRESET, "Points": [0, 0, 0.5, 0, 0, 1, 0.5, 0]}), "strictly increasing"),
        (json.dumps({**PRESET, "Points": [0, 1.5, 0.5, 0]}), "alpha outside [0, 1]"),
        (json.dumps({**PRESET, "RGBPoints": [0, 1, 2, 1]}), "colour outside [0, 1]"),
        ('{"RGBPoints": [0, NaN, 0, 0]}', "NaN is not a number"),
        (json.dumps({**PRESET, "RGBPoints": [0, 1, None, 1]}), "flat list of numbers"),
        ("[]", "empty list"),
        ("3", "expected a ParaView colour-map preset"),
    ],
)
def test_malformed_presets_name_the_file_and_the_problem(tmp_path, text, needle):
    path = _write(tmp_path, text, "bad-preset.json")
    with pytest.raises(ExabricksError) as e:
        TransferFunction.from_paraview(path)
    assert str(path) in str(e.value) and needle in str(e.value), str(e.value)


def test_missing_preset_file(tmp_path):
    with pytest.raises(ExabricksError, match="nope.json: cannot read transfer function"):
        TransferFunction.from_paraview(tmp_path / "nope.json")


def _random_tf(rng, n_rgb, n_alpha):
    x_rgb = np.sort(rng.choice(np.linspace(-3, 3, 601), n_rgb, replace=False))
    x_alpha = np.sort(rng.uniform(-4, 4, n_alpha))
    rgb = np.column_stack([x_rgb, rng.random((n_rgb, 3))])
    alpha = rng.random(n_alpha)
    alpha[rng.random(n_alpha) < 0.3] = 0.0  # transparent stretches
    return TransferFunction(rgb, np.column_stack([x_alpha, alpha]))


def test_merged_knots_reproduce_evaluate(rng):
    for n_rgb, n_alpha in [(1, 1), (2, 5), (7, 3), (40, 40)]:
        tf = _random_tf(rng, n_rgb, n_alpha)
        values = np.concatenate([rng.uniform(-6, 6, 5000), tf.rgb_points[:, 0], tf.alpha_points[:, 0]])
        xs64, rgba64 = tf.merged_knots(dtype=np.float64)
        interpolated = np.column_stack([np.interp(values, xs64, rgba64[:, c]) for c in range(4)])
        np.testing.assert_allclose(interpolated, tf.evaluate(values), rtol=0, atol=1e-12)
        xs, rgba = tf.merged_knots()
        assert xs.dtype == rgba.dtype == np.float32 and rgba.shape == (len(xs), 4)
        assert (np.diff(xs) > 0).all()
        interpolated32 = np.column_stack([np.interp(values, xs, rgba[:, c]) for c in range(4)])
        np.testing.assert_allclose(interpolated32, tf.evaluate(values), rtol=0, atol=2e-5)


def test_any_alpha_against_dense_sampling(rng):
    for n_alpha in (1, 2, 3, 8, 33):
        tf = _random_tf(rng, 3, n_alpha)
        lo = rng.uniform(-5, 5, 300)
        hi = lo + rng.exponential(1.0, 300) * (rng.random(300) < 0.9)  # some empty intervals
        found = tf.any_alpha(lo, hi)
        assert found.shape == lo.shape and found.dtype == bool
        knots = tf.alpha_points[:, 0]
        for i in range(len(lo)):
            # The float64 reference at a dense grid and at every knot inside: its
            # largest value there is alpha's maximum over the interval.
            samples = np.concatenate([np.linspace(lo[i], hi[i], 2001),
                                      knots[(knots >= lo[i]) & (knots <= hi[i])]])
            assert found[i] == (tf.evaluate(samples)[:, 3].max() > 0), (lo[i], hi[i])
        np.testing.assert_array_equal(tf.any_alpha(hi, lo), found)  # swapped bounds


def test_any_alpha_finds_interior_peaks_and_zero_stretches():
    tf = TransferFunction([[0, 1, 1, 1]], [[0, 0], [1, 0], [2, 0.7], [3, 0], [4, 0]])
    np.testing.assert_array_equal(
        tf.any_alpha([0.0, 1.5, 0.0, 3.0, -9.0, 1.0, 2.0, np.nan],
                     [1.0, 2.5, 4.0, 9.0, 0.5, 1.0, 2.0, 1.0]),
        [False, True, True, False, False, False, True, False],
    )


def test_colormap_shortcut_equals_the_preset_with_the_same_knots(tmp_path):
    import matplotlib

    tf = TransferFunction.from_colormap("magma", (10.0, 20.0), opacity=(0.0, 0.5, 0.1))
    preset = TransferFunction.from_paraview(_write(tmp_path, [tf.to_paraview_dict()]))
    assert preset == tf
    values = np.random.default_rng(5).uniform(5, 25, 1000)
    np.testing.assert_array_equal(preset.evaluate(values), tf.evaluate(values))
    # the knots are matplotlib's 256-entry table, and opacity knots evenly spaced
    lut = matplotlib.colormaps["magma"](np.arange(256))[:, :3]
    np.testing.assert_array_equal(tf.rgb_points[:, 1:], lut)
    np.testing.assert_allclose(tf.rgb_points[[0, -1], 0], [10.0, 20.0])
    np.testing.assert_allclose(tf.alpha_points, [[10, 0], [15, 0.5], [20, 0.1]])
    with pytest.raises(ExabricksError, match="unknown colormap 'nope'"):
        TransferFunction.from_colormap("nope", (0, 1))
    with pytest.raises(ExabricksError, match="low < high"):
        TransferFunction.from_colormap("magma", (1, 1))


def test_default_transfer_function_is_viridis_with_a_ramp_over_the_range():
    assert {"default", "inferno-shells"} <= set(builtin_presets())
    tf = default_transfer_function((2.0, 6.0))
    reference = TransferFunction.from_colormap("viridis", (2.0, 6.0))
    values = np.linspace(0, 8, 997)
    np.testing.assert_allclose(tf.evaluate(values), reference.evaluate(values), rtol=0, atol=1e-12)
    np.testing.assert_allclose(tf.evaluate([2.0, 4.0, 6.0])[:, 3], [0.0, 0.5, 1.0], atol=1e-15)
    constant = default_transfer_function((3.0, 3.0))  # a constant field sits mid-ramp
    assert constant.evaluate(3.0)[3] == pytest.approx(0.5)
    for name in builtin_presets():
        TransferFunction.from_paraview(preset_path(name))
    with pytest.raises(ExabricksError, match="no built-in transfer function 'nope'"):
        preset_path("nope")


def test_opacity_correction_composes_over_sub_steps(rng):
    alpha = rng.random(100)
    np.testing.assert_allclose(opacity_correct(alpha, 2.5, 2.5), alpha, atol=1e-15)
    half = opacity_correct(alpha, 0.5, 1.0)
    # two half steps are one full step: 1 - (1 - a_half)^2 = alpha
    np.testing.assert_allclose(1 - (1 - half) ** 2, alpha, atol=1e-14)
    np.testing.assert_allclose(opacity_correct(alpha, 0.0, 1.0), 0.0)
    np.testing.assert_allclose(opacity_correct(1.0, 0.1, 1.0), 1.0)
    np.testing.assert_allclose(opacity_correct(0.0, 7.0, 1.0), 0.0)


# ---------------------------------------------------------------------------------------
# images


def _premultiplied(rng, height, width):
    rgba = rng.random((height, width, 4)).astype(np.float32)
    rgba[..., 3] = np.where(rng.random((height, width)) < 0.1, 0.0, rgba[..., 3])
    rgba[..., :3] *= rgba[..., 3:]
    return rgba


METADATA = {
    "camera": {"position": [1.0, 2.0, 3.0], "look_at": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fovy": 30.0},
    "transfer_function": PRESET,
    "dataset": "amrex-advection3d/plt00020",
    "settings": {"sampling_rate": 2, "seed": np.int64(7), "jitter": True},
}
METADATA_JSON = json.loads(json.dumps({**METADATA, "settings": {**METADATA["settings"], "seed": 7}}))


def test_exr_round_trip_is_exact_with_metadata_and_depth(tmp_path, rng):
    rgba = _premultiplied(rng, 17, 23)
    depth = rng.uniform(0, 10, (17, 23)).astype(np.float32)
    depth[0, 0] = np.inf
    path = tmp_path / "image.exr"
    write_image(path, rgba, metadata=METADATA, depth=depth)
    back, meta = read_image(path)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, rgba)
    assert meta == METADATA_JSON
    np.testing.assert_array_equal(read_depth(path), depth)
    write_image(path, rgba, metadata={})
    assert read_depth(path) is None
    assert os.listdir(tmp_path) == ["image.exr"]


def test_png_round_trip_within_one_level_after_premultiplication(tmp_path, rng):
    rgba = _premultiplied(rng, 31, 12)
    path = tmp_path / "image.png"
    write_image(path, rgba, metadata=METADATA)
    back, meta = read_image(path)
    assert back.shape == rgba.shape and back.dtype == np.float32
    assert np.abs(back - rgba).max() <= 1 / 255
    assert meta == METADATA_JSON
    from PIL import Image

    with Image.open(path) as image:
        pixels = np.asarray(image)
        assert image.mode == "RGBA" and image.text["Software"].startswith("exabricks")
    # un-premultiplied on disk: colour of a half-transparent pixel is rgb / alpha
    transparent = rgba[..., 3] == 0
    assert (pixels[transparent] == 0).all()
    expected = np.rint(np.clip(rgba[..., :3] / np.maximum(rgba[..., 3:], 1e-30), 0, 1) * 255)
    np.testing.assert_array_equal(pixels[~transparent, :3], expected[~transparent])


def test_image_write_refusals_leave_nothing(tmp_path, rng):
    rgba = _premultiplied(rng, 4, 5)
    with pytest.raises(ExabricksError, match="unknown image format '.jpg'"):
        write_image(tmp_path / "a.jpg", rgba, metadata={})
    with pytest.raises(ExabricksError, match="depth image needs .exr"):
        write_image(tmp_path / "a.png", rgba, metadata={}, depth=np.zeros((4, 5)))
    with pytest.raises(ExabricksError, match="cannot be written as JSON"):
        write_image(tmp_path / "a.exr", rgba, metadata={"x": object()})
    with pytest.raises(ExabricksError, match=r"\(height, width, 4\)"):
        write_image(tmp_path / "a.exr", rgba[..., :3], metadata={})
    bad = rgba.copy()
    bad[1, 1, 1] = np.nan
    with pytest.raises(ExabricksError, match="1 non-finite"):
        write_image(tmp_path / "a.png", bad, metadata={})
    with pytest.raises(ExabricksError, match="does not exist"):
        write_image(tmp_path / "missing" / "a.exr", rgba, metadata={})
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("suffix, writer", [(".exr", "_write_exr"), (".png", "_write_png")])
def test_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path, rng, monkeypatch, suffix, writer):
    path = tmp_path / f"image{suffix}"
    old = _premultiplied(rng, 4, 5)
    write_image(path, old, metadata={"n": 1})
    original = getattr(image_io, writer)

    def fail_half_way(f, *args):
        original(f, *args)
        f.truncate(10)  # a partial file, then the failure
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(image_io, writer, fail_half_way)
    with pytest.raises(ExabricksError, match="cannot write image: No space left on device"):
        write_image(path, _premultiplied(rng, 4, 5), metadata={"n": 2})
    assert os.listdir(tmp_path) == [path.name]
    back, meta = read_image(path)
    assert meta == {"n": 1}


@pytest.mark.parametrize("suffix", [".exr", ".png"])
def test_reading_missing_or_corrupt_images_names_the_file(tmp_path, suffix):
    with pytest.raises(ExabricksError, match=f"nope{suffix}: no such image file"):
        read_image(tmp_path / f"nope{suffix}")
    path = tmp_path / f"corrupt{suffix}"
    path.write_bytes(b"\x89PNG\r\n\x1a\n garbage" if suffix == ".png" else b"v/1\x01 garbage")
    with pytest.raises(ExabricksError, match=f"corrupt{suffix}: cannot read"):
        read_image(path)


@pytest.mark.parametrize("height, width", [(1, 1), (37, 5), (300, 1100)])
def test_streamed_writers_match_the_libraries_readers(tmp_path, rng, height, width):
    """Our PNG and OpenEXR writers (bands of rows, EXR blocks of 16 lines, the
    last ones short) read back exactly through Pillow and OpenEXR."""
    rgba = _premultiplied(rng, height, width)
    depth = rng.random((height, width), dtype=np.float32)
    depth[0, 0] = np.inf
    write_image(tmp_path / "a.exr", rgba, metadata={"k": [1, "é"]}, depth=depth)
    back, meta = read_image(tmp_path / "a.exr")
    np.testing.assert_array_equal(back, rgba)
    np.testing.assert_array_equal(read_depth(tmp_path / "a.exr"), depth)
    assert meta == {"k": [1, "é"]}
    write_image(tmp_path / "a.png", rgba, metadata={"k": 2})
    from PIL import Image

    with Image.open(tmp_path / "a.png") as image:
        np.testing.assert_array_equal(np.asarray(image), image_io.to_png_pixels(rgba))
    assert read_image(tmp_path / "a.png")[1] == {"k": 2}


def test_a_frame_file_writes_what_was_put_and_the_background_below(tmp_path, rng):
    rgba = _premultiplied(rng, 50, 40)
    depth = rng.random((50, 40), dtype=np.float32)
    path = tmp_path / "f.exr"
    with image_io.FrameFile(path, 40, 50, depth=True, background=(0, 0, 1, 0.5)) as frame:
        for row in range(0, 30, 7):
            frame.put(row, rgba[row:min(row + 7, 30)], depth[row:min(row + 7, 30)])
        with pytest.raises(ExabricksError, match="does not continue"):
            frame.put(0, rgba[:3], depth[:3])
        frame.write(metadata={"rows": 30})
        assert len(os.listdir(tmp_path)) == 2  # the output and the scratch file beside it
    assert os.listdir(tmp_path) == ["f.exr"]
    back, meta = read_image(path)
    np.testing.assert_array_equal(back[:30], rgba[:30])
    np.testing.assert_array_equal(back[30:], np.broadcast_to([0, 0, 0.5, 0.5], (20, 40, 4)))
    z = read_depth(path)
    np.testing.assert_array_equal(z[:30], depth[:30])
    assert np.isinf(z[30:]).all() and meta == {"rows": 30}
    with pytest.raises(ExabricksError, match="depth image needs .exr"):
        image_io.FrameFile(tmp_path / "f.png", 4, 4, depth=True)
