"""The geometry of an annotated picture (docs/annotate.md; exabricks.film.annotate
draws it): where the frame, each colour bar and swatch, the title, the scale bar
and the axes triad go, with the sizes of their fonts and lines as multiples of
the font size, which scales with the frame's shorter side, and the colour of
text on the backdrop; and the facts it states (`facts_from_meta`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..picture.transfer_function import TransferFunction
from ..scene import Scene
from ..util.constants import MAX_TITLE_CHARS
from ..util.errors import ExabricksError

# What a picture can state from the provenance (`facts_from_meta`).
FACT_KEYS = ("time", "time_unit", "length_unit", "field_units")


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


def tick_marks(lo: float, hi: float, n: int) -> tuple[np.ndarray, list[str]]:
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
        _, tick_labels = tick_marks(*value_range, 5)
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
