"""Annotated pictures of a rendered frame (docs/annotate.md; DESIGN.md "Annotated images").

`annotate(rgba, scene, facts=..., title=...)` returns an opaque 8-bit picture:
the frame, pixel for pixel and uncovered, with margins that hold

- a colour bar per volume layer (its transfer function's colours over its data
  range, with the opacity curve drawn over the bar), per colour-mapped
  iso-surface and per slice, each captioned and labelled with the field and its
  units when known; a colour swatch per iso-surface of a fixed colour;
- the simulation time when known, and an optional title, above the frame;
- a scale bar in world units (at the depth of the camera's look-at point) and an
  axes triad (world x, y, z as the camera projects them) below it.

The frame's pixels are those `render` writes to a ``.png``; where they are not
opaque they are composited over the *backdrop* (the scene's background colour
made opaque, black when the background is fully transparent, as yt's
``save_annotated``), which also fills the margins. Sizes (fonts, lines, bars)
scale with the frame's shorter side; the text is dark or light by the backdrop's
luminance. `annotation_layout` is the geometry alone (where the frame, each bar,
the scale bar and the triad go), for callers and tests.

Drawn with matplotlib's Agg canvas through its object API (no pyplot state).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..util.constants import MAX_TITLE_CHARS
from ..util.errors import ExabricksError
from .image_io import to_png_pixels
from ..scene import Scene
from ..picture.transfer_function import TransferFunction

# Font size in pixels: this fraction of the frame's shorter side (14 px at 512,
# 111 px at 4096), and never below MIN_FONT_PX, so that a small frame stays legible.
FONT_FRACTION = 0.027
MIN_FONT_PX = 10.0

# Every size below is a multiple of the font size.
PAD = 0.8               # outer margin and gaps
TICK_FONT = 0.8         # tick labels, captions, the scale bar's and the triad's labels
TITLE_FONT = 1.3
LINE_HEIGHT = 1.25      # text line height per font size
VOLUME_BAR_WIDTH = 3.0  # wider than a plain bar: the opacity curve runs across it
BAR_WIDTH = 1.6
MIN_BAR_HEIGHT = 4.0
TRIAD_SIZE = 5.0        # the square the axes triad is drawn in
LINE_WIDTH = 0.07       # axes, ticks, triad arrows
END_ON = 0.25           # a triad axis projected shorter than this is drawn end-on

# Text is near-black on a backdrop brighter than this relative luminance, near-white
# otherwise: the luminance at which black and white text have the same contrast ratio
# (WCAG 2: (L + 0.05) / 0.05 = 1.05 / (L + 0.05)).
LUMINANCE_SPLIT = math.sqrt(1.05 * 0.05) - 0.05
DARK_TEXT = (0.08, 0.08, 0.08)
LIGHT_TEXT = (0.94, 0.94, 0.94)

# The triad's x, y, z colours (ParaView's red, green, blue), for dark and light backdrops.
AXIS_COLOURS = {"dark": ((1.0, 0.36, 0.3), (0.4, 0.86, 0.4), (0.45, 0.62, 1.0)),
                "light": ((0.8, 0.1, 0.08), (0.1, 0.5, 0.1), (0.1, 0.25, 0.85))}

# What a picture can state from the provenance (`facts_from_meta`).
FACT_KEYS = ("time", "time_unit", "length_unit", "field_units")

# Rows per band when compositing the frame (bounds the float64 scratch at 4096 px wide).
_BAND_ROWS = 256


# -- facts ---------------------------------------------------------------------------------


def facts_from_meta(meta) -> dict:
    """What an annotated picture can state, from a file's provenance `meta`.

    Reads the source description a reader writes: ``meta["source"]`` of the
    cells a reader returns, ``meta["source"]["source"]`` of a cells file that
    `ingest` wrote (the innermost dict down the ``"source"`` keys; a dict with a
    ``"format"`` key and no ``"source"`` is taken as the description itself).
    Its ``time`` (a number: the AMReX, Athena++ and yt readers record it, in the
    simulation's own units), ``units`` (field name -> unit string: the yt bridge
    records yt's units of each field) and, where a reader gives them,
    ``time_unit`` and ``length_unit`` (strings). Returns ``{"time": float |
    None, "time_unit": str | None, "length_unit": str | None, "field_units":
    {field: unit}}``; what the source does not give is None (or empty). ExaJet
    cells record no source: every fact is unknown.
    """
    source = meta if isinstance(meta, dict) and "source" not in meta and "format" in meta else {}
    inner = meta
    for _ in range(4):  # ingest nests the reader's {"source": ...} under its own "source"
        inner = inner.get("source") if isinstance(inner, dict) else None
        if not isinstance(inner, dict):
            break
        source = inner
    time = source.get("time")
    ok = isinstance(time, (int, float, np.integer, np.floating)) and not isinstance(time, bool)
    units = source.get("units")
    return {
        "time": float(time) if ok and math.isfinite(float(time)) else None,
        "time_unit": _text(source.get("time_unit")),
        "length_unit": _text(source.get("length_unit")),
        "field_units": ({str(k): v for k, v in units.items() if _text(v)}
                        if isinstance(units, dict) else {}),
    }


def _text(value) -> str | None:
    return value if isinstance(value, str) and value.strip() else None


def _checked_facts(facts) -> dict:
    """`facts` (None, or a dict with some of FACT_KEYS) with every key filled in."""
    if facts is None:
        facts = {}
    if not isinstance(facts, dict):
        raise ExabricksError(f"annotation facts must be a dict, got {type(facts).__name__}")
    unknown = sorted(set(facts) - set(FACT_KEYS))
    if unknown:
        raise ExabricksError(f"unknown annotation fact(s) {', '.join(map(repr, unknown))} "
                             f"(known: {', '.join(FACT_KEYS)})")
    time = facts.get("time")
    if time is not None:
        if isinstance(time, bool) or not isinstance(time, (int, float, np.integer, np.floating)) \
                or not math.isfinite(float(time)):
            raise ExabricksError(f"annotation fact 'time' must be a finite number, got {time!r}")
        time = float(time)
    units = facts.get("field_units") or {}
    if not isinstance(units, dict):
        raise ExabricksError("annotation fact 'field_units' must map field names to unit strings")
    return {"time": time, "time_unit": _text(facts.get("time_unit")),
            "length_unit": _text(facts.get("length_unit")),
            "field_units": {str(k): v for k, v in units.items() if _text(v)}}


# -- layout --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Box:
    """A rectangle of the picture: columns x .. x + width - 1, rows y .. y + height - 1
    (row 0 at the top)."""

    x: int
    y: int
    width: int
    height: int

    @property
    def pixels(self):
        """The index of the box in an (H, W, ...) image."""
        return np.s_[self.y:self.y + self.height, self.x:self.x + self.width]


@dataclass(frozen=True)
class ColourBar:
    """A vertical colour bar: `colormap`'s RGB over `value_range`, high at the top.

    kind: "volume" (with the opacity curve over the bar: opacity 0 at the left
    edge, `opacity_top` at the right), "isosurface" (the colour field of an iso-surface) or
    "slice". `value_range` and the bar's axis are on the colour map's scaled axis
    (exabricks.picture.scaling: the data value, or its log or symlog): row r of `box`
    (from its top) shows the scaled value ``hi - (r + 0.5) / box.height * (hi - lo)``.
    """

    kind: str
    caption: str
    label: str
    colormap: TransferFunction
    value_range: tuple[float, float]
    box: Box

    @property
    def opacity(self) -> bool:
        return self.kind == "volume"

    @property
    def opacity_top(self) -> float:
        """The opacity at the bar's right edge (its left edge is 0): the highest
        opacity of the transfer function rounded up to one significant digit (at
        most 1), so that the low opacities of most volume renderings fill the bar."""
        top = float(self.colormap.alpha_points[:, 1].max())
        if top <= 0.0:
            return 1.0
        step = 10.0 ** math.floor(math.log10(top))
        return min(1.0, round(math.ceil(top / step * (1 - 1e-9)) * step, 12))

    def values(self) -> np.ndarray:
        """The data value of each row of the bar (float64 (height,), top row first)."""
        from ..picture.scaling import inverse

        lo, hi = self.value_range
        scaled = hi - (np.arange(self.box.height) + 0.5) / self.box.height * (hi - lo)
        return inverse(scaled, self.colormap.scale, self.colormap.threshold)


@dataclass(frozen=True)
class Swatch:
    """The colour of an iso-surface of a fixed colour, and its caption."""

    label: str
    color: tuple[float, float, float]
    box: Box


@dataclass(frozen=True)
class Layout:
    """Where everything goes in a `width` x `height` picture (pixels, row 0 at the top).

    font_px: the text size; backdrop and text_color: RGB in [0, 1]. title_box /
    time_box: the text lines above the frame (None when absent). scale_bar: the
    bar itself, `scale_length_world` world units long at the look-at depth.
    triad_centre (x, y) and triad_radius: the axes triad (an in-plane axis's
    arrow is `triad_radius` long).
    """

    width: int
    height: int
    frame: Box
    font_px: float
    backdrop: tuple[float, float, float]
    text_color: tuple[float, float, float]
    bars: tuple[ColourBar, ...]
    swatches: tuple[Swatch, ...]
    title: str | None
    title_box: Box | None
    time_text: str | None
    time_box: Box | None
    scale_bar: Box
    scale_length_world: float
    scale_text: str
    triad_centre: tuple[float, float]
    triad_radius: float


def backdrop_color(background) -> tuple[float, float, float]:
    """The opaque colour behind the frame and the margins: the background's RGB, or
    black for a fully transparent background."""
    r, g, b, a = (float(c) for c in background)
    return (r, g, b) if a > 0.0 else (0.0, 0.0, 0.0)


def png_backdrop(scene):
    """The opaque RGB a scene's .png is composited over (`backdrop_color`), or None
    where the scene keeps the frame's alpha (``--transparent``)."""
    if scene is None or scene.settings.transparent:
        return None
    return backdrop_color(scene.background)


def relative_luminance(rgb) -> float:
    """WCAG 2 relative luminance of an sRGB colour in [0, 1]."""
    c = np.asarray(rgb, dtype=np.float64)
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return float(linear @ [0.2126, 0.7152, 0.0722])


def text_color(backdrop) -> tuple[float, float, float]:
    """Near-black text on a bright backdrop, near-white on a dark one."""
    return DARK_TEXT if relative_luminance(backdrop) > LUMINANCE_SPLIT else LIGHT_TEXT


def font_size(height: int, width: int) -> float:
    """Text size in pixels for an `height` x `width` frame."""
    return max(MIN_FONT_PX, FONT_FRACTION * min(height, width))


def scale_length(camera, height: int, width: int) -> tuple[float, float]:
    """(world length, pixels) of the scale bar of an `height` x `width` frame.

    A pixel at the look-at point's depth is ``2 d tan(fovy / 2) / height`` world
    units (d the camera's distance to it; square pixels). The length is the
    largest 1, 2 or 5 x 10^k world units at most a quarter of the frame's width.
    """
    distance = float(np.linalg.norm(np.subtract(camera.look_at, camera.position)))
    pixel_world = 2.0 * distance * math.tan(math.radians(camera.fovy) / 2.0) / height
    target = 0.25 * width * pixel_world
    exponent = math.floor(math.log10(target))
    length = max(m * 10.0 ** exponent for m in (1, 2, 5) if m * 10.0 ** exponent <= target * (1 + 1e-12))
    return length, length / pixel_world


def projected_axes(camera) -> np.ndarray:
    """World x, y, z as the camera sees them: (3, 3) float64, row i the unit vector
    of axis i in (screen right, screen up, toward the viewer) components."""
    _, forward, du, dv = camera.frame(1, 1)
    right, up = du / np.linalg.norm(du), dv / np.linalg.norm(dv)
    return np.column_stack([right, up, -forward])


class _Measure:
    """Text extents in pixels (Agg at 72 dpi: a point is a pixel)."""

    def __init__(self):
        from matplotlib.backends.backend_agg import RendererAgg

        self._renderer = RendererAgg(8, 8, 72)

    def width(self, text: str, size: float, bold: bool = False) -> float:
        from matplotlib.font_manager import FontProperties

        prop = FontProperties(size=size, weight="bold" if bold else "normal")
        return self._renderer.get_text_width_height_descent(text, prop, ismath=False)[0]


def _number(v: float) -> str:
    return f"{v:.4g}"


def _with_unit(text: str, unit: str | None) -> str:
    return f"{text} ({unit})" if unit else text


def _slice_caption(s) -> str:
    n = np.abs(np.asarray(s.normal, dtype=np.float64))
    axis = int(np.argmax(n))
    if n[axis] > 0 and np.all(np.delete(n, axis) == 0):
        return f"slice {'xyz'[axis]} = {_number(s.point[axis])}"
    return "slice"


def _legends(scene: Scene, units: dict) -> tuple[list, list]:
    """(colour bars, swatches) of `scene` without their boxes, in scene order:
    (kind, caption, label, colormap, range) and (label, colour)."""
    from ..picture.scaling import axis_label, forward

    bars, swatches = [], []
    for v in scene.volumes:
        tf = v.transfer_function
        span = tuple(float(x) for x in forward(tf.value_range, tf.scale, tf.threshold))
        bars.append(("volume", "volume", _with_unit(axis_label(v.field, tf.scale), units.get(v.field)),
                     tf, span))
    for s in scene.isosurfaces:
        caption = f"iso {s.field} = {_number(s.value)}"
        if units.get(s.field):
            caption += f" {units[s.field]}"
        if s.colormap is not None:
            rgb = s.colormap.rgb_points
            bars.append(("isosurface", caption, _with_unit(s.color_field, units.get(s.color_field)),
                         s.colormap, (float(rgb[0, 0]), float(rgb[-1, 0]))))
        else:
            opacity = "" if s.opacity == 1.0 else f", opacity {s.opacity:g}"
            swatches.append((caption + opacity, tuple(s.color)))
    for s in scene.slices:
        rgb = s.colormap.rgb_points
        bars.append(("slice", _slice_caption(s), _with_unit(s.field, units.get(s.field)),
                     s.colormap, (float(rgb[0, 0]), float(rgb[-1, 0]))))
    return bars, swatches


def _ticks(lo: float, hi: float, n: int) -> tuple[np.ndarray, list[str]]:
    """Round tick values within [lo, hi] (about `n`) and their labels."""
    from matplotlib.ticker import MaxNLocator

    ticks = MaxNLocator(nbins=max(2, n), steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
    slack = 1e-9 * (hi - lo)
    ticks = ticks[(ticks >= lo - slack) & (ticks <= hi + slack)]
    if len(ticks) < 2:
        ticks = np.array([lo, hi])
    step = float(np.min(np.diff(ticks)))
    ticks = np.where(np.abs(ticks) < 1e-9 * step, 0.0, ticks)
    magnitude = float(np.max(np.abs(ticks)))
    exponent = 0 if 1e-3 <= magnitude < 1e5 or magnitude == 0 else math.floor(math.log10(magnitude))
    scaled_step = step / 10.0 ** exponent
    decimals = next((d for d in range(12) if abs(round(scaled_step, d) - scaled_step)
                     <= 1e-6 * scaled_step), 12)
    suffix = f"e{exponent}" if exponent else ""
    labels = [f"{t / 10.0 ** exponent + 0.0:.{decimals}f}{suffix}" for t in ticks]
    return ticks, labels


def checked_title(title) -> str | None:
    """`title` stripped (None for none or blanks); ExabricksError for what is not text
    or is longer than MAX_TITLE_CHARS (one line above the frame)."""
    if title is not None and not isinstance(title, str):
        raise ExabricksError(f"title must be text, got {type(title).__name__}")
    title = (title.strip() or None) if title else None
    if title is not None and len(title) > MAX_TITLE_CHARS:
        raise ExabricksError(f"title: {len(title):,} characters, more than the one line above "
                             f"the frame holds (at most {MAX_TITLE_CHARS})")
    return title


def annotation_layout(frame_shape, scene: Scene, *, facts=None, title=None) -> Layout:
    """Where `annotate` puts the frame and each annotation, for a frame of
    `frame_shape` (H, W[, ...]) pixels drawn from `scene`. Arguments as `annotate`."""
    if not isinstance(scene, Scene):
        raise ExabricksError(f"annotate needs an exabricks Scene, got {type(scene).__name__}")
    height, width = (int(n) for n in frame_shape[:2])
    if height < 1 or width < 1:
        raise ExabricksError(f"frame size must be positive, got {width}x{height}")
    facts = _checked_facts(facts)
    title = checked_title(title)
    units = facts["field_units"]
    f = font_size(height, width)
    small = TICK_FONT * f
    pad = round(PAD * f)
    measure = _Measure()
    backdrop = backdrop_color(scene.background)

    # Above the frame: the title (left) and the time (right), on one line.
    time_text = None
    if facts["time"] is not None:
        time_text = f"t = {_number(facts['time'])}" + (f" {facts['time_unit']}" if facts["time_unit"] else "")
    top = round(LINE_HEIGHT * TITLE_FONT * f) + pad // 2 if (title or time_text) else 0
    frame = Box(pad, pad + top, width, height)

    # Below the frame: the triad (left), then the scale bar with its label above it.
    triad = round(TRIAD_SIZE * f)
    bottom = pad // 2 + triad
    triad_centre = (frame.x + triad / 2.0, frame.y + height + pad // 2 + triad / 2.0)
    length_world, length_px = scale_length(scene.camera, height, width)
    scale_text = _number(length_world) + (f" {facts['length_unit']}" if facts["length_unit"] else "")
    thickness = max(2, round(0.25 * f))
    scale_x = frame.x + triad + pad
    scale_bar = Box(scale_x, round(triad_centre[1] + 0.25 * f), max(1, round(length_px)), thickness)

    # Beside the frame: columns of legends (caption, label, bar[, opacity axis]).
    bars, swatches = _legends(scene, units)
    line = LINE_HEIGHT * f
    small_line = LINE_HEIGHT * small
    entries = []
    for kind, caption, label, colormap, value_range in bars:
        bar_width = round((VOLUME_BAR_WIDTH if kind == "volume" else BAR_WIDTH) * f)
        _, tick_labels = _ticks(*value_range, 5)
        ticks_width = max(measure.width(t, small) for t in tick_labels)
        text_width = max(measure.width(caption, small), measure.width(label, f))
        overhead = small_line + line + 0.3 * f + (2.2 * small_line if kind == "volume" else 0.0)
        entries.append({"bar": (kind, caption, label, colormap, value_range), "bar_width": bar_width,
                        "width": max(text_width, bar_width + 0.6 * f + ticks_width),
                        "overhead": overhead + pad})
    for label, color in swatches:
        entries.append({"swatch": (label, color), "width": 1.4 * f + measure.width(label, small),
                        "overhead": small_line * 1.3})

    columns, bar_height = _pack(entries, height, MIN_BAR_HEIGHT * f)
    laid_bars, laid_swatches = [], []
    x = frame.x + width + round(1.5 * pad)
    panel_bottom = frame.y + height
    for column in columns:
        y = float(frame.y)
        for e in column:
            if "bar" in e:
                kind, caption, label, colormap, value_range = e["bar"]
                bar_top = y + small_line + line + 0.3 * f
                box = Box(x, round(bar_top), e["bar_width"], bar_height)
                laid_bars.append(ColourBar(kind, caption, label, colormap, value_range, box))
                y += e["overhead"] + bar_height
            else:
                label, color = e["swatch"]
                side = round(0.9 * small)
                laid_swatches.append(Swatch(label, color, Box(x, round(y + 0.2 * small), side, side)))
                y += e["overhead"]
        panel_bottom = max(panel_bottom, round(y))
        x += math.ceil(max(e["width"] for e in column)) + round(1.5 * pad)
    right = x - round(1.5 * pad) + pad if columns else frame.x + width + pad

    # The title may be wider than everything else: the picture grows to hold it.
    title_width = measure.width(title, TITLE_FONT * f, bold=True) if title else 0.0
    time_width = measure.width(time_text, f) if time_text else 0.0
    text_right = frame.x + math.ceil(title_width + (2 * f if title and time_text else 0) + time_width)
    total_width = max(right, text_right + pad, scale_x + scale_bar.width + pad)
    total_height = max(frame.y + height + bottom, panel_bottom) + pad
    title_box = Box(frame.x, pad, math.ceil(title_width), top - pad // 2) if title else None
    time_right = max(frame.x + width, text_right)
    time_box = (Box(time_right - math.ceil(time_width), pad, math.ceil(time_width), top - pad // 2)
                if time_text else None)
    return Layout(total_width, total_height, frame, f, backdrop, text_color(backdrop),
                  tuple(laid_bars), tuple(laid_swatches), title, title_box, time_text, time_box,
                  scale_bar, length_world, scale_text, triad_centre, 0.36 * triad)


def _pack(entries: list, height: int, min_bar: float) -> tuple[list, int]:
    """Legends in the fewest columns (consecutive runs of equal count) whose bars
    can be at least `min_bar` tall beside a frame `height` tall, and the bar height."""
    if not entries:
        return [], 0
    n = len(entries)
    for count in range(1, n + 1):
        per = math.ceil(n / count)
        columns = [entries[i:i + per] for i in range(0, n, per)]
        spare = [(height - sum(e["overhead"] for e in c)) / max(1, sum("bar" in e for e in c))
                 for c in columns if any("bar" in e for e in c)]
        bar = min(spare, default=float(height))
        if bar >= min_bar:
            break
    return columns, max(round(min_bar), math.floor(bar))


# -- drawing -------------------------------------------------------------------------------


def frame_pixels(rgba, backdrop) -> np.ndarray:
    """The frame as the picture shows it: uint8 (H, W, 3).

    The pixels `render` writes to a ``.png`` (`to_png_pixels`: un-premultiplied
    8-bit RGBA); where their alpha is below 255 they are composited over the
    opaque `backdrop` (RGB in [0, 1]), ``rint(rgb * a + (1 - a) * backdrop)``.
    Opaque pixels are unchanged.
    """
    png = to_png_pixels(rgba)
    out = np.ascontiguousarray(png[..., :3])
    behind = np.asarray(backdrop, dtype=np.float64) * 255.0
    for r in range(0, png.shape[0], _BAND_ROWS):
        band = png[r:r + _BAND_ROWS]
        seen = band[..., 3] < 255
        if seen.any():
            a = band[seen, 3:4] / 255.0
            out[r:r + _BAND_ROWS][seen] = np.rint(band[seen, :3] * a + (1.0 - a) * behind)
    return out


def annotate(rgba, scene: Scene, *, facts=None, title=None) -> np.ndarray:
    """The annotated picture of a rendered frame: uint8 (H', W', 4), opaque (alpha 255).

    rgba: (H, W, 4) float32 premultiplied, row 0 at the top, as the renderer returns
    it (already over `scene.background`). scene: the `Scene` it was drawn from
    (camera, volume layers, iso-surfaces, slices, background). facts: what the
    source says (`facts_from_meta`: ``time``, ``time_unit``, ``length_unit``,
    ``field_units``), None when nothing is known. title: text above the frame.

    The frame sits at `annotation_layout(...).frame`, exactly `frame_pixels(rgba,
    backdrop)`: nothing is drawn over it (module docstring). ExabricksError for
    input it cannot draw.
    """
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4 or not np.issubdtype(rgba.dtype, np.floating):
        raise ExabricksError(f"annotate needs a float (H, W, 4) RGBA frame, got {rgba.dtype} "
                             f"{tuple(rgba.shape)}")
    layout = annotation_layout(rgba.shape, scene, facts=facts, title=title)
    picture = _draw(layout, scene)
    picture[layout.frame.pixels + (slice(0, 3),)] = frame_pixels(rgba, layout.backdrop)
    picture[..., 3] = 255
    return picture


def _draw(layout: Layout, scene: Scene) -> np.ndarray:
    """The margins drawn by matplotlib (Agg, object API): uint8 (H', W', 4)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle
    from matplotlib.transforms import IdentityTransform

    width, height = layout.width, layout.height
    # 72 dpi: one point is one pixel, so every size here is in pixels.
    fig = Figure(figsize=(width / 72.0, height / 72.0), dpi=72, facecolor=layout.backdrop)
    canvas = FigureCanvasAgg(fig)
    f, fg = layout.font_px, layout.text_color
    small = TICK_FONT * f
    line_width = max(1.0, LINE_WIDTH * f)

    def fx(x):  # picture column -> figure fraction
        return x / width

    def fy(y):  # picture row (from the top) -> figure fraction (from the bottom)
        return 1.0 - y / height

    def text(x, y, s, size, **kw):
        fig.text(fx(x), fy(y), s, fontsize=size, color=kw.pop("color", fg), parse_math=False,
                 va=kw.pop("va", "top"), ha=kw.pop("ha", "left"), **kw)

    if layout.title_box is not None:
        text(layout.title_box.x, layout.title_box.y, layout.title, TITLE_FONT * f,
             fontweight="bold")
    if layout.time_box is not None:
        b = layout.time_box
        text(b.x + b.width, b.y + b.height / 2.0, layout.time_text, f, ha="right", va="center")

    for bar in layout.bars:
        _draw_bar(fig, bar, height, fx, fy, text, f, fg, line_width)
    for s in layout.swatches:
        b = s.box
        fig.figimage(np.broadcast_to(np.rint(np.asarray(s.color) * 255).astype(np.uint8),
                                     (b.height, b.width, 3)).copy(),
                     xo=b.x, yo=height - b.y - b.height, origin="upper", zorder=1)
        # An outline in the text colour: a pale swatch on a pale backdrop stays visible.
        fig.add_artist(Rectangle((b.x - 0.5, height - b.y - b.height - 0.5), b.width + 1,
                                 b.height + 1, fill=False, edgecolor=fg, linewidth=1.0,
                                 transform=IdentityTransform(), zorder=2))
        text(b.x + b.width + 0.5 * f, b.y + b.height / 2.0, s.label, small, va="center")

    b = layout.scale_bar
    fig.figimage(np.broadcast_to(np.rint(np.asarray(fg) * 255).astype(np.uint8),
                                 (b.height, b.width, 3)).copy(),
                 xo=b.x, yo=height - b.y - b.height, origin="upper", zorder=1)
    text(b.x + b.width / 2.0, b.y - 0.25 * f, layout.scale_text, small, ha="center", va="bottom")

    _draw_triad(fig, layout, scene.camera, fx, fy, small, line_width)
    canvas.draw()
    picture = np.array(canvas.buffer_rgba(), dtype=np.uint8)
    if picture.shape[:2] != (height, width):  # Agg rounds the figure size to whole pixels
        raise ExabricksError(f"annotation canvas is {picture.shape[1]}x{picture.shape[0]}, "
                             f"expected {width}x{height}")
    return picture


def _draw_bar(fig, bar: ColourBar, height: int, fx, fy, text, f, fg, line_width) -> None:
    """A colour bar: its pixels (unresampled), axes with ticks, caption and label;
    for a volume layer the opacity curve over it and an opacity axis under it."""
    import matplotlib.patheffects as pe

    b = bar.box
    colours = np.rint(np.clip(bar.colormap.evaluate(bar.values())[:, :3], 0, 1) * 255).astype(np.uint8)
    fig.figimage(np.repeat(colours[:, None, :], b.width, axis=1), xo=b.x, yo=height - b.y - b.height,
                 origin="upper", zorder=1)
    small = TICK_FONT * f
    text(b.x, b.y - 0.3 * f - LINE_HEIGHT * f, bar.caption, small, va="bottom")
    text(b.x, b.y - 0.3 * f, bar.label, f, va="bottom")

    lo, hi = bar.value_range
    ax = fig.add_axes((fx(b.x), fy(b.y + b.height), fx(b.x + b.width) - fx(b.x),
                       fy(b.y) - fy(b.y + b.height)), zorder=2)
    ax.patch.set_visible(False)
    ax.set_ylim(lo, hi)
    ticks, labels = _ticks(lo, hi, max(2, min(8, int(b.height / (3.0 * f)))))
    ax.set_yticks(ticks, labels)
    ax.yaxis.tick_right()
    ax.tick_params(axis="both", colors=fg, labelsize=small, length=0.35 * f, width=line_width,
                   pad=0.25 * f)
    for spine in ax.spines.values():
        spine.set_color(fg)
        spine.set_linewidth(line_width)
    ax.set_xlim(0.0, 1.0)
    if bar.opacity:
        from ..picture.scaling import forward

        alpha = bar.colormap.alpha_points.copy()
        alpha[:, 0] = forward(alpha[:, 0], bar.colormap.scale, bar.colormap.threshold)
        inside = alpha[(alpha[:, 0] > lo) & (alpha[:, 0] < hi), 0]
        values = np.concatenate([[lo], inside, [hi]])
        opacity = np.interp(values, alpha[:, 0], alpha[:, 1])
        ax.plot(opacity, values, color="white", linewidth=1.6 * line_width, clip_on=False,
                solid_capstyle="butt",
                path_effects=[pe.Stroke(linewidth=3.6 * line_width, foreground="black"), pe.Normal()])
        top = bar.opacity_top
        ax.set_xlim(0.0, top)
        ax.set_xticks([0.0, top], ["0", f"{top:g}"])
        ax.set_xlabel("opacity", fontsize=small, color=fg, labelpad=0.1 * f)
    else:
        ax.set_xticks([])


def _draw_triad(fig, layout: Layout, camera, fx, fy, size, line_width) -> None:
    """World x, y, z arrows from the triad's centre as the camera projects them,
    the farthest first; labels beyond the tips."""
    axes = projected_axes(camera)
    colours = AXIS_COLOURS["light" if layout.text_color == DARK_TEXT else "dark"]
    cx, cy = layout.triad_centre
    r = layout.triad_radius
    # A square axes around the centre, in units of the arrow length.
    span = 1.55 * r
    ax = fig.add_axes((fx(cx - span), fy(cy + span), fx(cx + span) - fx(cx - span),
                       fy(cy - span) - fy(cy + span)), zorder=2)
    ax.set_axis_off()
    ax.set_xlim(-span / r, span / r)
    ax.set_ylim(-span / r, span / r)
    for i in np.argsort(axes[:, 2]):
        dx, dy, dz = axes[i]
        reach = math.hypot(dx, dy)
        if reach >= END_ON:
            ax.annotate("", xy=(dx, dy), xytext=(0.0, 0.0), annotation_clip=False,
                        arrowprops={"arrowstyle": "-|>", "color": colours[i], "lw": 1.6 * line_width,
                                    "mutation_scale": 0.9 * size, "shrinkA": 0, "shrinkB": 0})
            label = (dx, dy) / np.float64(reach) * (reach + 0.3)
        else:
            # Seen end-on: a circle with a dot (toward the viewer) or a cross (away), as
            # in physics diagrams, labelled on the side the other two arrows leave free.
            ax.plot([0.0], [0.0], "o", markersize=0.9 * size, markerfacecolor="none",
                    markeredgecolor=colours[i], markeredgewidth=1.2 * line_width, clip_on=False)
            ax.plot([0.0], [0.0], "." if dz > 0 else "x", markersize=0.5 * size,
                    color=colours[i], markeredgewidth=1.2 * line_width, clip_on=False)
            others = np.delete(axes[:, :2], i, axis=0).sum(axis=0)
            away = -others / max(float(np.linalg.norm(others)), 1e-12)
            label = away * 0.45 if np.linalg.norm(others) > 1e-6 else np.array([-0.45, -0.45])
        ax.text(label[0], label[1], "xyz"[i], color=colours[i], fontsize=size, fontweight="bold",
                ha="center", va="center", parse_math=False)
