"""Framing: where the default camera looks when none is given (docs/scene.md,
"Defaults that show the data").

The default camera frames what the volume layers make visible, not the whole
domain: `visible_corners` is the box holding all but `TRIM` of the opacity
(extinction x volume) of a layer on each side of each axis, and `framed_camera`
looks at it from the three-quarter direction at the distance where its corners
fill the frame up to `MARGIN`.
"""

from __future__ import annotations

import math

import numpy as np

from .camera import DEFAULT_UP, DEFAULT_VIEW_DIRECTION, Camera

# Share of the opacity left outside the visible box at each end of each axis.
TRIM = 0.005
# Share of the frame's half-width and half-height left free around the box.
MARGIN = 0.05
# Bins per axis of the opacity's distribution over the lattice.
POSITION_BINS = 1024


def view_axes() -> np.ndarray:
    """(3, 3) float64 rows right, up and forward of the default three-quarter view
    (`DEFAULT_VIEW_DIRECTION` toward the camera, +y up)."""
    forward = -np.asarray(DEFAULT_VIEW_DIRECTION, np.float64)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, DEFAULT_UP)
    right /= np.linalg.norm(right)
    return np.array([right, np.cross(right, forward), forward])


def visible_corners(bricks, field: str, transfer_function, *, axes=None, trim: float = TRIM):
    """(8, 3) float64 world corners of the box, with edges along the rows of
    `axes` (orthonormal; default: the world axes), that holds what
    `transfer_function` makes visible of `field` (module docstring); None where
    nothing is."""
    from .camera import box_corners
    from .field_statistics import opacity_along
    from ..formats.kinds import world_bounds

    axes = np.eye(3) if axes is None else np.asarray(axes, np.float64)
    # The data's extent along each axis, from the corners of its world box.
    along = box_corners(*(np.asarray(b, np.float64) for b in world_bounds(bricks))) @ axes.T
    lo, span = along.min(0), along.max(0) - along.min(0)
    histograms = opacity_along(bricks, field, transfer_function, axes, lo, span, POSITION_BINS)
    total = histograms[0].sum()
    if not total > 0:
        return None
    lower, upper = np.empty(3), np.empty(3)
    for a in range(3):
        cumulative = np.cumsum(histograms[a]) / total
        first = int(np.searchsorted(cumulative, trim, side="right"))
        last = int(np.searchsorted(cumulative, 1.0 - trim, side="left"))
        lower[a] = lo[a] + span[a] * first / POSITION_BINS
        upper[a] = lo[a] + span[a] * min(last + 1, POSITION_BINS) / POSITION_BINS
    return box_corners(lower, upper) @ axes


def visible_points(bricks, volumes, *, axes=None) -> np.ndarray:
    """(n, 3) world corners of the boxes (edges along the rows of `axes`) that the
    volume layers `volumes` make visible of `bricks` (`visible_corners`), else
    the corners of the dataset's world box."""
    from .camera import box_corners
    from ..formats.kinds import world_bounds

    boxes = [visible_corners(bricks, v.field, v.transfer_function, axes=axes) for v in volumes]
    return np.concatenate([b for b in boxes if b is not None]
                          or [box_corners(*world_bounds(bricks))])


def framed_camera(points_world, *, aspect: float = 1.0, fovy: float = 30.0,
                  margin: float = MARGIN) -> Camera:
    """The three-quarter view (`view_axes`) of the world points `points_world`
    (n, 3), from the nearest distance at which all of them lie inside the frame
    of width/height `aspect`, `margin` of each half-extent left free, and
    outside their bounding sphere."""
    right, up, forward = view_axes()
    points = np.asarray(points_world, np.float64)
    # Centre the frame on the middle of the points' extent across the view.
    x, y, z = points @ right, points @ up, points @ forward
    centre = (right * 0.5 * (x.min() + x.max()) + up * 0.5 * (y.min() + y.max())
              + forward * 0.5 * (z.min() + z.max()))
    tan_v = math.tan(math.radians(fovy) / 2.0) * (1.0 - margin)
    tan_h = tan_v * aspect
    offset = points - centre
    depth = offset @ forward  # along the view, from the centre
    # A point at (x, y, depth) is inside when |x| <= tan_h (d + depth), |y| likewise.
    need = np.concatenate([np.abs(offset @ right) / tan_h - depth, np.abs(offset @ up) / tan_v - depth])
    radius = float(np.linalg.norm(offset, axis=1).max()) or 1.0
    distance = max(float(need.max()), 1.05 * radius)
    return Camera(tuple(centre - distance * forward), tuple(centre), DEFAULT_UP, fovy)
