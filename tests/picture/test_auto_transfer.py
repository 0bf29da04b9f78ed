"""The defaults' machinery (issue 48; docs/scene.md "Defaults", docs/design-rendering.md
"Volume shading"): scales, transfer functions on a scaled axis, the automatic
transfer function, the statistics it reads (jitted loops against NumPy in
float64), framing, the default field, the suggested iso-value, and the
weighted volume headlight against its closed form."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from exabricks import schema
from exabricks.picture.auto_transfer import (
    KNOT_LATTICE, ambient_band, automatic_transfer_function, opacity_shape, suggested_iso_value
)
from exabricks.picture.camera import Camera
from exabricks.engine.renderer import Renderer
from exabricks.util.errors import ExabricksError
from exabricks.picture.field_statistics import opacity_along, opacity_columns, smallest_positive, volume_histogram
from exabricks.picture.framing import framed_camera, view_axes, visible_corners
from exabricks.picture.scaling import forward, inverse, resolve, scaled_range
from exabricks.scene import Clip, Lighting, Scene, Settings, VolumeLayer, scene_from_options
from exabricks.scene.build import default_field
from exabricks.picture.transfer_function import TransferFunction, lookup_table

from helpers import ENZO, GERRIS, build, device_param


def test_scales():
    assert resolve(None, (0.1, 2.6e5)) == "log" and resolve("auto", (0.04, 2.7)) == "linear"
    assert resolve(None, (0.0, 2.6e6), floor=1e-3) == "log"  # zeros and decades of positives
    assert resolve(None, (-1.0, 2.6e6), floor=1e-3) == "linear" and resolve("symlog", (-1, 1)) == "symlog"
    with pytest.raises(ExabricksError, match="no positive value"):
        resolve("log", (-2.0, 0.0))
    v = np.array([-1e4, -0.5, 0.0, 1e-3, 7.0, 1e6])
    for scale in ("linear", "symlog"):
        np.testing.assert_allclose(inverse(forward(v, scale, 0.01), scale, 0.01), v, rtol=1e-12)
    np.testing.assert_allclose(inverse(forward(v[3:], "log"), "log"), v[3:], rtol=1e-12)
    assert scaled_range((0.0, 100.0), "log", floor=0.1) == pytest.approx((-1.0, 2.0))


def test_a_transfer_function_on_a_log_axis_is_piecewise_linear_in_the_data():
    """Laid out on log10 [-1, 5]: at data values it is the scaled-axis function of
    log10(v) within 1e-3 of its change per knot interval, it carries its scale
    through a preset and `rescaled` stretches it on its own axis."""
    shape = TransferFunction.from_colormap("viridis", (-1.0, 5.0), opacity=(0.0, 0.3, 1.0))
    tf = shape.on_scale("log")
    v = np.logspace(-1, 5, 2001)
    np.testing.assert_allclose(tf.evaluate(v), shape.evaluate(np.log10(v)), atol=1e-3)
    assert tf.value_range == pytest.approx((0.1, 1e5)) and tf.scale == "log"
    back = TransferFunction.from_paraview_dict(tf.to_paraview_dict())
    assert back == tf and back.to_paraview_dict()["Scale"] == "log"
    stretched = tf.rescaled((1.0, 1e3))
    # knots exactly where they map to; between them linear in the data, as any knots
    np.testing.assert_allclose(stretched.evaluate(np.logspace(0, 3, 7)),
                               tf.evaluate(np.logspace(-1, 5, 7)), atol=1e-3)
    assert stretched.value_range == pytest.approx((1.0, 1e3))
    with pytest.raises(ExabricksError, match="positive"):
        TransferFunction([[-1, 0, 0, 0], [1, 1, 1, 1]], [[-1, 0], [1, 1]], scale="log")


@functools.lru_cache(maxsize=None)
def _gerris():
    from exabricks.readers import read

    return build(read(str(GERRIS), fields=["T", "P"])).bricks


def _cells_of(bricks, field):
    """(values, level, centre_lattice) of every cell, in float64 (NumPy reference)."""
    values = np.asarray(bricks.values[bricks.field_index(field)], np.float64)
    counts = np.prod(bricks.dims.astype(np.int64), axis=1)
    level = np.repeat(bricks.level.astype(np.int64), counts)
    local = np.arange(values.size) - np.repeat(bricks.offset, counts)
    dims = np.repeat(bricks.dims.astype(np.int64), counts, axis=0)
    index = np.column_stack([local % dims[:, 0], local // dims[:, 0] % dims[:, 1],
                             local // (dims[:, 0] * dims[:, 1])])
    centre = np.repeat(bricks.lower_lattice.astype(np.float64), counts, axis=0) \
        + (index + 0.5) * (2.0 ** level)[:, None]
    return values, level, centre


def test_the_statistics_agree_with_numpy_in_float64():
    bricks = _gerris()
    values, level, centre = _cells_of(bricks, "T")
    volume = 8.0 ** level
    got = volume_histogram(bricks, "T", "linear", 1.0, (0.0, 0.9), 64)
    want = np.bincount(np.clip(((np.clip(values, 0, 0.9)) * (64 / 0.9)).astype(int), 0, 63),
                       weights=volume, minlength=64)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    tf = TransferFunction([[0, 1, 1, 1], [1, 1, 1, 1]], [[0.0, 0.0], [0.2, 0.1], [0.9, 1.0]])
    weight = np.interp(values, tf.alpha_points[:, 0], tf.alpha_points[:, 1]) * volume
    axes = view_axes()
    world = centre * bricks.spacing_world + bricks.origin_world
    at = world @ axes.T
    lo, span = at.min(0) - 0.3718, np.ptp(at, 0) + 2  # no centre on a bin edge
    along = opacity_along(bricks, "T", tf, axes, lo, span, 100)
    for k in range(3):
        j = np.clip(((at[:, k] - lo[k]) / span[k] * 100).astype(int), 0, 99)
        np.testing.assert_allclose(along[k], np.bincount(j, weights=weight, minlength=100), rtol=1e-9)
    columns = opacity_columns(bricks, "T", tf, axes[:2], lo[:2], span[:2].max() / 40, 40, 1)
    assert columns.sum() == pytest.approx(weight.sum(), rel=1e-9)
    assert smallest_positive(bricks, "T") == pytest.approx(values[values > 0].min())


def test_the_automatic_transfer_function():
    """On the Gerris plume's T: the ambient (T = 0, most of the volume) is
    transparent, the hot core opaque-ish, the colours spread over what is seen,
    and its table is exact enough for the kernels' table lookup."""
    bricks = _gerris()
    tf = automatic_transfer_function(bricks, "T")
    assert tf.scale == "linear" and tf.name == "automatic"
    assert tf.evaluate(0.0)[3] == 0.0 and tf.evaluate(0.8)[3] > 0.1
    assert 0 < tf.alpha_points[:, 1].max() <= 0.9
    table = lookup_table(*tf.merged_knots(np.float64))
    # its knots on KNOT_LATTICE: an exact table of at most that many intervals
    assert len(table.rows) - 2 <= KNOT_LATTICE and table.rows.nbytes <= 16 * (KNOT_LATTICE + 2)
    assert max(table.error_rgb, table.error_alpha) <= 1e-12
    assert tf.table is tf.table  # made once per function
    hist = np.zeros(10)
    hist[[2, 3, 4]] = [0.04, 1.0, 0.06]
    assert ambient_band(hist) == (3, 4)
    # bins 3 and 4 ambient: the low side reaches 0.3, the high side 0.5, which gets
    # the full ramp; the low side (0.3 / 0.5)**2 of it
    shape = opacity_shape((0.0, 1.0), (3, 4), bins=10)
    assert shape[0].tolist() == [0.0, pytest.approx(0.36)] and shape[-1].tolist() == [1.0, 1.0]
    assert np.interp(0.4, shape[:, 0], shape[:, 1]) == 0.0
    iso = suggested_iso_value(bricks, "T")
    assert 0.2 < iso < 0.88  # inside the hot side, where T varies


