"""The pinhole camera: where rays start and which direction each pixel looks.

Convention (docs/design-rendering.md, "Camera"): a camera is ``position``, ``look_at``,
``up`` (world units) and ``fovy`` (the full vertical field of view in degrees).
Pixel ``(col, row)``, row 0 at the top, of a ``W x H`` image is hit by the ray
from ``position`` along

    forward + u * du + v * dv,   u = 2 (col + 0.5) / W - 1,   v = 1 - 2 (row + 0.5) / H,

with ``du = tan(fovy/2) * aspect * right``, ``dv = tan(fovy/2) * up'``,
``aspect = W / H``, ``right = normalize(forward x up)`` and
``up' = right x forward``.  `Camera.frame` returns exactly these vectors (the
OpenCL kernel receives them as arguments); `Camera.rays` builds the float64
rays of the NumPy reference integrator from the same vectors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..util.constants import FLOAT32_MAX
from ..util.errors import ExabricksError

CAMERA_KEYS = ("position", "look_at", "up", "fovy")

# Below this |forward x up| (both unit vectors, i.e. sin of the angle between them)
# the right vector is numerically meaningless: about 0.06 degrees.
_PARALLEL_TOLERANCE = 1e-3

# The default view direction (from the centre of the box towards the camera):
# a three-quarter view from the +x/+z side, a little above (+y is up, as in
# ParaView's default view), so that all three axes are visible and foreshortened
# differently.
DEFAULT_VIEW_DIRECTION = (1.0, 0.6, 1.4)
DEFAULT_UP = (0.0, 1.0, 0.0)


def _format_vector(v) -> str:
    return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"


def _vector(value, key: str, where: str) -> tuple[float, float, float]:
    """A finite 3-vector of floats from JSON or Python input; ExabricksError otherwise."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3:
        raise ExabricksError(f"{where}: camera '{key}' must be a list of 3 numbers, got {value!r}")
    out = []
    for x in value:
        if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
            raise ExabricksError(f"{where}: camera '{key}' must be a list of 3 numbers, got {value!r}")
        if not math.isfinite(float(x)):
            raise ExabricksError(f"{where}: camera '{key}' has a non-finite value: {value!r}")
        if abs(float(x)) > FLOAT32_MAX:
            raise ExabricksError(f"{where}: camera '{key}' {_format_vector(value)} is beyond the "
                                 f"float32 range the renderer computes in (magnitude at most "
                                 f"{FLOAT32_MAX:.6g})")
        out.append(float(x))
    return (out[0], out[1], out[2])


