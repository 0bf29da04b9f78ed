"""Annotated pictures (exabricks.film.annotate, docs/annotate.md) of real renders of the
Gerris plume: the scene of docs/examples/plume-scene.json (a volume layer, an
iso-surface coloured by a field, one of a fixed colour, a slice).

- The frame's pixels are those `render` writes to a .png, unchanged (composited
  over black where the background is transparent), and the picture is larger.
- Each colour bar shows its colour map, row by row, over its data range; the
  volume's bar carries its opacity curve.
- Text is light on a dark background and dark on a light one (WCAG contrast).
- The scale bar is a round world length at the look-at depth; the triad's arrows
  point along the world axes as the camera projects them.
- Sizes scale with the frame (512 against 2048; 4096 in the slow suite).
- Facts come from the readers' provenance; bad input is refused; no warnings.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
import pytest

from exabricks.film.annotate import annotate
from exabricks.film.layout import facts_from_meta
from exabricks.film.layout import annotation_layout, font_size, projected_axes
from exabricks.picture.camera import Camera
from exabricks.util.errors import ExabricksError
from exabricks.film.image_io import to_png_pixels
from exabricks.readers import read
from exabricks.engine.renderer import Renderer
from exabricks.scene import scene_from_options
from exabricks.stages.ingest import ingest

from helpers import AMREX, DEVICES, GERRIS, ROOT, build

SCENE = ROOT / "docs" / "examples" / "plume-scene.json"
SIZE = 256
DARK = (0.05, 0.05, 0.08)
LIGHT = (0.96, 0.96, 0.94)
TRANSPARENT = (0.0, 0.0, 0.0, 0.0)

needs_device = pytest.mark.skipif(not DEVICES, reason="no OpenCL device")


@functools.lru_cache(maxsize=None)
def plume():
    return build(read(GERRIS))


@functools.lru_cache(maxsize=None)
def rendered(background: tuple, camera: Camera | None = None):
    """(scene, rgba) of the plume scene at SIZE x SIZE over `background`, one
    sample per pixel (the scene file asks for 4), on the first OpenCL device."""
    built = plume()
    scene = scene_from_options(built.bricks, scene_path=SCENE,
                               flags={"size": (SIZE, SIZE), "spp": 1, "background": background})
    if camera is not None:
        scene = scene.replace(camera=camera)
    renderer = Renderer(built.bricks, built.regions, built.bvh, fields=scene.fields(),
                        device=DEVICES[0])
    return scene, renderer.render_scene(scene).rgba


def annotated(rgba, scene, **kw):
    """`annotate`, with any warning an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return annotate(rgba, scene, **kw)


def contrast(a, b) -> float:
    """WCAG 2 contrast ratio of two 8-bit sRGB colours."""
    def luminance(c):
        c = np.asarray(c, float) / 255.0
        c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        return c @ [0.2126, 0.7152, 0.0722]
    hi, lo = sorted((luminance(a), luminance(b)), reverse=True)
    return (hi + 0.05) / (lo + 0.05)


def ink(region, backdrop8):
    """Mask of the pixels of `region` (h, w, 3+) that differ from the backdrop."""
    return np.any(region[..., :3] != backdrop8, axis=-1)


def backdrop8(background):
    return np.rint(np.asarray(background[:3]) * 255).astype(np.uint8)


# ---------------------------------------------------------------------------------------
# the frame


