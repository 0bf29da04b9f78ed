"""Camera paths: keyframes interpolated into the cameras of a movie's frames.

A *camera-path file* (docs/workflows.md, "Camera paths") is JSON::

    {"kind": "exabricks camera path", "version": 1,
     "keyframes": [{"position": [...], "look_at": [...], "up": [...], "fovy": 30, "time": 0}, ...],
     "loop": false,
     "frames": [{"position": [...], "look_at": [...], "up": [...], "fovy": 30}, ...]}

``frames`` are the cameras `render --camera-path FILE --frame I` draws, one per
frame, already interpolated (so that every consumer, a SLURM array task
included, sees exactly the same camera for frame I); ``keyframes`` and
``loop`` record where they came from.

Interpolation between keyframes (at their ``time``, strictly increasing;
default 0, 1, 2, ...): ``position``, ``look_at`` and ``fovy`` follow a cubic
Hermite spline whose tangents are the Catmull-Rom finite differences of the
non-uniformly spaced keyframes (one-sided at the ends of an open path,
wrapped round a loop), so the camera moves with a continuous velocity through
every keyframe; ``up`` is slerped between neighbouring keyframes and then made
perpendicular to the view direction. The N frames sample the time span evenly,
both ends included for an open path; a loop leaves out the end, which is its
start.

An *orbit* turns the default three-quarter view of `render` (or a camera at
the given elevation) about an axis through the look-at point, 360 degrees over
N frames, the last frame one step short of the first.
"""

from __future__ import annotations

import json
import math

import numpy as np

from .camera import DEFAULT_VIEW_DIRECTION, Camera, default_camera
from ..util.errors import ExabricksError
from ..util.vectors import unit

KIND = "exabricks camera path"
VERSION = 1
# An hour of movie at 30 frames per second is 108,000 frames; a path file of this many is about 20 MB.
MAX_FRAMES = 100_000
# The largest camera-path file read (MAX_FRAMES frames take about 13 MB).
MAX_PATH_BYTES = 32 << 20
# Keyframes of one path: a few dozen in practice; each is checked as a camera.
MAX_KEYFRAMES = 4096
# Values in a camera-path file: a frame is an object of a few lists of 3 numbers.
MAX_PATH_VALUES = 32 * MAX_FRAMES


def _check_frames(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_FRAMES:
        raise ExabricksError(f"the number of frames must be an integer in [1, {MAX_FRAMES:,}], got {n!r}")
    return int(n)


def _perpendicular_up(up: np.ndarray, forward: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """`up` without its component along `forward` (unit), or `fallback`'s when
    `up` is (nearly) parallel to the view direction."""
    for candidate in (up, fallback, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])):
        u = candidate - np.dot(candidate, forward) * forward
        norm = np.linalg.norm(u)
        if norm > 1e-3 * max(np.linalg.norm(candidate), 1e-300):
            return u / norm
    raise ExabricksError("camera path: no up vector fits the view direction")  # unreachable


def _slerp(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """Spherical interpolation of unit vectors; linear (then renormalised) when they
    are nearly equal or opposite."""
    cos = float(np.clip(np.dot(a, b), -1.0, 1.0))
    angle = math.acos(cos)
    if angle < 1e-6 or math.pi - angle < 1e-6:
        v = (1.0 - s) * a + s * b
        n = np.linalg.norm(v)
        return v / n if n > 1e-12 else a
    sin = math.sin(angle)
    return (math.sin((1.0 - s) * angle) * a + math.sin(s * angle) * b) / sin


def _tangents(t: np.ndarray, p: np.ndarray, loop: bool) -> np.ndarray:
    """Catmull-Rom tangents dp/dt of values `p` (K, D) at times `t` (K,)."""
    k = len(t)
    m = np.zeros_like(p)
    if k < 2:
        return m
    if loop:
        period = t[-1] - t[0]
        # the loop's keyframes are t[0..K-2]; the last one repeats the first
        for i in range(k - 1):
            prev = i - 1 if i > 0 else k - 2
            t_prev = t[prev] - (period if i == 0 else 0.0)
            nxt = i + 1
            m[i] = (p[nxt] - p[prev]) / (t[nxt] - t_prev)
        m[-1] = m[0]
        return m
    m[0] = (p[1] - p[0]) / (t[1] - t[0])
    m[-1] = (p[-1] - p[-2]) / (t[-1] - t[-2])
    for i in range(1, k - 1):
        m[i] = (p[i + 1] - p[i - 1]) / (t[i + 1] - t[i - 1])
    return m


def _hermite(t: np.ndarray, p: np.ndarray, m: np.ndarray, i: int, u: float) -> np.ndarray:
    h = t[i + 1] - t[i]
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * p[i] + (u3 - 2 * u2 + u) * h * m[i]
            + (-2 * u3 + 3 * u2) * p[i + 1] + (u3 - u2) * h * m[i + 1])


