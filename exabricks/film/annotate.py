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
luminance. `annotation_layout` (exabricks.film.layout) is the geometry alone
(where the frame, each bar, the scale bar and the triad go), for callers and
tests; this module draws it.

Drawn with matplotlib's Agg canvas through its object API (no pyplot state).
"""

from __future__ import annotations

import math

import numpy as np

from ..util.errors import ExabricksError
from .image_io import to_png_pixels
from .layout import (AXIS_COLOURS, DARK_TEXT, END_ON, LINE_HEIGHT, LINE_WIDTH, TICK_FONT, TITLE_FONT, ColourBar,
                     Layout, annotation_layout, backdrop_color, projected_axes, tick_marks)
from ..scene import Scene


# Rows per band when compositing the frame (bounds the float64 scratch at 4096 px wide).
_BAND_ROWS = 256


def png_backdrop(scene):
    """The opaque RGB a scene's .png is composited over (`backdrop_color`), or None
    where the scene keeps the frame's alpha (``--transparent``)."""
    if scene is None or scene.settings.transparent:
        return None
    return backdrop_color(scene.background)


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
    ticks, labels = tick_marks(lo, hi, max(2, min(8, int(b.height / (3.0 * f)))))
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
