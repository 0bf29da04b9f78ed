"""How a field's values are laid out on a colour axis: linear, log or symlog
(docs/scene.md, "Defaults that show the data").

A transfer function is always piecewise linear in the *data* value (the kernels'
contract, docs/design.md); a scale only says where its knots sit and how its
colour bar is drawn. `forward` maps data values to the scaled axis, `inverse`
back. ``auto`` takes log for a positive field that spans more than
`AUTO_LOG_DECADES` decades, as yt's ``take_log`` does for such fields, and
linear otherwise.

symlog is ``sign(x) log10(1 + |x| / c)`` with the linear threshold ``c > 0``:
linear within about ``c`` of zero, logarithmic beyond, for signed fields that
span decades on either side.
"""

from __future__ import annotations

import math

import numpy as np

from ..util.errors import ExabricksError

SCALES = ("auto", "linear", "log", "symlog")
# auto: log where max / min of a positive field exceeds 10 ** AUTO_LOG_DECADES.
AUTO_LOG_DECADES = 2.0
# symlog's linear threshold when none is given: this fraction of the largest |value|.
SYMLOG_THRESHOLD = 1e-3
# The share of the range (from its low end, linear) above which a value counts as
# bright, and the share of the volume so bright that a linear axis shows it
# (exabricks.picture.auto_transfer.field_axis measures it).
BRIGHT = 0.01
LOG_BRIGHT_SHARE = 0.01


def resolve(scale: str | None, value_range, floor: float | None = None,
            bright_share: float | None = None) -> str:
    """The concrete scale ("linear", "log" or "symlog") of `scale` (None: auto)
    for a field whose finite values span `value_range` (low, high), `floor`
    its smallest positive value (a non-negative field with zeros, as a dark
    matter density, is on a log scale when its positive values span decades).
    `bright_share`: the share of the volume whose value lies above BRIGHT of
    the range on a linear axis; where it exceeds LOG_BRIGHT_SHARE the structure
    shows on a linear axis, and auto stays linear (a Gaussian blob, whose tails
    span decades that a log axis would give most of its colours to)."""
    scale = scale or "auto"
    if scale not in SCALES:
        raise ExabricksError(f"unknown scale {scale!r} (one of {', '.join(SCALES)})")
    lo, hi = (float(v) for v in value_range)
    if scale == "auto":
        low = lo if lo > 0 else (floor if lo == 0 and floor else 0.0)
        shows = bright_share is not None and bright_share > LOG_BRIGHT_SHARE
        return "log" if low > 0 and hi / low > 10.0 ** AUTO_LOG_DECADES and not shows else "linear"
    if scale == "log" and not hi > 0:
        raise ExabricksError(f"--scale log: the field has no positive value (its range is "
                             f"[{lo:g}, {hi:g}]); use linear or symlog")
    return scale


def default_threshold(value_range) -> float:
    """symlog's linear threshold for values within `value_range`."""
    lo, hi = (float(v) for v in value_range)
    big = max(abs(lo), abs(hi))
    return SYMLOG_THRESHOLD * big if big > 0 else 1.0


def forward(values, scale: str, threshold: float = 1.0) -> np.ndarray:
    """Data values (any shape) on the scaled axis, float64. log of a value <= 0 is -inf."""
    v = np.asarray(values, np.float64)
    if scale == "linear":
        return v
    if scale == "log":
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), -np.inf)
    return np.sign(v) * np.log10(1.0 + np.abs(v) / threshold)


def inverse(scaled, scale: str, threshold: float = 1.0) -> np.ndarray:
    """Scaled-axis values (any shape) back to data values, float64."""
    s = np.asarray(scaled, np.float64)
    if scale == "linear":
        return s
    if scale == "log":
        return np.power(10.0, s)
    return np.sign(s) * threshold * (np.power(10.0, np.abs(s)) - 1.0)


def scaled_range(value_range, scale: str, threshold: float = 1.0,
                 floor: float | None = None) -> tuple[float, float]:
    """`value_range` on the scaled axis; for log, a range reaching 0 or below starts
    at `floor` (the smallest positive value), else `AUTO_LOG_DECADES` * 3
    decades under its top."""
    lo, hi = (float(v) for v in value_range)
    if scale == "log" and lo <= 0:
        lo = floor if floor and 0 < floor < hi else hi * 10.0 ** (-3 * AUTO_LOG_DECADES)
    a, b = (float(x) for x in forward([lo, hi], scale, threshold))
    if not (math.isfinite(a) and math.isfinite(b) and a < b):
        raise ExabricksError(f"cannot lay the range [{lo:g}, {hi:g}] on a {scale} axis")
    return a, b


def axis_label(field: str, scale: str) -> str:
    """The colour bar's label of `field` on `scale` (yt writes log(field))."""
    return {"linear": field, "log": f"log10 {field}", "symlog": f"symlog {field}"}[scale]
