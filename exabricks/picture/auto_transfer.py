"""The automatic transfer function: what a render shows when it is given none
(docs/scene.md, "Defaults that show the data").

It is made from the field's *volume-weighted* histogram on its scaled axis
(exabricks.picture.scaling; log for a positive field spanning more than two decades),
over the span that holds all but TAIL of the volume at either end
(`volume_percentiles`), so that a few outlying cells cannot take the axis:

1. The ambient value is the histogram's mode: the value that fills the most
   space (the quiet medium around a blast, the cold gas of a cosmology box, the
   unheated fluid around a plume). It and the bins around it that hold at least
   `AMBIENT_SHOULDER` of the mode's volume (the ambient medium's own noise) are
   transparent.
2. Opacity then grows with the fourth power of the distance from that band on
   the scaled axis (`RAMP_POWER`), on each side, to its largest value at the
   field's extremes: what differs most from the surroundings shows most. The
   side that reaches less far is scaled by the square of its reach over the
   other's: a few cells slightly below the ambient value (the corners of a
   box around a dense core) stay clear, a void as deep as the shell around it
   is high (a blast) shows as the shell does. On a log axis (a positive field
   over decades: a density) only what lies above the ambient band shows: the
   decades below it are tails and voids (a Gaussian blob's 37 decades of tails
   would otherwise outshine the blob).
3. The opacity's height is set so that the rays of the default view through
   the visible part cross an optical depth of at most about `TARGET_DEPTH`
   (all but the thickest tenth of them): the opacity (sigma x volume) of the
   cells summed over columns along the view (`column_depths`).
4. The colours are `colormap` spread over the values by the share of that
   opacity (volume x opacity) below each (`equalised_colours`, Chourasia and
   Schulze's opacity-weighted histogram equalisation), so that every colour
   covers as much of what is seen: nested shells and a core in distinct
   colours, however many decades apart. Over a range given, the colours span
   it evenly instead.
5. The opacity is drawn in LAYERS smooth bands at even shares of that same
   opacity (`layered`; yt's add_layers, placed by the histogram), so that
   nested shells and fronts show as bands of their own colour, with edges.

The result is an ordinary piecewise-linear function of the data value
(`TransferFunction.on_scale`), so every renderer, the scene file and the colour
bar take it as any other.
"""

from __future__ import annotations

import math

import numpy as np

from .field_statistics import field_range, opacity_columns, smallest_positive, volume_histogram
from .scaling import BRIGHT, default_threshold, resolve, scaled_range
from .transfer_function import (TransferFunction, matplotlib_colormap, strictly_increasing,
                                widen_degenerate_range)

# Bins of the volume-weighted histogram over the scaled range.
HISTOGRAM_BINS = 256
# The share of the volume at either end of the field's range that the automatic
# axis leaves out (values beyond take the colour and opacity of its ends), found
# on a histogram of PERCENTILE_BINS bins.
TAIL = 1e-6
PERCENTILE_BINS = 4096
# Bins next to the mode holding at least this share of its volume are ambient too.
AMBIENT_SHOULDER = 0.05
# The opacity's rise with the distance from the ambient band: a power of it, so that
# what differs most from the surroundings stands out of the haze around it.
RAMP_POWER = 4.0
RAMP_KNOTS = 17
# Share of the opacity whose values lie below (above) the colour map's ends.
COLOUR_TRIM = 0.005
# The opacity's layers: LAYERS bands at even shares of the opacity, each drawn
# with LAYER_KNOTS knots, the opacity between them LAYER_FLOOR of the shape's,
# their profile a raised cosine to the power LAYER_SHARPNESS.
LAYERS = 5
LAYER_KNOTS = 8
LAYER_FLOOR = 0.3
LAYER_SHARPNESS = 1.0
# Samples per finest cell width of a region that a frame of only automatic transfer
# functions takes by default (exabricks.scene.build): at the default 2 their layers
# and colours alias into moire on the Gerris cap and the Enzo halo (fine detail
# 3.3-6x that of 16 samples a pixel unshaded; 1.4-1.75x at 4; docs/scene.md).
AUTOMATIC_SAMPLING_RATE = 4.0
# Bins on each side over which the suggested iso-value's steepness is smoothed, and
# the share of the scaled axis next to the ambient band it keeps away from.
ISO_SMOOTHING = 4
ISO_MARGIN = 0.05
# Colours of the equalised colour map (the knots of its piecewise-linear function).
COLOUR_KNOTS = 33
# The optical depth of the DEPTH_QUANTILE of the default view's columns through
# the visible part (column_depths, COLUMN_BINS across the data): the thickest
# tenth of the visible part stays translucent enough to see into.
TARGET_DEPTH = 2.0
DEPTH_QUANTILE = 0.9
COLUMN_BINS = 96
# Most points per axis a cell is spread over its columns with.
SPLAT = 8
# Intervals of the lattice over the scaled axis that every knot lies on, so that
# a linear-scaled function is looked up exactly from a table of at most this
# many intervals (transfer_function.lookup_table; 16 KiB a layer).
KNOT_LATTICE = 4 * HISTOGRAM_BINS
# The most opacity per unit distance any value gets.
MAX_ALPHA = 0.9
DEFAULT_NAME = "automatic"