def interpolate(keyframes: list[Camera], times, n_frames: int, *, loop: bool = False) -> list[Camera]:
    """`n_frames` cameras evenly spaced in time along the keyframes (module docstring)."""
    n_frames = _check_frames(n_frames)
    keys = list(keyframes)
    t = np.asarray(times, np.float64)
    if not keys:
        raise ExabricksError("camera path: no keyframes")
    if t.shape != (len(keys),) or not np.isfinite(t).all():
        raise ExabricksError("camera path: every keyframe needs one finite time")
    if len(keys) > 1 and not (np.diff(t) > 0).all():
        raise ExabricksError("camera path: keyframe times must increase strictly")
    if len(keys) == 1:
        return [keys[0]] * n_frames
    if loop:  # close the loop: the first keyframe again, one mean interval later
        keys = keys + [keys[0]]
        t = np.append(t, t[-1] + (t[-1] - t[0]) / (len(t) - 1))
    pos = np.array([k.position for k in keys])
    look = np.array([k.look_at for k in keys])
    fovy = np.array([[k.fovy] for k in keys])
    ups = [unit(k.up) for k in keys]
    tangents = [_tangents(t, v, loop) for v in (pos, look, fovy)]
    span = t[-1] - t[0]
    samples = t[0] + span * (np.arange(n_frames) / (n_frames if loop else max(n_frames - 1, 1)))
    out, previous_up = [], ups[0]
    for time in samples:
        i = int(min(np.searchsorted(t, time, side="right") - 1, len(t) - 2))
        u = float((time - t[i]) / (t[i + 1] - t[i]))
        p, q, f = (_hermite(t, v, m, i, u) for v, m in zip((pos, look, fovy), tangents))
        fov = float(np.clip(f[0], min(fovy[i, 0], fovy[i + 1, 0]), max(fovy[i, 0], fovy[i + 1, 0])))
        forward = q - p
        if np.linalg.norm(forward) == 0.0:
            raise ExabricksError(f"camera path: at time {time:g} the camera sits on its look-at point")
        forward = forward / np.linalg.norm(forward)
        up = _perpendicular_up(_slerp(ups[i], ups[i + 1], u), forward, previous_up)
        previous_up = up
        out.append(Camera(tuple(p), tuple(q), tuple(up), fov))
    return out


def orbit(lower_world, upper_world, n_frames: int, *, look_at=None, axis=None,
          elevation: float | None = None, fovy: float = 30.0, degrees: float = 360.0) -> list[Camera]:
    """`n_frames` cameras turning about `axis` (default +y, the default view's up)
    through `look_at` (default the centre of the box), starting from the default
    three-quarter view of the box (camera.default_camera) at its distance.
    `elevation`: the angle (degrees) of the camera above the plane perpendicular
    to the axis (default: the default view's, about 20.8 degrees); `degrees`:
    the angle turned over the whole path (360: a loop, its last frame one step
    short of the first)."""
    n_frames = _check_frames(n_frames)
    start = default_camera(lower_world, upper_world, fovy=fovy)
    centre = np.asarray(start.look_at if look_at is None else look_at, np.float64)
    if centre.shape != (3,) or not np.isfinite(centre).all():
        raise ExabricksError(f"orbit: the look-at point must be 3 finite numbers, got {look_at!r}")
    a = np.asarray((0.0, 1.0, 0.0) if axis is None else axis, np.float64)
    if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) == 0.0:
        raise ExabricksError(f"orbit: the axis must be a non-zero 3-vector, got {axis!r}")
    if not math.isfinite(degrees):
        raise ExabricksError(f"orbit: the angle must be finite, got {degrees!r}")
    a = a / np.linalg.norm(a)
    distance = float(np.linalg.norm(np.subtract(start.position, start.look_at)))
    d = unit(DEFAULT_VIEW_DIRECTION)
    # the default direction's components along the axis and in its plane
    along = float(np.dot(d, a))
    flat = d - along * a
    if np.linalg.norm(flat) < 1e-6:  # axis along the default direction: any perpendicular
        flat = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 0.0, 1.0])
    flat = flat / np.linalg.norm(flat)
    if elevation is None:
        elevation = math.degrees(math.asin(max(-1.0, min(1.0, along))))
    if not -90.0 < float(elevation) < 90.0:
        raise ExabricksError(f"orbit: the elevation must be in (-90, 90) degrees, got {elevation:g}")
    e = math.radians(float(elevation))
    side = np.cross(a, flat)
    step = math.radians(degrees) / (n_frames if abs(degrees) % 360.0 == 0.0 else max(n_frames - 1, 1))
    cameras = []
    for k in range(n_frames):
        phi = k * step
        horizontal = math.cos(phi) * flat + math.sin(phi) * side
        direction = math.cos(e) * horizontal + math.sin(e) * a
        cameras.append(Camera(tuple(centre + distance * direction), tuple(centre), tuple(a), fovy))
    return cameras