@needs_device
def test_frame_pixels_are_the_png_pixels_unchanged():
    scene, rgba = rendered(DARK)
    out = annotated(rgba, scene, facts={"time": 1.0}, title="Gerris plume")
    layout = annotation_layout(rgba.shape, scene, facts={"time": 1.0}, title="Gerris plume")
    assert out.dtype == np.uint8 and out.shape == (layout.height, layout.width, 4)
    assert out.shape[0] > SIZE and out.shape[1] > SIZE
    png = to_png_pixels(rgba)
    assert (png[..., 3] == 255).all()  # an opaque background: the frame is opaque
    np.testing.assert_array_equal(out[layout.frame.pixels], png)
    assert len(np.unique(png.reshape(-1, 4), axis=0)) > 1000  # a real picture, not a blank
    assert (out[..., 3] == 255).all()
    # The margins are the background: the corners and the row just outside the frame.
    f = layout.frame
    for row, col in ((0, 0), (-1, -1), (f.y - 1, f.x + f.width // 2), (f.y + 5, f.x - 1)):
        np.testing.assert_array_equal(out[row, col, :3], backdrop8(DARK))


@needs_device
def test_a_transparent_background_is_composited_over_black():
    scene, rgba = rendered(TRANSPARENT)
    out = annotated(rgba, scene)
    layout = annotation_layout(rgba.shape, scene)
    png = to_png_pixels(rgba)
    assert (png[..., 3] < 255).any() and (png[..., 3] == 255).any()
    frame = out[layout.frame.pixels]
    want = np.rint(png[..., :3] * (png[..., 3:] / 255.0)).astype(np.uint8)
    np.testing.assert_array_equal(frame[..., :3], want)
    opaque = png[..., 3] == 255
    np.testing.assert_array_equal(frame[opaque][:, :3], png[opaque][:, :3])
    assert (out[..., 3] == 255).all()
    assert layout.backdrop == (0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------------------
# colour bars


@needs_device
def test_colour_bars_follow_their_colour_maps():
    """One bar per volume layer, colour-mapped iso-surface and slice, in scene order,
    each over its data range; inside its edge (where the axes' spines lie) every
    pixel of a bar without an opacity curve is the colour map's colour at the row's
    value, and nearly every row of the volume's bar is, away from the curve."""
    scene, rgba = rendered(DARK)
    out = annotated(rgba, scene)
    layout = annotation_layout(rgba.shape, scene)
    kinds = [(b.kind, b.value_range) for b in layout.bars]
    assert kinds == [("volume", (0.1, 0.8)), ("isosurface", (-0.06, 0.06)), ("slice", (0.0, 0.15))]
    maps = [scene.volumes[0].transfer_function, scene.isosurfaces[0].colormap,
            scene.slices[0].colormap]
    for bar, colormap in zip(layout.bars, maps):
        assert bar.colormap is colormap
        b = bar.box
        lo, hi = bar.value_range
        values = hi - (np.arange(b.height) + 0.5) / b.height * (hi - lo)
        want = np.rint(colormap.evaluate(values)[:, :3] * 255)
        got = out[b.pixels][..., :3].astype(float)
        inner = np.s_[2:-2, 2:-2]
        if not bar.opacity:
            np.testing.assert_array_equal(got[inner], np.broadcast_to(want[:, None], got.shape)[inner])
        else:
            row_median = np.median(got[inner], axis=1)
            rows_ok = np.all(np.abs(row_median - want[2:-2]) <= 1, axis=1)
            assert rows_ok.mean() > 0.95, rows_ok.mean()
        # the colour map varies along the bar: a gradient, not a flat swatch
        assert np.abs(np.diff(want, axis=0)).sum() > 100
    assert [s.label for s in layout.swatches] == ["iso T = 0.5"]


@needs_device
def test_the_opacity_curve_runs_across_the_volume_bar():
    """In each row of the volume's bar, the pixel farthest from the colour map's
    colour (the curve: white with a black outline) sits where the opacity of the
    row's value puts it: 0 at the left edge, `opacity_top` at the right."""
    scene, rgba = rendered(DARK)
    out = annotated(rgba, scene)
    layout = annotation_layout(rgba.shape, scene)
    bar = layout.bars[0]
    tf = scene.volumes[0].transfer_function
    assert bar.opacity_top == pytest.approx(0.6)  # the scene's highest opacity
    b = bar.box
    values = bar.values()
    want_colour = np.rint(tf.evaluate(values)[:, :3] * 255)
    got = out[b.pixels][..., :3].astype(float)
    far = np.argmax(np.abs(got - want_colour[:, None]).sum(axis=-1), axis=1)
    want_col = tf.evaluate(values)[:, 3] / bar.opacity_top * (b.width - 1)
    error = np.abs(far - want_col)[3:-3]
    assert np.median(error) <= 2.0 and (error <= 0.35 * layout.font_px + 2).mean() > 0.9, error


# ---------------------------------------------------------------------------------------
# text, scale bar, triad


@needs_device
@pytest.mark.parametrize("background, light_text", [(DARK, True), (LIGHT, False)],
                         ids=["dark", "light"])
def test_text_contrasts_with_the_background(background, light_text):
    scene, rgba = rendered(background)
    out = annotated(rgba, scene, title="Gerris buoyant plume")
    layout = annotation_layout(rgba.shape, scene, title="Gerris buoyant plume")
    bg = backdrop8(background)
    title = out[layout.title_box.pixels][..., :3]
    marked = title[ink(title, bg)]
    assert len(marked) > 50
    strongest = max(marked, key=lambda c: contrast(c, bg))
    assert contrast(strongest, bg) >= 12.0
    lighter = strongest.astype(int).sum() > bg.astype(int).sum()
    assert lighter == light_text
    # The tick labels of the bars are drawn in the same colour.
    b = layout.bars[1].box
    ticks = out[b.y:b.y + b.height, b.x + b.width + 3:b.x + b.width + 3 * round(layout.font_px), :3]
    assert any(contrast(c, bg) >= 12.0 for c in ticks[ink(ticks, bg)])


@needs_device
def test_the_scale_bar_is_a_round_world_length():
    scene, rgba = rendered(LIGHT)
    out = annotated(rgba, scene, facts={"length_unit": "cm"})
    layout = annotation_layout(rgba.shape, scene, facts={"length_unit": "cm"})
    cam = scene.camera
    distance = np.linalg.norm(np.subtract(cam.look_at, cam.position))
    pixel_world = 2 * distance * math.tan(math.radians(cam.fovy) / 2) / SIZE
    length = layout.scale_length_world
    mantissa = length / 10 ** math.floor(math.log10(length))
    assert min(abs(mantissa - m) for m in (1, 2, 5)) < 1e-9
    assert 0.1 * SIZE < length / pixel_world <= 0.25 * SIZE
    assert abs(layout.scale_bar.width - length / pixel_world) <= 0.5
    assert layout.scale_text == f"{length:g} cm"
    bar = out[layout.scale_bar.pixels][..., :3]
    text = np.rint(np.asarray(layout.text_color) * 255)
    np.testing.assert_array_equal(bar, np.broadcast_to(text, bar.shape))
    b = layout.scale_bar  # the pixels just beside the bar are the background
    np.testing.assert_array_equal(out[b.y + b.height // 2, [b.x - 2, b.x + b.width + 1], :3],
                                  [backdrop8(LIGHT)] * 2)


def test_projected_axes_of_a_camera_looking_down_z():
    camera = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0)
    np.testing.assert_allclose(projected_axes(camera), np.eye(3), atol=1e-12)
    tilted = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), (1.0, 1.0, 0.0), 30.0)
    s = math.sqrt(0.5)
    np.testing.assert_allclose(projected_axes(tilted)[:2, :2], [[s, s], [-s, s]], atol=1e-12)


@needs_device
@pytest.mark.parametrize("camera", [None, Camera((70.0, 40.0, 250.0), (70.0, 40.0, 64.0),
                                                 (0.0, 1.0, 0.0), 30.0)],
                         ids=["scene-camera", "down-z"])
def test_the_triad_arrows_follow_the_projected_axes(camera):
    """The pixels of each axis's colour around the triad's centre lie, on average,
    along that axis's projection (screen right, screen up); an axis pointing at the
    viewer shows no long arrow."""
    scene, rgba = rendered(DARK, camera)
    out = annotated(rgba, scene).astype(float)
    layout = annotation_layout(rgba.shape, scene)
    cx, cy = layout.triad_centre
    r = layout.triad_radius
    rows, cols = np.mgrid[0:out.shape[0], 0:out.shape[1]]
    near = np.hypot(cols + 0.5 - cx, rows + 0.5 - cy) <= 1.1 * r
    axes = projected_axes(scene.camera)
    colours = np.array([(255, 92, 77), (102, 219, 102), (115, 158, 255)])  # AXIS_COLOURS["dark"]
    distance = np.abs(out[..., None, :3] - colours).sum(axis=-1)  # (H', W', 3 axes)
    inked = np.abs(out[..., :3] - backdrop8(DARK)).sum(axis=-1) > 90
    for i in range(3):
        mine = near & inked & (np.argmin(distance, axis=-1) == i) & (distance[..., i] < 200)
        reach = math.hypot(*axes[i, :2])
        if reach < 0.25:  # seen end-on: a circle at the centre, its label beside it
            assert mine.sum() > 5
            assert np.hypot(cols[mine] + 0.5 - cx, rows[mine] + 0.5 - cy).mean() < 0.6 * r
            continue
        assert mine.sum() > r
        dx = (cols[mine] + 0.5 - cx).mean()
        dy = -(rows[mine] + 0.5 - cy).mean()  # rows grow downwards, screen up is up
        angle = math.degrees(math.atan2(dx * axes[i, 1] - dy * axes[i, 0], dx * axes[i, 0] + dy * axes[i, 1]))
        assert abs(angle) < 12, (i, angle)


# ---------------------------------------------------------------------------------------
# sizes, facts, titles


def ink_rows(picture, box, bg) -> int:
    """Rows of `box` in `picture` holding text."""
    return int(ink(picture[box.pixels], bg).any(axis=1).sum())


@needs_device
def test_sizes_scale_with_the_frame():
    """The same frame at 512 and 2048 (the 256 render repeated): fonts, margins,
    bars and text heights grow 4 times; the 512 picture's text is legible."""
    scene, rgba = rendered(DARK)
    facts = {"time": 1.0}
    pictures, layouts = {}, {}
    for size in (512, 2048):
        frame = np.repeat(np.repeat(rgba, size // SIZE, axis=0), size // SIZE, axis=1)
        pictures[size] = annotated(frame, scene, facts=facts, title="Gerris plume")
        layouts[size] = annotation_layout(frame.shape, scene, facts=facts, title="Gerris plume")
        np.testing.assert_array_equal(pictures[size][layouts[size].frame.pixels],
                                      to_png_pixels(frame))
    small, big = layouts[512], layouts[2048]
    assert small.font_px == pytest.approx(font_size(512, 512)) and small.font_px >= 13
    assert big.font_px == pytest.approx(4 * small.font_px)
    margin = {s: layouts[s].width - layouts[s].frame.width for s in layouts}
    assert margin[2048] == pytest.approx(4 * margin[512], rel=0.05)
    assert big.bars[0].box.width == pytest.approx(4 * small.bars[0].box.width, rel=0.05)
    assert big.scale_bar.width == pytest.approx(4 * small.scale_bar.width, abs=2)
    bg = backdrop8(DARK)
    title = {s: ink_rows(pictures[s], layouts[s].title_box, bg) for s in layouts}
    assert title[512] >= 12
    assert title[2048] == pytest.approx(4 * title[512], rel=0.12)
    time = {s: ink_rows(pictures[s], layouts[s].time_box, bg) for s in layouts}
    assert time[512] >= 9
    assert time[2048] == pytest.approx(4 * time[512], rel=0.15)


@pytest.mark.slow
@needs_device
def test_a_4096_frame_is_annotated_at_its_scale():
    scene, rgba = rendered(LIGHT)
    frame = np.repeat(np.repeat(rgba, 4096 // SIZE, axis=0), 4096 // SIZE, axis=1)
    out = annotated(frame, scene, facts={"time": 0.25}, title="Gerris plume")
    layout = annotation_layout(frame.shape, scene, facts={"time": 0.25}, title="Gerris plume")
    np.testing.assert_array_equal(out[layout.frame.pixels], to_png_pixels(frame))
    assert layout.font_px == pytest.approx(0.027 * 4096)
    assert ink_rows(out, layout.title_box, backdrop8(LIGHT)) >= 90
    assert out.shape[1] - 4096 == pytest.approx(8 * (annotation_layout(
        (512, 512), scene, facts={"time": 0.25}, title="Gerris plume").width - 512), rel=0.05)


@needs_device
@pytest.mark.parametrize("shape", [(16, 16), (48, 256), (256, 40)], ids=["tiny", "wide", "tall"])
def test_small_and_narrow_frames_keep_their_pixels(shape):
    """Pieces of the real frame: the margins grow to hold legible annotations
    (the minimum font size), and the frame stays as it was."""
    scene, rgba = rendered(DARK)
    frame = np.ascontiguousarray(rgba[:shape[0], :shape[1]])
    out = annotated(frame, scene, facts={"time": 1.0}, title="plume")
    layout = annotation_layout(frame.shape, scene, facts={"time": 1.0}, title="plume")
    np.testing.assert_array_equal(out[layout.frame.pixels], to_png_pixels(frame))
    assert layout.font_px == 10.0
    for bar in layout.bars:  # every bar inside the picture, beside the frame
        assert bar.box.x >= layout.frame.x + layout.frame.width
        assert bar.box.y + bar.box.height <= layout.height and bar.box.height >= 40


def test_facts_come_from_the_readers_provenance():
    """AMReX: the time in the plotfile's Header (after the field names and the
    dimension), through `ingest`'s cells meta; the ExaJet cells of the plume record
    no source, so nothing is known."""
    header = (AMREX / "Header").read_text().splitlines()
    time = float(header[2 + int(header[1]) + 1])
    facts = facts_from_meta(ingest(AMREX).meta)
    assert facts == {"time": time, "time_unit": None, "length_unit": None, "field_units": {}}
    assert facts_from_meta(read(AMREX, fields=["phi"]).meta)["time"] == time
    assert facts_from_meta(ingest(GERRIS).meta) == {"time": None, "time_unit": None,
                                                    "length_unit": None, "field_units": {}}
    described = {"source": {"format": "yt", "time": 2.5, "time_unit": "Myr", "length_unit": "kpc",
                            "units": {"density": "g/cm**3", "x": ""}}}
    assert facts_from_meta(described) == {"time": 2.5, "time_unit": "Myr", "length_unit": "kpc",
                                          "field_units": {"density": "g/cm**3"}}
    assert facts_from_meta({"source": {"time": True}})["time"] is None
    assert facts_from_meta(None)["time"] is None


@needs_device
def test_facts_and_title_label_the_picture():
    """Units reach the bar labels and the iso-value caption; the time line and the
    title sit above the frame, and without them the frame starts at the top margin."""
    scene, rgba = rendered(DARK)
    facts = {"time": 0.5, "time_unit": "s", "field_units": {"T": "K", "W": "m/s"}}
    layout = annotation_layout(rgba.shape, scene, facts=facts, title="plume")
    assert [b.label for b in layout.bars] == ["T (K)", "W (m/s)", "V"]
    assert layout.bars[1].caption == "iso T = 0.08 K"
    assert layout.bars[2].caption == "slice y = 20"
    assert layout.time_text == "t = 0.5 s"
    assert layout.time_box.y + layout.time_box.height <= layout.frame.y
    assert layout.title_box.y + layout.title_box.height <= layout.frame.y
    bare = annotation_layout(rgba.shape, scene)
    assert bare.title_box is None and bare.time_box is None
    assert bare.frame.y < layout.frame.y and bare.height < layout.height
    out = annotated(rgba, scene, facts=facts, title="plume")
    assert ink(out[layout.time_box.pixels], backdrop8(DARK)).sum() > 20


@needs_device
def test_bad_input_is_refused():
    scene, rgba = rendered(DARK)
    with pytest.raises(ExabricksError, match="RGBA frame"):
        annotate(rgba[..., :3], scene)
    with pytest.raises(ExabricksError, match="unknown annotation fact"):
        annotate(rgba, scene, facts={"tiem": 1.0})
    with pytest.raises(ExabricksError, match="finite number"):
        annotate(rgba, scene, facts={"time": float("nan")})
    with pytest.raises(ExabricksError, match="Scene"):
        annotate(rgba, {"camera": None})