def ambient_band(histogram: np.ndarray) -> tuple[int, int]:
    """(first, last) bin of the ambient band: the mode and the bins next to it
    holding at least AMBIENT_SHOULDER of its volume."""
    mode = int(np.argmax(histogram))
    floor = AMBIENT_SHOULDER * histogram[mode]
    first = last = mode
    while first > 0 and histogram[first - 1] >= floor:
        first -= 1
    while last < len(histogram) - 1 and histogram[last + 1] >= floor:
        last += 1
    return first, last


def opacity_shape(axis_range, band, bins: int = HISTOGRAM_BINS, *, below: bool = True) -> np.ndarray:
    """Opacity knots ``[[s, r], ...]`` of the shape: 0 over the ambient band and
    rising as the power RAMP_POWER of the distance from it to each end of
    `axis_range` that lies beyond it (RAMP_KNOTS knots a side), there 1 on the
    side that reaches further and (its reach / the other's)**2 on the other;
    0 below the band unless `below`."""
    a, b = axis_range
    width = (b - a) / bins
    low, high = a + band[0] * width, a + (band[1] + 1) * width
    if not below:
        a = low
    reach = max(low - a, b - high)
    t = np.linspace(0.0, 1.0, RAMP_KNOTS)
    top_left, top_right = ((low - a) / reach) ** 2 if reach > 0 else 0.0, \
        ((b - high) / reach) ** 2 if reach > 0 else 0.0
    left = [(low - (low - a) * u, top_left * u ** RAMP_POWER) for u in t[::-1]] \
        if low > a else [(low, 0.0)]
    right = [(high + (b - high) * u, top_right * u ** RAMP_POWER) for u in t] \
        if high < b else [(high, 0.0)]
    return strictly_increasing(np.asarray(left + right, np.float64))


def on_lattice(knots: np.ndarray, axis_range) -> np.ndarray:
    """`knots` (rows [x, ...]) with each x moved to the nearest node of
    KNOT_LATTICE even intervals over `axis_range`, those that land on the node
    of the one before dropped."""
    a, b = axis_range
    at = np.rint((knots[:, 0] - a) * (KNOT_LATTICE / (b - a)))
    snapped = knots.copy()
    snapped[:, 0] = a + (b - a) * (at / KNOT_LATTICE)
    return strictly_increasing(snapped)


def _opacity_by_bin(histogram: np.ndarray, shape: np.ndarray, axis_range):
    """(bin centres on the scaled axis, volume x `shape` in each bin)."""
    a, b = axis_range
    centres = a + (np.arange(len(histogram)) + 0.5) * (b - a) / len(histogram)
    return centres, histogram * np.interp(centres, shape[:, 0], shape[:, 1])


def _at_shares(shares: np.ndarray, histogram: np.ndarray, shape: np.ndarray, axis_range):
    """The values on the scaled axis below which each of `shares` of the opacity
    (volume x `shape`) lies; None where there is none."""
    a, b = axis_range
    _, weight = _opacity_by_bin(histogram, shape, axis_range)
    if not weight.sum() > 0:
        return None
    cumulative = np.concatenate([[0.0], np.cumsum(weight) / weight.sum()])
    return np.interp(shares, cumulative, np.linspace(a, b, len(histogram) + 1))


def equalised_colours(colormap: str, histogram: np.ndarray, shape: np.ndarray,
                      axis_range) -> TransferFunction:
    """`colormap` over the scaled axis, each of COLOUR_KNOTS evenly spaced
    colours at the value below which that share of the opacity (volume x
    `shape`, all but COLOUR_TRIM at either end) lies: colours spread by what
    is seen (module docstring, 4); evenly over `axis_range` where nothing is."""
    shares = np.linspace(COLOUR_TRIM, 1.0 - COLOUR_TRIM, COLOUR_KNOTS)
    at = _at_shares(shares, histogram, shape, axis_range)
    colours = np.asarray(matplotlib_colormap(colormap)(np.linspace(0.0, 1.0, COLOUR_KNOTS)))[:, :3]
    knots = None if at is None else strictly_increasing(np.column_stack([at, colours]))
    if knots is None or len(knots) < 2:
        return TransferFunction.from_colormap(colormap, axis_range)
    alpha = np.array([[knots[0, 0], 1.0], [knots[-1, 0], 1.0]])
    return TransferFunction(knots, alpha, DEFAULT_NAME)