def test_log_scale_by_default_on_enzo_density():
    from exabricks.readers import read

    bricks = build(read(str(ENZO), fields=["Density"])).bricks
    tf = automatic_transfer_function(bricks, "Density")
    assert tf.scale == "log"
    assert tf.evaluate(0.1)[3] == 0.0 and tf.evaluate(1e4)[3] > tf.evaluate(10.0)[3] > 0


def test_default_field_and_framing():
    assert default_field(("vfrac", "pressure", "Density")) == "Density"
    assert default_field(("volFrac", "afrac_x", "phi")) == "phi"
    assert default_field(("P", "T")) == "P" and default_field(("vfrac",)) == "vfrac"
    bricks = _gerris()
    scene = scene_from_options(bricks, flags={"field": "T"})
    corners = visible_corners(bricks, "T", scene.volumes[0].transfer_function, axes=view_axes())
    assert scene.camera == framed_camera(corners)
    # Every corner of the visible box projects inside the frame, with the margin.
    cam = scene.camera
    o, f = np.asarray(cam.position), np.asarray(cam.look_at) - np.asarray(cam.position)
    f /= np.linalg.norm(f)
    right = np.cross(f, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    rel = corners - o
    tan = np.tan(np.radians(cam.fovy / 2))
    for axis in (right, up):
        assert (np.abs(rel @ axis) / (rel @ f) <= tan * 0.951).all()
    # Nothing visible: the whole dataset is framed.
    none = scene_from_options(bricks, flags={"field": "T", "colormap": "gray", "opacity": (0, 0)})
    lo, hi = schema.world_bounds(bricks)
    assert np.allclose(none.camera.look_at, 0.5 * (np.asarray(lo) + np.asarray(hi)))


LINEAR = np.array([0.3, 0.5, 0.8])  # gradient per world unit
N = 16


@functools.lru_cache(maxsize=1)
def _linear():
    lower = np.stack(np.meshgrid(*[np.arange(N)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = schema.Cells(fields=("f",), origin_world=np.zeros(3), spacing_world=np.full(3, 0.5),
                         lower_lattice=lower.astype(np.int32), level=np.zeros(len(lower), np.int8),
                         values=((0.5 * (lower + 0.5)) @ LINEAR)[None].astype(np.float32))
    return build(cells)


@device_param
@pytest.mark.parametrize("packets", [True, False])
@pytest.mark.parametrize("span", [0.25, 2.0])
def test_the_weighted_headlight_against_its_closed_form(device, packets, span):
    """A linear field, one constant-colour layer whose knots span `span`, rays
    clipped to where the basis is linear: every sample's factor is
    1 - w 0.7 (1 - |n.d|), w = |g|^2 / (1 + |g|^2), |g| = |grad f| h / span
    (SHADING_CELLS = 1 finest cell of width h), so the shaded frame is the
    unshaded one times that factor, per pixel; with sample packets
    (kernels/packet.cl) and one sample at a time (kernels/medium.cl)."""
    built = _linear()
    h = 0.5
    rgb = (0.8, 0.6, 0.3)
    tf = TransferFunction([[1.0, *rgb], [1.0 + span, *rgb]], [[1.0, 0.05], [1.0 + span, 0.05]])
    centre = np.full(3, h * N / 2)
    camera = Camera(tuple(centre + 25.0 * np.array([0.5, 0.3, 0.8])), tuple(centre), (0, 1, 0), 20.0)
    clip = Clip(box=(tuple(np.full(3, 1.5 * h)), tuple(np.full(3, (N - 1.5) * h))))
    size = 24
    settings = Settings(width=size, height=size, jitter=False, max_opacity=1.0)
    frames = {}
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device).with_packets(packets)
    for shading in ("headlight", "none"):
        scene = Scene(camera=camera, volumes=(VolumeLayer("f", tf),), clip=clip,
                      lighting=Lighting(shading=shading), settings=settings)
        frames[shading] = renderer.render_scene(scene).rgba
    _, d = (x.reshape(-1, 3) for x in camera.rays(size, size))
    g = np.linalg.norm(LINEAR) * h / span
    w = g * g / (1 + g * g)
    n = LINEAR / np.linalg.norm(LINEAR)
    factor = 1 - w * 0.7 * (1 - np.abs(d @ n))
    flat = frames["none"].reshape(-1, 4)
    seen = flat[:, 3] > 0.05
    assert seen.sum() > 100
    want = flat[seen, :3] * factor[seen, None]
    np.testing.assert_allclose(frames["headlight"].reshape(-1, 4)[seen, :3], want, rtol=0, atol=2e-5)