def dumps(doc: dict) -> str:
    """The camera-path file's text: one camera (or keyframe) per line."""
    lines = []
    for key, value in doc.items():
        if key in ("frames", "keyframes"):
            items = ",\n  ".join(json.dumps(v, separators=(", ", ": ")) for v in value)
            lines.append(f' "{key}": [\n  {items}\n ]')
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value)}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def to_dict(frames: list[Camera], *, keyframes: list[Camera] | None = None, times=None,
            loop: bool = False, source: dict | None = None) -> dict:
    """The camera-path file's JSON object."""
    doc = {"kind": KIND, "version": VERSION}
    if source:
        doc["source"] = source
    if keyframes is not None:
        doc["keyframes"] = [{**k.to_dict(), "time": float(t)} for k, t in zip(keyframes, times)]
        doc["loop"] = bool(loop)
    doc["frames"] = [c.to_dict() for c in frames]
    return doc


def read_keyframes(path) -> tuple[list[Camera], np.ndarray, bool]:
    """Keyframes of a KEYFRAMES.json: a list of cameras (each optionally with
    "time"), or an object {"keyframes": [...], "loop": bool} (a camera-path file
    too). Times default to 0, 1, 2, ..."""
    from ..util.jsonfile import read_json

    doc = read_json(path, "keyframe file", max_bytes=MAX_PATH_BYTES, max_list=MAX_FRAMES,
                    max_values=MAX_PATH_VALUES)
    loop = False
    if isinstance(doc, dict):
        unknown = sorted(set(doc) - {"kind", "version", "keyframes", "loop", "frames", "source"})
        if unknown:
            raise ExabricksError(f"{path}: unknown key(s) {', '.join(map(repr, unknown))} "
                                 "(expected keyframes, loop)")
        if "keyframes" not in doc:
            raise ExabricksError(f"{path}: no 'keyframes' list")
        loop = doc.get("loop", False)
        if not isinstance(loop, bool):
            raise ExabricksError(f"{path}: 'loop' must be true or false, got {loop!r}")
        doc = doc["keyframes"]
    if not isinstance(doc, list) or not doc:
        raise ExabricksError(f"{path}: keyframes must be a non-empty list of cameras")
    if len(doc) > MAX_KEYFRAMES:
        raise ExabricksError(f"{path}: {len(doc):,} keyframes, at most {MAX_KEYFRAMES:,}")
    cameras, times = [], []
    for i, entry in enumerate(doc):
        where = f"{path}: keyframes[{i}]"
        if not isinstance(entry, dict):
            raise ExabricksError(f"{where}: a keyframe must be a JSON object")
        entry = dict(entry)
        time = entry.pop("time", i)
        if isinstance(time, bool) or not isinstance(time, (int, float)) or not math.isfinite(time):
            raise ExabricksError(f"{where}: 'time' must be a finite number, got {time!r}")
        entry.setdefault("fovy", 30.0)
        cameras.append(Camera.from_dict(entry, source=where))
        times.append(float(time))
    if len(times) > 1 and not all(b > a for a, b in zip(times, times[1:])):
        raise ExabricksError(f"{path}: keyframe times must increase strictly, got {times}")
    return cameras, np.asarray(times), loop


class Frames:
    """The frames of a camera-path file, a sequence of Camera: each is checked as a
    camera when it is taken (a render of frame I of a long path builds that one)."""

    def __init__(self, path, frames: list):
        self.path, self._frames = path, frames

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, i: int) -> Camera:
        return Camera.from_dict(self._frames[i], source=f"{self.path}: frames[{i % len(self)}]")


def read_frames(path) -> Frames:
    """The frames of a camera-path file (Frames)."""
    from ..util.jsonfile import read_json

    doc = read_json(path, "camera path", max_bytes=MAX_PATH_BYTES, max_list=MAX_FRAMES,
                    max_values=MAX_PATH_VALUES)
    if not isinstance(doc, dict) or doc.get("kind") != KIND:
        raise ExabricksError(f"{path}: not a camera path (expected an object with \"kind\": "
                             f"\"{KIND}\"; `exabricks camera orbit|path` writes one)")
    if doc.get("version") != VERSION:
        raise ExabricksError(f"{path}: camera path version {doc.get('version')!r} is not "
                             f"supported (this exabricks reads version {VERSION})")
    frames = doc.get("frames")
    if not isinstance(frames, list) or not frames:
        raise ExabricksError(f"{path}: 'frames' must be a non-empty list of cameras")
    return Frames(path, frames)


def parse_frame_range(text: str, n: int, where: str) -> range:
    """Frames `A:B` (B excluded; either may be left out; negatives count from the
    end, as in Python) or a single index `I` of a path of `n` frames."""
    parts = text.split(":")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise ExabricksError(f"{where}: {text!r} is not a frame index I or a range A:B") from None
    if len(values) == 1:
        i = values[0]
        if i is None or not -n <= i < n:
            raise ExabricksError(f"{where}: frame {text} does not exist (the path has {n} frames, "
                                 f"0-{n - 1})")
        return range(i % n, i % n + 1)
    if len(values) != 2:
        raise ExabricksError(f"{where}: {text!r} is not a frame index I or a range A:B")
    frames = range(n)[slice(*values)]
    if not frames:
        raise ExabricksError(f"{where}: frames {text} select none of the path's {n} frames")
    return frames