def _scalar(value, key: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ExabricksError(f"{where}: camera '{key}' must be a number, got {value!r}")
    if not math.isfinite(float(value)):
        raise ExabricksError(f"{where}: camera '{key}' is not finite: {value!r}")
    if abs(float(value)) > FLOAT32_MAX:
        raise ExabricksError(f"{where}: camera '{key}' {float(value):g} is beyond the float32 range")
    return float(value)


def _validated(position, look_at, up, fovy, where: str):
    """Parse and check the four camera parameters; returns them as tuples/float."""
    position = _vector(position, "position", where)
    look_at = _vector(look_at, "look_at", where)
    up = _vector(up, "up", where)
    fovy = _scalar(fovy, "fovy", where)
    if not 0.0 < fovy < 180.0:
        raise ExabricksError(f"{where}: camera fovy must be in (0, 180) degrees, got {fovy:g}")
    view = np.subtract(look_at, position)
    view_length = float(np.linalg.norm(view))
    if not math.isfinite(view_length) or view_length > FLOAT32_MAX:
        raise ExabricksError(
            f"{where}: camera position {_format_vector(position)} and look_at "
            f"{_format_vector(look_at)} are too far apart: their distance overflows the float32 "
            f"range the renderer computes in"
        )
    if view_length == 0.0:
        raise ExabricksError(
            f"{where}: camera position and look_at are the same point {_format_vector(position)}"
        )
    up_length = float(np.linalg.norm(up))
    if up_length == 0.0:
        raise ExabricksError(f"{where}: camera up vector {_format_vector(up)} has zero length")
    sin_angle = float(np.linalg.norm(np.cross(view / view_length, np.divide(up, up_length))))
    if sin_angle < _PARALLEL_TOLERANCE:
        raise ExabricksError(
            f"{where}: camera up vector {_format_vector(up)} is parallel to the view direction "
            f"{_format_vector(view / view_length)}"
        )
    return position, look_at, up, fovy


@dataclass(frozen=True)
class Camera:
    """A pinhole camera in world units; ``fovy`` is the full vertical angle in degrees."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    fovy: float = 30.0

    def __post_init__(self):
        values = _validated(self.position, self.look_at, self.up, self.fovy, "camera")
        for key, value in zip(CAMERA_KEYS, values):
            object.__setattr__(self, key, value)

    # -- construction -------------------------------------------------------------------

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "camera") -> Camera:
        """Camera from ``{"position", "look_at", "up", "fovy"}``; errors name `source`."""
        if not isinstance(d, dict):
            raise ExabricksError(f"{source}: a camera must be a JSON object, got {type(d).__name__}")
        missing = [k for k in CAMERA_KEYS if k not in d]
        if missing:
            raise ExabricksError(f"{source}: camera is missing {', '.join(repr(k) for k in missing)}")
        unknown = sorted(set(d) - set(CAMERA_KEYS))
        if unknown:
            raise ExabricksError(
                f"{source}: unknown camera key(s) {', '.join(repr(k) for k in unknown)} "
                f"(expected {', '.join(CAMERA_KEYS)})"
            )
        return cls(*_validated(d["position"], d["look_at"], d["up"], d["fovy"], source))

    @classmethod
    def from_json(cls, path) -> Camera:
        """Read a camera JSON file; ExabricksError naming the file if unreadable or invalid."""
        from ..util.jsonfile import read_json

        return cls.from_dict(read_json(path, "camera file"), source=str(path))

    def to_dict(self) -> dict:
        """The JSON form (lists of floats), readable by `from_dict`."""
        return {
            "position": list(self.position),
            "look_at": list(self.look_at),
            "up": list(self.up),
            "fovy": self.fovy,
        }

    def with_overrides(self, *, position=None, look_at=None, up=None, fovy=None,
                       source: str = "command line") -> Camera:
        """A copy with the given parameters replaced (None keeps the current value)."""
        values = {
            "position": self.position if position is None else position,
            "look_at": self.look_at if look_at is None else look_at,
            "up": self.up if up is None else up,
            "fovy": self.fovy if fovy is None else fovy,
        }
        return Camera(*_validated(*(values[k] for k in CAMERA_KEYS), source))

    # -- projection ---------------------------------------------------------------------

    def frame(self, width: int, height: int):
        """The ray frame of a ``width x height`` image.

        Returns ``(origin, forward, du, dv)``, each float64 (3,) in world units
        (forward unit length; du, dv scaled by the half-extent of the image plane
        at distance 1) such that pixel (col, row) looks along
        ``forward + u * du + v * dv`` (module docstring).
        """
        if int(width) < 1 or int(height) < 1:
            raise ExabricksError(f"image size must be positive, got {width}x{height}")
        origin = np.asarray(self.position, dtype=np.float64)
        forward = np.subtract(self.look_at, self.position, dtype=np.float64)
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, np.asarray(self.up, dtype=np.float64))
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        half_height = math.tan(math.radians(self.fovy) / 2.0)
        aspect = int(width) / int(height)
        return origin, forward, half_height * aspect * right, half_height * up

    def footprint(self, lower, upper, width: int, height: int):
        """Pixels (col0, row0, col1, row1), half-open, whose rays of a ``width x
        height`` image can meet the world box [lower, upper] (any sub-pixel
        position): the box's eight corners projected, one pixel of margin. The
        whole image when a corner is not in front of the eye; None when the
        box is outside the image or wholly behind the eye."""
        origin, forward, du, dv = self.frame(width, height)
        corners = box_corners(lower, upper) - origin
        depth = corners @ forward
        size = float(np.abs(corners).max()) or 1.0
        if (depth <= 0.0).all():  # wholly behind the eye
            return None
        if not (depth > 1e-9 * size).all():
            return 0, 0, int(width), int(height)
        u = (corners @ du) / (du @ du) / depth
        v = (corners @ dv) / (dv @ dv) / depth
        x = (u + 1.0) * 0.5 * width  # pixel col looks at x in [col, col + 1)
        y = (1.0 - v) * 0.5 * height
        c0, c1 = max(0, math.floor(x.min()) - 1), min(int(width), math.floor(x.max()) + 2)
        r0, r1 = max(0, math.floor(y.min()) - 1), min(int(height), math.floor(y.max()) + 2)
        return (c0, r0, c1, r1) if c0 < c1 and r0 < r1 else None

    def rays(self, width: int, height: int, jitter=None):
        """Float64 primary rays of every pixel, for the NumPy reference integrator.

        `jitter`: None for pixel centres, else sub-pixel positions in [0, 1),
        shape broadcastable to (height, width, 2) as (x, y) offsets from the
        pixel's top-left corner (0.5 is the centre).
        Returns ``origins`` (height, width, 3) and unit ``directions``
        (height, width, 3), float64, world units; row 0 is the top of the image.
        """
        origin, forward, du, dv = self.frame(width, height)
        offset = np.full((height, width, 2), 0.5) if jitter is None else np.broadcast_to(
            np.asarray(jitter, dtype=np.float64), (height, width, 2))
        cols = np.arange(width, dtype=np.float64)[None, :]
        rows = np.arange(height, dtype=np.float64)[:, None]
        u = 2.0 * (cols + offset[..., 0]) / width - 1.0
        v = 1.0 - 2.0 * (rows + offset[..., 1]) / height
        directions = forward + u[..., None] * du + v[..., None] * dv
        directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        origins = np.broadcast_to(origin, directions.shape).copy()
        return origins, directions


def box_corners(lower, upper) -> np.ndarray:
    """float64 (8, 3): the corners of the box [lower, upper]."""
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    return np.array([[(lower, upper)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])


def default_camera(lower_world, upper_world, *, fovy: float = 30.0) -> Camera:
    """A three-quarter view that shows the whole box ``[lower_world, upper_world]``.

    The camera looks at the centre of the box from direction
    `DEFAULT_VIEW_DIRECTION` (1, 0.6, 1.4) with +y up, at the distance
    ``r / sin(fovy / 2)`` where ``r`` is the radius of the box's bounding
    sphere: the sphere then exactly fills the vertical field of view, so every
    corner is inside an image whose aspect is at least 1 (wider than tall) from
    any direction.
    """
    lower = np.asarray(lower_world, dtype=np.float64)
    upper = np.asarray(upper_world, dtype=np.float64)
    if lower.shape != (3,) or upper.shape != (3,) or not (np.isfinite(lower).all() and np.isfinite(upper).all()):
        raise ExabricksError(f"default camera needs finite 3-vector bounds, got {lower_world!r} .. {upper_world!r}")
    if not (upper >= lower).all():
        raise ExabricksError(f"default camera: empty box {_format_vector(lower)} .. {_format_vector(upper)}")
    centre = 0.5 * (lower + upper)
    radius = 0.5 * float(np.linalg.norm(upper - lower))
    if radius == 0.0:
        radius = 1.0  # a single point: any sensible distance
    direction = np.asarray(DEFAULT_VIEW_DIRECTION) / np.linalg.norm(DEFAULT_VIEW_DIRECTION)
    distance = radius / math.sin(math.radians(fovy) / 2.0)
    position = centre + distance * direction
    return Camera(tuple(position), tuple(centre), DEFAULT_UP, fovy)