def layered(shape: np.ndarray, histogram: np.ndarray, axis_range) -> np.ndarray:
    """`shape` times LAYERS smooth layers, placed as the equalised colours are
    (at even shares of the opacity): between two layers the opacity falls to
    LAYER_FLOOR of the shape's, so that nested shells and fronts show as bands
    of their own colour (yt's add_layers, placed by the histogram)."""
    shares = np.linspace(0.0, 1.0, LAYERS * LAYER_KNOTS + 1)
    at = _at_shares(shares, histogram, shape, axis_range)
    if at is None:
        return shape
    wave = 0.5 - 0.5 * np.cos(2.0 * np.pi * LAYERS * shares)  # peaks at (k + 1/2) / LAYERS
    modulation = LAYER_FLOOR + (1.0 - LAYER_FLOOR) * wave ** LAYER_SHARPNESS
    xs = np.union1d(shape[:, 0], at)
    keep = np.concatenate([[True], np.diff(at) > 0])
    factor = np.interp(xs, at[keep], modulation[keep])
    return strictly_increasing(np.column_stack([xs, np.interp(xs, shape[:, 0], shape[:, 1]) * factor]))


def field_axis(bricks, field: str, scale: str | None = None):
    """(scale, symlog threshold, finite range widened where constant, smallest
    positive value or None) of `field` for `scale` (None: auto; exabricks.picture.scaling)."""
    data_range = widen_degenerate_range(field_range(bricks, field))
    floor = smallest_positive(bricks, field) if data_range[0] <= 0 < data_range[1] else None
    bright = None
    if scale in (None, "auto"):
        volume = volume_histogram(bricks, field, "linear", 1.0, data_range, round(1 / BRIGHT))
        bright = float(volume[1:].sum() / volume.sum()) if volume.sum() > 0 else 0.0
    return (resolve(scale, data_range, floor, bright), default_threshold(data_range), data_range,
            floor)


def volume_percentiles(bricks, field: str, scale: str, threshold: float, axis_range):
    """The span of the scaled axis `axis_range` that holds all but TAIL of the
    volume at either end: an axis that a few outlying cells, or the far tails
    of a distribution, cannot take. Found on a histogram of PERCENTILE_BINS
    bins, then again on one over the span found (values beyond it in its end
    bins), to 1/PERCENTILE_BINS of what the outliers leave."""
    for _ in range(2):
        a, b = axis_range
        volume = volume_histogram(bricks, field, scale, threshold, axis_range, PERCENTILE_BINS)
        if not volume.sum() > 0:
            return axis_range
        cumulative = np.cumsum(volume) / volume.sum()
        width = (b - a) / PERCENTILE_BINS
        lo = a + width * int(np.searchsorted(cumulative, TAIL, side="right"))
        hi = min(b, a + width * (int(np.searchsorted(cumulative, 1.0 - TAIL)) + 1))
        if not hi > lo:
            return axis_range
        axis_range = (lo, hi)
    return axis_range


def _ambient_shape(bricks, field: str, scale, value_range):
    """(scale, threshold, scaled axis, histogram, ambient band, opacity shape) of
    `field` over `value_range` (None: its volume percentiles, `volume_percentiles`)."""
    scale, threshold, data_range, floor = field_axis(bricks, field, scale)
    axis = scaled_range(tuple(value_range) if value_range else data_range, scale, threshold, floor)
    if not value_range:
        axis = volume_percentiles(bricks, field, scale, threshold, axis)
    histogram = volume_histogram(bricks, field, scale, threshold, axis, HISTOGRAM_BINS)
    band = ambient_band(histogram)
    return scale, threshold, axis, histogram, band, opacity_shape(axis, band, below=scale != "log")


