"""Transfer functions: data value -> RGBA, piecewise linear, as in ParaView presets.

A `TransferFunction` holds RGB knots ``[x, r, g, b]`` and opacity knots
``[x, alpha]``; each is piecewise linear in the data value ``x`` and clamps to
its first/last knot outside its range (docs/design-rendering.md, "Transfer functions and volume layers").
`evaluate` is the float64 reference; `merged_knots` is the exact representation
the OpenCL kernel interpolates; `any_alpha` says where opacity is above zero over
value intervals, so the renderer can skip transparent BVH nodes and regions (the
majorant idea of paper §3.3/§4.1).

Opacity unit: ``alpha`` is the opacity of a slab of thickness
``unit_distance`` (world units); a step of length ``dt`` has opacity
``1 - (1 - alpha) ** (dt / unit_distance)`` (paper §4.3) -- `opacity_correct`.

Reading ParaView presets (``File > Export`` of a colour map, or the files in
ParaView's ``ColorMaps.json``): the ``Points`` midpoint/sharpness values are
ignored (linear between knots), ``ColorSpace`` is ignored (RGB interpolation,
as ParaView does for ``"RGB"``), knots must be strictly increasing in x, and a
preset without ``Points`` gets an opacity ramp from 0 at its first RGB x to 1
at its last.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..util.constants import FLOAT32_MAX, MAX_KNOTS
from ..util.errors import ExabricksError
from .scaling import SCALES

# Knots of a matplotlib colormap shortcut: matplotlib's own lookup tables have 256
# entries, so 256 evenly spaced knots reproduce them (`from_colormap`).
COLORMAP_KNOTS = 256

DEFAULT_PRESET = "default"


def opacity_correct(alpha, dt, unit_distance):
    """Opacity of a step of length `dt` given slab opacity `alpha` per `unit_distance`.

    Float64 reference of paper §4.3: ``1 - (1 - alpha) ** (dt / unit_distance)``.
    `alpha` in [0, 1], `dt` >= 0 and `unit_distance` > 0 in world units;
    arrays broadcast.
    """
    alpha = np.asarray(alpha, dtype=np.float64)
    exponent = np.asarray(dt, dtype=np.float64) / np.asarray(unit_distance, dtype=np.float64)
    return 1.0 - np.power(1.0 - alpha, exponent)


def _knots(points, width: int, what: str, where: str) -> np.ndarray:
    """Knots as (n, width) float64 from a flat list or (n, width) rows, checked.

    x (column 0) must be strictly increasing and column 1 (the first colour
    channel or alpha) onwards in [0, 1] -- except the ParaView ``Points``
    midpoint/sharpness columns 2-3, which are ignored. At most MAX_KNOTS knots,
    refused before the numbers are looked at. ExabricksError otherwise.
    """
    if isinstance(points, np.ndarray):
        n = points.shape[0] if points.ndim == 2 else points.size // width
    elif isinstance(points, (list, tuple)):
        n = len(points) if points and isinstance(points[0], (list, tuple)) else len(points) // width
    else:
        n = 0
    if n > MAX_KNOTS:
        raise ExabricksError(f"{where}: {what} holds more than {MAX_KNOTS:,} knots")
    if isinstance(points, (list, tuple)) and points and all(isinstance(p, (list, tuple)) for p in points):
        try:  # rows given as nested lists (Python callers; presets are flat)
            points = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise ExabricksError(f"{where}: {what} rows must all be {width} numbers") from None
    if isinstance(points, np.ndarray) and points.ndim == 2:
        if points.shape[1] != width:
            raise ExabricksError(f"{where}: {what} must have {width} columns, got shape {points.shape}")
        array = points.astype(np.float64)
    else:
        if isinstance(points, np.ndarray):
            points = points.reshape(-1).tolist()
        if not isinstance(points, (list, tuple)) or not all(
            isinstance(p, (int, float)) and not isinstance(p, bool) for p in points
        ):
            raise ExabricksError(f"{where}: {what} must be a flat list of numbers")
        if len(points) == 0 or len(points) % width:
            raise ExabricksError(f"{where}: {what} length {len(points)} is not a positive multiple of {width}")
        array = np.asarray(points, dtype=np.float64).reshape(-1, width)
    if len(array) == 0:
        raise ExabricksError(f"{where}: {what} is empty")
    if not np.isfinite(array).all():
        bad = int(np.argwhere(~np.isfinite(array))[0, 0])
        raise ExabricksError(f"{where}: {what} knot {bad} has a non-finite value: {array[bad].tolist()}")
    x = array[:, 0]
    step = np.diff(x)
    if (step <= 0).any():
        i = int(np.argmax(step <= 0)) + 1
        raise ExabricksError(
            f"{where}: {what} x values must be strictly increasing (knot {i}: x = {x[i]:g} after {x[i - 1]:g})"
        )
    is_opacity = what == "Points"
    values = array[:, 1:2] if is_opacity else array[:, 1:]
    outside = (values < 0) | (values > 1)
    if outside.any():
        i = int(np.argwhere(outside)[0, 0])
        name = "alpha" if is_opacity else "colour"
        raise ExabricksError(f"{where}: {what} knot {i} has {name} outside [0, 1]: {array[i].tolist()}")
    return np.ascontiguousarray(array)


@dataclass(frozen=True, eq=False)
class TransferFunction:
    """Piecewise-linear RGBA of the data value.

    rgb_points:   (n, 4) float64 ``[x, r, g, b]``, x strictly increasing, colour in [0, 1].
    alpha_points: (m, 2) float64 ``[x, alpha]``, x strictly increasing, alpha in [0, 1]
                  (the opacity of a slab of thickness ``unit_distance``).
    x is in the units of the rendered field.
    """

    rgb_points: np.ndarray
    alpha_points: np.ndarray
    name: str = "custom"
    # How the knots were laid out and the colour bar reads them (exabricks.picture.scaling):
    # "linear", "log" or "symlog" with the linear threshold `threshold`.
    scale: str = "linear"
    threshold: float = 1.0

    def __post_init__(self):
        where = f"transfer function {self.name!r}"
        if self.scale not in SCALES[1:] or not (math.isfinite(self.threshold) and self.threshold > 0):
            raise ExabricksError(f"{where}: scale must be one of {', '.join(SCALES[1:])} with a "
                                 f"positive threshold, got {self.scale!r}, {self.threshold!r}")
        if self.scale != "symlog":
            object.__setattr__(self, "threshold", 1.0)  # only symlog has one
        rgb = _knots(self.rgb_points, 4, "RGBPoints", where)
        alpha = _knots(self.alpha_points, 2, "Points", where)
        if self.scale == "log" and min(rgb[0, 0], alpha[0, 0]) <= 0:
            raise ExabricksError(f"{where}: a log scale needs knots at positive values")
        rgb.setflags(write=False)
        alpha.setflags(write=False)
        object.__setattr__(self, "rgb_points", rgb)
        object.__setattr__(self, "alpha_points", alpha)

    def __eq__(self, other):
        if not isinstance(other, TransferFunction):
            return NotImplemented
        return (self.name == other.name and np.array_equal(self.rgb_points, other.rgb_points)
                and np.array_equal(self.alpha_points, other.alpha_points)
                and (self.scale, self.threshold) == (other.scale, other.threshold))

    __hash__ = None

    # -- construction -------------------------------------------------------------------

    @classmethod
    def from_paraview_dict(cls, preset, *, source: str = "transfer function") -> TransferFunction:
        """From a parsed ParaView preset: an object, or a list whose first element is used."""
        if isinstance(preset, list):
            if not preset:
                raise ExabricksError(f"{source}: empty list, expected a ParaView colour-map preset")
            preset = preset[0]
        if not isinstance(preset, dict):
            raise ExabricksError(f"{source}: expected a ParaView colour-map preset object, got {type(preset).__name__}")
        if "RGBPoints" not in preset:
            raise ExabricksError(f"{source}: ParaView preset has no 'RGBPoints'")
        name = preset.get("Name", Path(source).stem)
        if not isinstance(name, str):
            name = str(name)
        rgb = _knots(preset["RGBPoints"], 4, "RGBPoints", source)
        if "Points" in preset:
            alpha = _knots(preset["Points"], 4, "Points", source)[:, :2]
        elif len(rgb) == 1:
            alpha = np.array([[rgb[0, 0], 1.0]])
        else:
            # No opacity in the preset: a linear ramp over the colour range (module docstring).
            alpha = np.array([[rgb[0, 0], 0.0], [rgb[-1, 0], 1.0]])
        scale, threshold = preset.get("Scale", "linear"), preset.get("LinearThreshold", 1.0)
        if scale not in SCALES[1:] or isinstance(threshold, bool) or not isinstance(threshold, (int, float)):
            raise ExabricksError(f"{source}: 'Scale' must be one of {', '.join(SCALES[1:])} and "
                                 f"'LinearThreshold' a positive number")
        return cls(rgb, alpha, name, scale, float(threshold))

    @classmethod
    def from_paraview(cls, path) -> TransferFunction:
        """Read a ParaView colour-map preset JSON file; ExabricksError naming the file if bad."""
        from ..util.jsonfile import read_json

        preset = read_json(path, "transfer function", parse_constant=_reject_constant)
        return cls.from_paraview_dict(preset, source=str(path))

    @classmethod
    def from_colormap(cls, name: str, value_range, *, opacity=(0.0, 1.0)) -> TransferFunction:
        """A matplotlib colormap over `value_range` with opacity knots evenly spaced over it.

        The colours are the colormap sampled at `COLORMAP_KNOTS` evenly spaced
        knots from ``value_range[0]`` to ``value_range[1]`` (matplotlib's own
        256-entry tables, reproduced exactly), so this is the same
        piecewise-linear function as a preset holding those knots. `opacity`:
        alpha values at evenly spaced knots over the range ((0, 1) is a linear
        ramp; one value is a constant).
        """
        lo, hi = _range(value_range, f"colormap {name!r}")
        cmap = matplotlib_colormap(name)
        t = np.linspace(0.0, 1.0, COLORMAP_KNOTS)
        xs = lo + (hi - lo) * t
        rgb = np.column_stack([xs, np.asarray(cmap(t), dtype=np.float64)[:, :3]])
        alphas = np.atleast_1d(np.asarray(opacity, dtype=np.float64))
        if alphas.ndim != 1 or alphas.size == 0:
            raise ExabricksError(f"colormap {name!r}: opacity must be a non-empty list of alpha values")
        if alphas.size > MAX_KNOTS:
            raise ExabricksError(f"colormap {name!r}: {alphas.size:,} opacity knots, at most "
                                 f"{MAX_KNOTS:,}")
        ax = np.linspace(lo, hi, alphas.size) if alphas.size > 1 else np.array([lo])
        return cls(rgb, np.column_stack([ax, alphas]), name)

    def rescaled(self, value_range) -> TransferFunction:
        """The same shape stretched so its knot span [first x, last x] becomes `value_range`.

        (ParaView's "rescale to data range"; used for presets stored over [0, 1].)
        A function on a log or symlog scale is stretched on its scaled axis.
        """
        from .scaling import forward, inverse, scaled_range

        lo, hi = _range(value_range, f"transfer function {self.name!r}")
        axis = (self.scale, self.threshold)
        if self.scale != "linear":
            lo, hi = scaled_range((lo, hi), *axis)
        x0, x1 = (float(x) for x in forward(self.value_range, *axis))
        stretch = 0.0 if x1 == x0 else (hi - lo) / (x1 - x0)  # one knot: move it to lo

        def remap(points):
            out = points.copy()
            out[:, 0] = inverse(lo + (forward(points[:, 0], *axis) - x0) * stretch, *axis)
            return out if self.scale == "linear" else strictly_increasing(out)

        return TransferFunction(remap(self.rgb_points), remap(self.alpha_points), self.name, *axis)

    def on_scale(self, scale: str, threshold: float = 1.0) -> TransferFunction:
        """This function read as one over the *scaled* axis of `scale`
        (exabricks.picture.scaling), as a function of the data value: its knots mapped
        back to data values, with knots added first so that no interval spans more
        than 1/COLORMAP_KNOTS of the scaled range (between knots the result is
        linear in the data value, which then differs from linear on the scaled
        axis by well under 1e-3 of an interval's change)."""
        from .scaling import inverse

        if scale == "linear":
            return TransferFunction(self.rgb_points, self.alpha_points, self.name)
        lo, hi = self.value_range
        grid = np.linspace(lo, hi, COLORMAP_KNOTS) if hi > lo else np.array([lo])

        def dense(points):
            xs = np.union1d(points[:, 0], grid)
            columns = [np.interp(xs, points[:, 0], points[:, c]) for c in range(1, points.shape[1])]
            return strictly_increasing(np.column_stack([inverse(xs, scale, threshold)] + columns))

        return TransferFunction(dense(self.rgb_points), dense(self.alpha_points), self.name, scale,
                                float(threshold))

    def to_paraview_dict(self) -> dict:
        """ParaView preset form (for image metadata and `from_paraview_dict`); a
        scale other than linear is kept as "Scale" (and "LinearThreshold")."""
        points = np.column_stack([self.alpha_points, np.full((len(self.alpha_points), 2), (0.5, 0.0))])
        out = {
            "Name": self.name,
            "ColorSpace": "RGB",
            "RGBPoints": self.rgb_points.reshape(-1).tolist(),
            "Points": points.reshape(-1).tolist(),
        }
        if self.scale != "linear":
            out["Scale"] = self.scale
        if self.scale == "symlog":
            out["LinearThreshold"] = self.threshold
        return out

    # -- evaluation ---------------------------------------------------------------------

    @property
    def value_range(self) -> tuple[float, float]:
        """(lowest, highest) knot x over colour and opacity."""
        return (float(min(self.rgb_points[0, 0], self.alpha_points[0, 0])),
                float(max(self.rgb_points[-1, 0], self.alpha_points[-1, 0])))

    def evaluate(self, values) -> np.ndarray:
        """RGBA (..., 4) float64 at data `values` (any shape); NaN values give NaN."""
        v = np.asarray(values, dtype=np.float64)
        out = np.empty(v.shape + (4,))
        for c in range(3):
            out[..., c] = np.interp(v, self.rgb_points[:, 0], self.rgb_points[:, c + 1])
        out[..., 3] = np.interp(v, self.alpha_points[:, 0], self.alpha_points[:, 1])
        return out

    @functools.cached_property
    def table(self) -> LookupTable:
        """`lookup_table` of the merged knots, made once per transfer function (a
        renderer looks it up every frame of every domain)."""
        return lookup_table(*self.merged_knots(np.float64))

    def merged_knots(self, dtype=np.float32, exponent: int = 0):
        """Knots of the whole RGBA function: ``(xs (K,), rgba (K, 4))`` in `dtype`,
        xs times 2**`exponent` (for a field the device holds so scaled,
        exabricks.engine.device_data.value_exponent).

        xs is the sorted union of the colour and opacity knots and rgba the
        function evaluated there, so interpolating linearly between consecutive
        knots (and clamping outside) is exactly `evaluate` -- each channel is
        linear between its own knots, hence between any finer set of knots.
        """
        xs = np.union1d(self.rgb_points[:, 0], self.alpha_points[:, 0])
        if np.dtype(dtype) == np.float32:
            xs = np.ldexp(_apart_in_float32(np.ldexp(xs, exponent)), -exponent)
        return np.ldexp(xs, exponent).astype(dtype), self.evaluate(xs).astype(dtype)

    def any_alpha(self, lo, hi) -> np.ndarray:
        """Whether alpha is above 0 somewhere in each value interval ``[lo_i, hi_i]``.

        `lo`, `hi`: arrays of the same shape (data units; swapped where lo > hi).
        Returns bool of that shape. Exact: a piecewise-linear function is positive
        somewhere in an interval iff it is at an end point or at a knot inside,
        and the knots inside are counted from a prefix count of the positive ones
        (O(1) per interval, at memory speed over millions of BVH nodes and regions).
        """
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        x, a = self.alpha_points[:, 0], self.alpha_points[:, 1]
        positive = np.concatenate([[0], np.cumsum(a > 0)])
        inside = positive[np.searchsorted(x, hi, side="right")] \
            - positive[np.searchsorted(x, lo, side="left")]
        return (inside > 0) | (np.interp(lo, x, a) > 0) | (np.interp(hi, x, a) > 0)


# Most buckets of a knot index (knot_buckets): 64 KiB per transfer function.
MAX_KNOT_BUCKETS = 16384


def knot_buckets(xs: np.ndarray) -> np.ndarray:
    """An index into the merged knots `xs` (strictly increasing float32) for a
    lookup without a binary search (kernels/packet.cl, eb_packet_lookup):
    ``[K, M, first_0, ..., first_{K-1}]`` as int32.

    Bucket j of K even buckets over [xs[0], xs[-1]] is what the device computes
    as ``floor((v - xs[0]) * (K / (xs[-1] - xs[0])))``, clamped to [0, K-1]. So
    that float rounding on either side cannot matter, first_j is the last knot
    at or below the start of bucket j - 1, and M the most knots any value of
    buckets j - 1 .. j + 1 can lie beyond first_j: the knot below v is first_j
    plus the number of xs[first_j + 1 .. first_j + M] at or below v (a prefix,
    xs being increasing), M independent comparisons."""
    xs = np.asarray(xs, np.float64)
    n = len(xs)
    if n < 2:
        return np.array([1, 0, 0], np.int32)
    k = int(min(4 * n, MAX_KNOT_BUCKETS))
    width = (xs[-1] - xs[0]) / k
    j = np.arange(k)
    low = xs[0] + (j - 1) * width
    high = xs[0] + (j + 2) * width
    first = np.clip(np.searchsorted(xs, low, side="right") - 1, 0, n - 1)
    last = np.clip(np.searchsorted(xs, high, side="right") - 1, 0, n - 1)
    m = int((last - first).max())
    return np.concatenate([[k, m], first]).astype(np.int32)


# Intervals of a lookup table (lookup_table): the knots' lattice where they have one
# of at most MAX_TABLE_INTERVALS intervals; else IRREGULAR_TABLE_INTERVALS (256 KiB),
# or MAX_TABLE_INTERVALS (1 MiB) where that leaves the table further than
# TABLE_TOLERANCE from the exact function; a renderer looks a layer up exactly when
# its table is further than that still.
IRREGULAR_TABLE_INTERVALS = 16384
MAX_TABLE_INTERVALS = 65536
TABLE_TOLERANCE = 1.0 / 1024.0


@dataclass(frozen=True)
class LookupTable:
    """A transfer function sampled for the table lookup of the kernels
    (docs/design-rendering.md, "Transfer-function tables").

    rows: float32 (K + 2, 4): a header ``(x0, K / (x_end - x0), K, 0)``, then RGBA at
    the K + 1 evenly spaced nodes ``x0 + i (x_end - x0) / K``; between nodes the
    kernel interpolates linearly and outside it clamps, as the exact path does.
    error_rgb, error_alpha: the most the table's colour and opacity differ from the
    exact piecewise-linear function at any value (float64)."""

    rows: np.ndarray
    error_rgb: float
    error_alpha: float


def _denominator(f: float, tol: float) -> int:
    """The least q with some p/q within `tol` of f in [0, 1], from f's continued
    fraction (its convergents are the best approximations); 0 when q would pass
    MAX_TABLE_INTERVALS."""
    p0, q0, p1, q1, x = 0, 1, 1, 0, f
    while q1 <= MAX_TABLE_INTERVALS:
        a = math.floor(x)
        p0, q0, p1, q1 = p1, q1, a * p1 + p0, a * q1 + q0
        if abs(f - p1 / q1) <= tol:
            return q1 if q1 <= MAX_TABLE_INTERVALS else 0
        if x == a:
            break
        x = 1.0 / (x - a)
    return 0


def _knot_lattice(xs: np.ndarray) -> int | None:
    """The fewest even intervals over [xs[0], xs[-1]] (float64 knots), at most
    MAX_TABLE_INTERVALS, whose nodes hold every knot to 1e-9 of the span (the
    rounding of a preset rescaled to any range), or None."""
    k = 1
    for f in (xs[1:-1] - xs[0]) / (xs[-1] - xs[0]):
        q = _denominator(float(f), 1e-9)
        k = k * q // math.gcd(k, q) if q else 0
        if not 0 < k <= MAX_TABLE_INTERVALS:
            return None
    return k


def lookup_table(xs: np.ndarray, rgba: np.ndarray) -> LookupTable:
    """The lookup table of the merged knots `xs` (strictly increasing) and `rgba`,
    in float64 (`TransferFunction.merged_knots(np.float64)`).

    Knots on a lattice (a colormap's 256 even knots, opacity knots at round
    fractions of the range: every built-in preset) all fall on nodes: K is the
    lattice, and the table is the exact function up to float rounding. Otherwise
    only a table interval with a knot strictly inside differs from the exact
    function; the two are linear on either side of each such knot, so the largest
    difference is at one of them, where it is measured (and K grows once where
    that is above TABLE_TOLERANCE)."""
    xs = np.asarray(xs, np.float64)
    rgba = np.asarray(rgba, np.float64)
    n = len(xs)
    if n < 2:
        rows = np.concatenate([[[xs[0], 0.0, 1.0, 0.0]], rgba[:1], rgba[:1]])
        return LookupTable(rows.astype(np.float32), 0.0, 0.0)
    x0, span = xs[0], xs[-1] - xs[0]
    lattice = _knot_lattice(xs)
    sizes = (lattice,) if lattice else (IRREGULAR_TABLE_INTERVALS, MAX_TABLE_INTERVALS)
    for k in sizes:
        nodes = x0 + span * (np.arange(k + 1) / k)
        table = np.stack([np.interp(nodes, xs, rgba[:, c]) for c in range(4)], axis=1)
        # Each inner knot against the chord of the table interval that holds it.
        at = (xs[1:-1] - x0) * (k / span)
        cell = np.clip(np.floor(at).astype(np.int64), 0, k - 1)
        t = (at - cell)[:, None]
        off = np.abs((1.0 - t) * table[cell] + t * table[cell + 1] - rgba[1:-1])
        error_rgb, error_alpha = float(off[:, :3].max(initial=0.0)), float(off[:, 3].max(initial=0.0))
        if max(error_rgb, error_alpha) <= TABLE_TOLERANCE:
            break
    # K / span beyond float32 (a span of a field the device holds scaled, whose
    # header exabricks.engine.look writes again) is cut rather than overflowed.
    rows = np.concatenate([[[x0, min(k / span, FLOAT32_MAX), float(k), 0.0]], table])
    return LookupTable(rows.astype(np.float32), error_rgb, error_alpha)


def _apart_in_float32(xs: np.ndarray) -> np.ndarray:
    """The sorted knots `xs` less those whose float32 distance to the knot kept
    before them is below float32's smallest normal number (the last knot is kept,
    in place of the one before it): the kernels flush such a distance to zero and
    would divide by it. Only knots within 1.2e-38 of each other go (a log axis
    reaching down to float32's underflow), where the function changes by nothing
    a frame can show."""
    x32 = xs.astype(np.float32)
    tiny = np.finfo(np.float32).tiny
    if len(xs) < 2 or (np.diff(x32) >= tiny).all():
        return xs
    keep = [0]
    for i in range(1, len(xs)):
        if x32[i] - x32[keep[-1]] >= tiny:
            keep.append(i)
        elif i == len(xs) - 1 and len(keep) > 1:
            keep[-1] = i
    return xs[keep]


def strictly_increasing(knots: np.ndarray) -> np.ndarray:
    """`knots` (rows [x, ...], x non-decreasing) without the rows whose x repeats the
    row before: knots that float64 rounding merged on a mapped axis."""
    return knots[np.concatenate([[True], np.diff(knots[:, 0]) > 0])]


def _range(value_range, what: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value_range)
    except (TypeError, ValueError):
        raise ExabricksError(f"{what}: value range must be two numbers, got {value_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
        raise ExabricksError(f"{what}: value range must be finite with low < high, got [{lo:g}, {hi:g}]")
    if not math.isfinite(hi - lo) or max(abs(lo), abs(hi)) > FLOAT32_MAX:
        raise ExabricksError(f"{what}: value range [{lo:g}, {hi:g}] is beyond the float32 range "
                             f"the renderer computes in (magnitude at most {FLOAT32_MAX:.6g})")
    return lo, hi


def _reject_constant(name):
    raise ValueError(f"{name} is not a number")


def matplotlib_colormap(name):
    """matplotlib's colormap `name`; an ExabricksError that names it otherwise, with
    the names closest to it ('infern': did you mean inferno?)."""
    import matplotlib

    try:
        return matplotlib.colormaps[name]
    except (KeyError, TypeError):
        pass
    from ..util.errors import quoted

    hint = ""
    if isinstance(name, str):
        import difflib

        # the reversed maps (NAME_r) only for a name that asks for one
        names = {n.lower(): n for n in matplotlib.colormaps if n.endswith("_r") == name.endswith("_r")}
        close = difflib.get_close_matches(name.lower(), list(names), n=1, cutoff=0.6)
        hint = f"; did you mean {names[close[0]]!r}?" if close else ""
    raise ExabricksError(f"unknown colormap {quoted(str(name))}{hint} (any matplotlib colormap name, e.g. "
                         "viridis, inferno, magma, coolwarm)")


def preset_path(name: str) -> Path:
    """Path of a preset shipped in exabricks/data/transfer_functions (NAME.json)."""
    path = Path(str(resources.files("exabricks") / "data" / "transfer_functions" / f"{name}.json"))
    if not path.is_file():
        raise ExabricksError(f"no built-in transfer function {name!r} (available: {', '.join(builtin_presets())})")
    return path


def builtin_presets() -> list[str]:
    """Names of the presets shipped with exabricks."""
    folder = Path(str(resources.files("exabricks") / "data" / "transfer_functions"))
    return sorted(p.stem for p in folder.glob("*.json"))


def widen_degenerate_range(value_range) -> tuple[float, float]:
    """`value_range`, or for a constant field (low == high = v) ``v -+ max(1, |v|) / 2``,
    cut at float32's largest magnitude, which the kernels compute in (a constant
    field of 3e38 is then at the top of its range, not beyond it)."""
    lo, hi = (float(v) for v in value_range)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ExabricksError(f"value range must be finite, got [{lo:g}, {hi:g}]")
    if lo == hi:
        half = 0.5 * max(1.0, abs(lo))
        return max(lo - half, -FLOAT32_MAX), min(hi + half, FLOAT32_MAX)
    return lo, hi


def default_transfer_function(value_range) -> TransferFunction:
    """The built-in ``default`` preset (viridis, opacity ramp 0 -> 1) over `value_range`.

    `value_range` is usually the field's (min, max); a constant field is
    widened (`widen_degenerate_range`) so its value sits mid-ramp.
    """
    return TransferFunction.from_paraview(preset_path(DEFAULT_PRESET)).rescaled(
        widen_degenerate_range(value_range))