def automatic_transfer_function(bricks, field: str, *, scale: str | None = None,
                                value_range=None, colormap: str = "viridis",
                                unit_distance: float | None = None) -> TransferFunction:
    """The automatic transfer function of `field` (module docstring).

    `scale`: "auto" (None), "linear", "log" or "symlog". `value_range`: the data
    range the colours span (default: the field's finite range). `unit_distance`:
    the world thickness alpha is the opacity of (default: the finest cell width).
    """
    scale, threshold, axis, histogram, _, shape = _ambient_shape(bricks, field, scale, value_range)
    colours = (TransferFunction.from_colormap(colormap, axis) if value_range
               else equalised_colours(colormap, histogram, shape, axis))
    shape = layered(shape, histogram, axis)
    unit = TransferFunction(on_lattice(colours.rgb_points, axis), on_lattice(shape, axis),
                            DEFAULT_NAME).on_scale(scale, threshold)
    sigma = _sigma_for_depth(bricks, field, unit, unit_distance)
    alpha = unit.alpha_points.copy()
    alpha[:, 1] = np.minimum(1.0 - np.exp(-sigma * alpha[:, 1]), MAX_ALPHA)
    return TransferFunction(unit.rgb_points, alpha, DEFAULT_NAME, scale, threshold)


def suggested_iso_value(bricks, field: str, *, scale: str | None = None) -> float:
    """An iso-value of `field` whose surface is well defined: among the values
    that the automatic opacity shows, at least ISO_MARGIN of the scaled axis
    beyond the ambient band (`ambient_band`; its own noise makes ragged
    surfaces), the one that the field crosses most steeply over the largest
    area: the peak of `steepness_histogram` (area x steepness) smoothed over
    ISO_SMOOTHING bins a side, so that neither a flat ridge (crossed nowhere
    steeply) nor a level that many cells hold exactly (a plateau's own value)
    is chosen; in data units. Where no such value is, the ambient value."""
    from .field_statistics import steepness_histogram
    from .scaling import inverse

    scale, threshold, axis, histogram, band, shape = _ambient_shape(bricks, field, scale, None)
    a, b = axis
    centres = a + (np.arange(HISTOGRAM_BINS) + 0.5) * (b - a) / HISTOGRAM_BINS
    steep = steepness_histogram(bricks, field, scale, threshold, axis, HISTOGRAM_BINS)
    kernel = np.hanning(2 * ISO_SMOOTHING + 3)[1:-1]
    steep = np.convolve(steep, kernel / kernel.sum(), mode="same")
    width = (b - a) / HISTOGRAM_BINS
    low, high = a + band[0] * width, a + (band[1] + 1) * width
    near = np.maximum(low - centres, centres - high) < ISO_MARGIN * (b - a)
    steep[near | (np.interp(centres, shape[:, 0], shape[:, 1]) <= 0.0)] = 0.0  # or nothing seen
    if not steep.max() > 0:
        return float(inverse(centres[band[0]], scale, threshold))
    return float(inverse(centres[int(np.argmax(steep))], scale, threshold))


def _sigma_for_depth(bricks, field: str, unit: TransferFunction, unit_distance) -> float:
    """The extinction (per `unit_distance`) that the shape `unit` (alpha read as a
    relative extinction in [0, 1]) is scaled by so that the rays of the default
    view through the visible part see an optical depth of at most about
    TARGET_DEPTH: the DEPTH_QUANTILE of `column_depths` over the covered columns."""
    spacing = np.asarray(bricks.spacing_world, np.float64)
    finest = float(2.0 ** int(bricks.level.min()) * spacing.min()) if bricks.n_bricks else 1.0
    unit_distance = float(unit_distance or finest)
    columns = column_depths(bricks, field, unit)
    covered = columns[columns > 0]
    if covered.size == 0:
        return 1.0
    depth = float(np.quantile(covered, DEPTH_QUANTILE))  # in lattice units x relative extinction
    sigma = TARGET_DEPTH / depth * unit_distance / float(spacing.min())
    return sigma if math.isfinite(sigma) and sigma > 0 else 1.0


def column_depths(bricks, field: str, unit: TransferFunction, bins: int = COLUMN_BINS) -> np.ndarray:
    """(bins, bins) float64: the relative extinction (`unit`'s alpha) of `field`
    summed along the default view's rays (framing.view_axes) through `bins` x
    `bins` square columns across the data, in lattice units of length."""
    from .camera import box_corners
    from ..formats.kinds import world_bounds
    from .framing import view_axes

    axes = view_axes()[:2]
    along = box_corners(*(np.asarray(b, np.float64) for b in world_bounds(bricks))) @ axes.T
    lower = along.min(0)
    size = max(float((along.max(0) - lower).max()), 1e-300) / bins  # world units
    mass = opacity_columns(bricks, field, unit, axes, lower, size, bins, SPLAT)
    lattice = size / float(np.asarray(bricks.spacing_world, np.float64).min())
    return mass / (lattice * lattice)
