"""The picture as one object: camera, volume layers, iso-surfaces, slices,
clipping, lighting, background and render settings (docs/scene.md).

`Scene` is what the renderer consumes (`exabricks.stages.render.render_scene`);
the CLI builds it from a scene file and flags (`scene_from_options`), and the
Python API builds it directly. Every colour map and transfer function here is
already stretched over its data range; every position is in world units.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .camera import Camera
from .errors import ExabricksError
from .jsonfile import not_regular
from .transfer_function import TransferFunction

SHADING_MODES = ("headlight", "none")
GRADIENTS = ("analytic", "central")
# How a point's value comes from the cells (docs/design.md, "Reconstructions").
RECONSTRUCTIONS = ("basis", "nearest", "vertex")

# Limits of one frame (the kernels keep these in private arrays).
MAX_VOLUMES = 8
MAX_ISOSURFACES = 32
MAX_SLICES = 8
MAX_CLIP_PLANES = 16
MAX_AO_SAMPLES = 256


@dataclass(frozen=True)
class VolumeLayer:
    """One field drawn as a participating medium with its own transfer function."""

    field: str
    transfer_function: TransferFunction


@dataclass(frozen=True)
class IsoSurface:
    """The surface where `field` equals `value` (basis field), drawn with `opacity`.

    Colour: the fixed RGB `color` (each in [0, 1]), or, when `color_field` is
    set, `colormap` (its RGB, over its range) evaluated on `color_field` at the hit.
    """

    field: str
    value: float
    color: tuple[float, float, float] = (0.9, 0.9, 0.9)
    opacity: float = 1.0
    color_field: str | None = None
    colormap: TransferFunction | None = None


@dataclass(frozen=True)
class Slice:
    """A plane through `point` with normal `normal` (world units), showing
    `colormap` (RGB over its range) of `field`, drawn with `opacity`."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    field: str
    colormap: TransferFunction
    opacity: float = 1.0


@dataclass(frozen=True)
class Clip:
    """What is kept: the inside of `box` ((lower xyz), (upper xyz)) and, for every
    plane (point, normal), the half-space (p - point) . normal >= 0. World units."""

    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    planes: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()

    @property
    def active(self) -> bool:
        return self.box is not None or bool(self.planes)


@dataclass(frozen=True)
class Lighting:
    """shading: "headlight" (diffuse, plus Blinn-Phong `specular` with exponent
    `shininess` on surfaces) or "none"; gradient: "analytic" or "central";
    ambient occlusion of surface hits: `ao_samples` rays (0: off) of length
    `ao_distance` world units (None: 10 finest cell widths)."""

    shading: str = "headlight"
    gradient: str = "analytic"
    specular: float = 0.0
    shininess: float = 32.0
    ao_samples: int = 0
    ao_distance: float | None = None


@dataclass(frozen=True)
class Settings:
    """Render settings, by their flag names (docs/design.md)."""

    width: int = 512
    height: int = 512
    spp: int = 1
    sampling_rate: float = 2.0
    max_opacity: float = 0.98
    seed: int = 0
    jitter: bool = True
    unit_distance: float | None = None
    depth: bool = False
    reconstruction: str = "basis"
    lod: float = 0.0


@dataclass(frozen=True)
class Scene:
    camera: Camera
    volumes: tuple[VolumeLayer, ...] = ()
    isosurfaces: tuple[IsoSurface, ...] = ()
    slices: tuple[Slice, ...] = ()
    clip: Clip = Clip()
    lighting: Lighting = Lighting()
    background: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    settings: Settings = Settings()

    def fields(self) -> tuple[str, ...]:
        """Every field the frame reads, in first-use order (volumes, iso-surfaces
        and their colour fields, slices): the only ones uploaded."""
        names = [v.field for v in self.volumes]
        for s in self.isosurfaces:
            names += [s.field] + ([s.color_field] if s.color_field else [])
        names += [s.field for s in self.slices]
        return tuple(dict.fromkeys(names))

    def replace(self, **changes) -> "Scene":
        return replace(self, **changes)

    def check(self) -> None:
        """ExabricksError for a scene no renderer can draw (limits, unknown modes)."""
        lim = ((self.volumes, MAX_VOLUMES, "volume layers"),
               (self.isosurfaces, MAX_ISOSURFACES, "iso-surfaces"),
               (self.slices, MAX_SLICES, "slices"),
               (self.clip.planes, MAX_CLIP_PLANES, "clip planes"))
        for items, most, what in lim:
            if len(items) > most:
                raise ExabricksError(f"{len(items)} {what}: at most {most} per frame")
        if self.lighting.shading not in SHADING_MODES:
            raise ExabricksError(f"unknown shading {self.lighting.shading!r} "
                                 f"(one of {', '.join(SHADING_MODES)})")
        if self.settings.reconstruction not in RECONSTRUCTIONS:
            raise ExabricksError(f"unknown reconstruction {self.settings.reconstruction!r} "
                                 f"(one of {', '.join(RECONSTRUCTIONS)})")
        if not (np.isfinite(self.settings.lod) and self.settings.lod >= 0):
            raise ExabricksError(f"--lod must be 0 (off) or a positive number of pixels, "
                                 f"got {self.settings.lod}")
        if self.lighting.gradient not in GRADIENTS:
            raise ExabricksError(f"unknown gradient {self.lighting.gradient!r} "
                                 f"(one of {', '.join(GRADIENTS)})")
        if not 0 <= self.lighting.ao_samples <= MAX_AO_SAMPLES:
            raise ExabricksError(f"ambient occlusion samples must lie in 0..{MAX_AO_SAMPLES}")
        d = self.lighting.ao_distance
        if d is not None and not (np.isfinite(d) and d > 0):
            raise ExabricksError(f"ambient occlusion distance must be positive, got {d}")
        for s in self.isosurfaces:
            if not np.isfinite(s.value):
                raise ExabricksError(f"iso-value {s.value} of field {s.field!r} is not finite")
            if not 0.0 <= s.opacity <= 1.0:
                raise ExabricksError(f"iso-surface opacity must lie in [0, 1], got {s.opacity}")
            if (s.color_field is None) != (s.colormap is None):
                raise ExabricksError("an iso-surface colour field needs a colour map and vice versa")
        for s in self.slices:
            n = np.asarray(s.normal, float)
            if not (np.all(np.isfinite(s.point)) and np.all(np.isfinite(n)) and n @ n > 0):
                raise ExabricksError(f"slice of {s.field!r} needs a finite point and a non-zero normal")
            if not 0.0 <= s.opacity <= 1.0:
                raise ExabricksError(f"slice opacity must lie in [0, 1], got {s.opacity}")
        for p, n in self.clip.planes:
            n = np.asarray(n, float)
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n)) and n @ n > 0):
                raise ExabricksError("a clip plane needs a finite point and a non-zero normal")
        if self.clip.box is not None:
            lo, hi = (np.asarray(b, float) for b in self.clip.box)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
                raise ExabricksError(f"clip box {lo.tolist()} .. {hi.tolist()} must be finite "
                                     "with lower <= upper")
        bg = self.background
        if len(bg) != 4 or not all(0.0 <= c <= 1.0 for c in bg):
            raise ExabricksError(f"background must be RGBA in [0, 1], got {list(bg)}")


# ---------------------------------------------------------------------------
# Building a scene from a scene file and command-line flags (docs/scene.md).
#
# Precedence: built-in defaults < scene file < flags. The file is validated
# against data/scene.schema.json first, so the builders below only check what a
# schema cannot say (field names, files, low < high, non-zero normals) -- each
# with the file and key path (or the flag) where the value came from.

DEFAULT_COLORMAP = "viridis"
DEFAULT_FOVY = 30.0
MAX_SCHEMA_ERRORS = 500

# The flags `scene_from_options` understands, by the names of their click
# parameters (`render --help`); None (or an empty tuple) means "not given".
FLAGS = (
    "position", "look_at", "up", "fovy",
    "field", "transfer_function", "colormap", "range", "opacity", "volume",
    "iso", "iso_color", "iso_opacity", "iso_color_field", "iso_colormap", "iso_range",
    "slice", "slice_colormap", "slice_range",
    "clip_box", "clip_plane",
    "shading", "gradient", "specular", "shininess", "ao_samples", "ao_distance",
    "background",
    "size", "spp", "sampling_rate", "max_opacity", "seed", "jitter", "unit_distance", "depth",
    "reconstruction", "lod",
)
_VOLUME_FLAGS = ("field", "transfer_function", "colormap", "range", "opacity")


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def field_range(bricks, field: str | None) -> tuple[float, float]:
    """(min, max) of the finite values of `field` (None: the first field);
    ExabricksError if it has none."""
    from .schema import reduce_chunks

    def extent(chunk):
        finite = chunk[np.isfinite(chunk)]
        return (float(finite.min()), float(finite.max())) if finite.size else (np.inf, -np.inf)

    lo, hi = reduce_chunks(bricks.values[bricks.field_index(field)], extent,
                           lambda a, b: (min(a[0], b[0]), max(a[1], b[1])))
    if lo > hi:
        raise ExabricksError(f"field {field or bricks.fields[0]!r} has no finite values")
    return lo, hi


def _data_range(bricks, field: str) -> tuple[float, float]:
    from .transfer_function import widen_degenerate_range

    return widen_degenerate_range(field_range(bricks, field))


def choose_transfer_function(bricks, field, preset=None, colormap=None, value_range=None,
                             opacity=None) -> TransferFunction:
    """The transfer function of `--transfer-function`, `--colormap`, `--range` and
    `--opacity` for `field` (docs/scene.md):

    - `colormap`: that matplotlib colormap over `value_range` (default: the
      field's finite range) with the `opacity` knots spread evenly over it
      (default (0, 1): a ramp);
    - `preset` naming a built-in preset (and no such file): its shape stretched
      over `value_range` or the field's range;
    - `preset` naming a preset file: used as stored, or rescaled to `value_range`;
    - neither: the default transfer function over `value_range` or the field's range.
    """
    from .transfer_function import builtin_presets, default_transfer_function, preset_path

    if preset and colormap:
        raise ExabricksError("give --transfer-function or --colormap, not both")
    data_range = tuple(value_range) if value_range else _data_range(bricks, field)
    if colormap:
        return TransferFunction.from_colormap(colormap, data_range, opacity=opacity or (0.0, 1.0))
    if opacity:
        raise ExabricksError("--opacity goes with --colormap")
    if preset is None:
        return default_transfer_function(data_range)
    if not Path(preset).exists() and preset in builtin_presets():
        # Built-in presets are shapes over [0, 1]: stretch them over the data (ParaView's rescale).
        return TransferFunction.from_paraview(preset_path(preset)).rescaled(data_range)
    tf = TransferFunction.from_paraview(preset)
    return tf.rescaled(value_range) if value_range else tf


def check_flags(flags: dict) -> None:
    """ExabricksError for flags that contradict each other whatever the scene file
    says (the CLI reports it as a usage error)."""
    f = _normalised_flags(flags)
    if f["transfer_function"] is not None and f["colormap"] is not None:
        raise ExabricksError("give --transfer-function or --colormap, not both")
    if f["opacity"] is not None and f["colormap"] is None:
        raise ExabricksError("--opacity goes with --colormap")
    if f["volume"] is False:
        for name in _VOLUME_FLAGS[1:]:
            if f[name] is not None:
                raise ExabricksError(f"{_flag(name)} describes a volume layer, but --no-volume draws none")
    if f["iso_color"] is not None and f["iso_color_field"] is not None:
        raise ExabricksError("give --iso-color or --iso-color-field, not both")
    for name in ("iso_colormap", "iso_range"):
        if f[name] is not None and f["iso_color"] is not None:
            raise ExabricksError(f"{_flag(name)} goes with --iso-color-field, not --iso-color")


def _normalised_flags(flags: dict | None) -> dict:
    out = dict.fromkeys(FLAGS)
    for name, value in (flags or {}).items():
        if name not in out:
            raise TypeError(f"unknown flag {name!r} (one of {', '.join(FLAGS)})")
        if isinstance(value, (tuple, list)) and len(value) == 0:
            value = None  # click's value of a repeatable option that was not given
        out[name] = value
    return out


# -- the scene file -------------------------------------------------------------------


def scene_schema() -> dict:
    """The JSON Schema of scene files (exabricks/data/scene.schema.json)."""
    import json
    from importlib import resources

    return json.loads((resources.files("exabricks") / "data" / "scene.schema.json").read_text("utf-8"))


def _key_path(path) -> str:
    """``volumes[1].transfer_function`` from ("volumes", 1, "transfer_function")."""
    out = ""
    for key in path:
        if isinstance(key, int):
            out += f"[{key}]"
        elif key.isidentifier():
            out += f".{key}" if out else key
        else:
            out += f"[{_shown(key)}]"
    return out


def _shown(value, most: int = 60) -> str:
    """A short JSON rendering of `value` for messages."""
    import json

    try:
        text = json.dumps(value)
    except RecursionError:
        return "a deeply nested value"
    return text if len(text) <= most else text[: most - 3] + "..."


def _at(name: str | None, path) -> str:
    """Where a value sits: ``scene.json: volumes[1].field`` (just the file for the root)."""
    keys = _key_path(path)
    return f"{name}: {keys}" if keys else str(name)


def _finite_number(checker, value) -> bool:
    import math

    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer beyond float range
        return False


def _schema_error_message(error, schema: dict, doc, name: str) -> str:
    """One line for one jsonschema error: `PATH: KEY.PATH: expected ... (found X)`."""
    resolve = lambda node: schema["$defs"][node["$ref"].rsplit("/", 1)[1]]
    # Walk the schema along the error's schema path, noting the instance depth of
    # every node; '$ref' steps are implicit in jsonschema's paths.
    nodes, node, depth = [], schema, 0
    keys = list(error.absolute_schema_path)
    i = 0
    while True:
        nodes.append((depth, node))
        while keys[i:] and keys[i] not in node and "$ref" in node:
            node = resolve(node)
            nodes.append((depth, node))
        if i >= len(keys) - 1:
            break
        key = keys[i]
        if key == "properties":
            node, depth, i = node[key][keys[i + 1]], depth + 1, i + 2
        elif key in ("items", "additionalProperties"):
            node, depth, i = node[key], depth + 1, i + 1
        elif key in ("allOf", "anyOf", "oneOf"):
            node, i = node[key][keys[i + 1]], i + 2
        else:  # if / then / else / not
            node, i = node[key], i + 1
    path = list(error.absolute_path)
    instance = error.instance
    if error.validator == "additionalProperties":
        known = list(node.get("properties", {}))
        extra = next(k for k in instance if k not in known)
        return f"{_at(name, path + [extra])}: unknown key (expected one of: {', '.join(known)})"
    if error.validator == "required":
        missing = next(k for k in node["required"] if k not in instance)
        prop = node["properties"][missing]
        while "description" not in prop and "$ref" in prop:
            prop = resolve(prop)
        return f"{_at(name, path + [missing])}: expected {prop['description']} (missing)"
    described = [(d, n) for d, n in nodes if "description" in n and d <= len(path)]
    deepest = max(d for d, _ in described)
    description = next(n["description"] for d, n in described if d == deepest)
    found = doc
    for key in path[:deepest]:
        found = found[key]
    return f"{_at(name, path[:deepest])}: expected {description} (found {_shown(found)})"


def _doc_order(doc, path) -> tuple:
    """Sort key of an instance path: keys by their place in the file, items by index."""
    order, node = [], doc
    for key in path:
        order.append(list(node).index(key) if isinstance(node, dict) else key)
        node = node[key]
    return tuple(order)


def _no_duplicate_keys(pairs):
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def read_scene_file(path) -> dict:
    """The parsed scene file `path`, validated against the scene schema; one
    ExabricksError `PATH: KEY.PATH: what was expected (found X)` for the first
    mistake in file order (docs/scene.md)."""
    import itertools

    import jsonschema

    from .jsonfile import read_json

    doc = read_json(path, "scene file", object_pairs_hook=_no_duplicate_keys)
    schema = scene_schema()
    if isinstance(doc, dict):  # the top-level lists' limits, before their items are validated
        for key, value in doc.items():
            limit = schema["properties"].get(key, {}).get("maxItems")
            if isinstance(value, list) and limit is not None and len(value) > limit:
                raise ExabricksError(f"{_at(str(path), (key,))}: expected "
                                     f"{schema['properties'][key]['description']} "
                                     f"(found a list of {len(value):,})")
    base = jsonschema.Draft202012Validator
    validator_class = jsonschema.validators.extend(
        base, type_checker=base.TYPE_CHECKER.redefine("number", _finite_number))
    # The first mistake in file order among the first few hundred found: a hostile
    # file may hold millions, and a list's own limits are reported before its items.
    errors = list(itertools.islice(validator_class(schema).iter_errors(doc), MAX_SCHEMA_ERRORS))
    if errors:
        priority = ("type", "additionalProperties", "required")
        first = min(errors, key=lambda e: (
            _doc_order(doc, e.absolute_path),
            priority.index(e.validator) if e.validator in priority else len(priority)))
        raise ExabricksError(_schema_error_message(first, schema, doc, str(path)))
    return doc


class _SceneFile:
    """A validated scene file: its object, its name in messages and its folder
    (the base of the relative paths it holds). `_SceneFile(None)` is no file."""

    def __init__(self, path):
        self.name = None if path is None else str(path)
        self.folder = None if path is None else Path(path).parent
        self.doc = {} if path is None else read_scene_file(path)

    def at(self, *path) -> str:
        return _at(self.name, path)

    def get(self, *path, default=None):
        node = self.doc
        for key in path:
            if not isinstance(node, dict) or key not in node:
                return default
            node = node[key]
        return node

    def camera_file(self) -> Path | None:
        value = self.doc.get("camera")
        if not isinstance(value, str):
            return None
        path = self.folder / value
        problem = not_regular(path)
        if problem:
            raise ExabricksError(f"{self.at('camera')}: expected a camera file (found {_shown(value)}: "
                                 f"{problem}: {path})")
        return path

    def preset_file(self, value, *path) -> Path | None:
        """The preset file a transfer-function string names (None: a built-in name)."""
        from .transfer_function import builtin_presets

        file = self.folder / value
        problem = not_regular(file)
        if problem is None:
            return file
        if value in builtin_presets():
            return None
        raise ExabricksError(
            f"{self.at(*path)}: expected a preset file, a built-in preset name or a preset object "
            f"(found {_shown(value)}: {problem}: {file}, nor a built-in preset: "
            f"{', '.join(builtin_presets())})")

    def references(self) -> list[Path]:
        """Every file the scene names (camera, preset files), each checked to exist."""
        files = [self.camera_file()]
        for i, volume in enumerate(self.doc.get("volumes", [])):
            tf = volume.get("transfer_function")
            if isinstance(tf, str):
                files.append(self.preset_file(tf, "volumes", i, "transfer_function"))
        return [f for f in files if f is not None]


def scene_file_references(path) -> list[Path]:
    """The files scene file `path` refers to (camera file, preset files), resolved
    against its folder; ExabricksError naming the key path of a missing one."""
    return _SceneFile(path).references()


# -- builders ---------------------------------------------------------------------------


def _within(where: str, build, *args, **kw):
    """`build(*args, **kw)`, with `where` put in front of its ExabricksError."""
    try:
        return build(*args, **kw)
    except ExabricksError as e:
        raise ExabricksError(f"{where}: {e}") from None


def _field(bricks, name: str, where: str) -> str:
    if name not in bricks.fields:
        raise ExabricksError(f"{where}: no field {name!r} (fields: {', '.join(bricks.fields) or 'none'})")
    return name


def _value_range(value, where: str):
    """(low, high) from a scene file or flag, or None; low < high."""
    if value is None:
        return None
    lo, hi = (float(v) for v in value)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ExabricksError(f"{where}: expected [low, high] with low < high (found {_shown([lo, hi])})")
    return lo, hi


def _nonzero(vector, where: str, what: str = "normal"):
    v = tuple(float(x) for x in vector)
    if not all(np.isfinite(v)) or not any(v):
        raise ExabricksError(f"{where}: expected a finite, non-zero {what} (found {_shown(list(v))})")
    return v


@dataclass
class _Colour:
    """A colour map of a field, before it is built: each part with where it came from."""

    field: str
    field_at: str
    colormap: str | dict = DEFAULT_COLORMAP
    colormap_at: str = ""
    range: tuple | None = None
    range_at: str = ""

    def build(self, bricks) -> tuple[str, TransferFunction]:
        field = _field(bricks, self.field, self.field_at)
        value_range = _value_range(self.range, self.range_at)
        if isinstance(self.colormap, dict):
            tf = TransferFunction.from_paraview_dict(self.colormap, source=self.colormap_at)
            return field, tf.rescaled(value_range) if value_range else tf
        data_range = value_range or _within(self.field_at, _data_range, bricks, field)
        return field, _within(self.colormap_at, TransferFunction.from_colormap, self.colormap, data_range)


def _file_colour(file: _SceneFile, spec: dict, *path) -> _Colour:
    return _Colour(spec["field"], file.at(*path, "field"),
                   spec.get("colormap", DEFAULT_COLORMAP), file.at(*path, "colormap"),
                   spec.get("range"), file.at(*path, "range"))


def _camera(bricks, file: _SceneFile, camera_path, f) -> Camera:
    from . import schema
    from .camera import default_camera

    inline = file.get("camera")
    if camera_path is not None:
        camera = Camera.from_json(camera_path)
    elif isinstance(inline, dict):
        camera = Camera.from_dict({"fovy": DEFAULT_FOVY, **inline}, source=file.at("camera"))
    elif inline is not None:
        camera = _within(file.at("camera"), Camera.from_json, file.camera_file())
    else:
        camera = default_camera(*schema.world_bounds(bricks))
    return camera.with_overrides(position=f["position"], look_at=f["look_at"], up=f["up"], fovy=f["fovy"])


def _file_transfer_function(bricks, file: _SceneFile, i: int, field: str) -> TransferFunction:
    from .transfer_function import DEFAULT_PRESET, preset_path

    where = file.at("volumes", i, "transfer_function")
    entry = file.doc["volumes"][i]
    spec = entry.get("transfer_function", DEFAULT_PRESET)
    value_range = _value_range(entry.get("range"), file.at("volumes", i, "range"))
    data_range = lambda: value_range or _within(file.at("volumes", i, "field"), _data_range, bricks, field)
    if isinstance(spec, dict) and "colormap" in spec:
        return _within(where, TransferFunction.from_colormap, spec["colormap"], data_range(),
                       opacity=spec.get("opacity", (0.0, 1.0)))
    if isinstance(spec, dict):
        tf = TransferFunction.from_paraview_dict(spec, source=where)
        return tf.rescaled(value_range) if value_range else tf
    preset = file.preset_file(spec, "volumes", i, "transfer_function")
    if preset is None:  # a built-in shape over [0, 1], stretched over the data
        return TransferFunction.from_paraview(preset_path(spec)).rescaled(data_range())
    tf = _within(where, TransferFunction.from_paraview, preset)
    return tf.rescaled(value_range) if value_range else tf


def _volumes(bricks, file: _SceneFile, f, base: str, base_at: str) -> tuple[VolumeLayer, ...]:
    if f["volume"] is False:
        return ()
    if any(f[name] is not None for name in _VOLUME_FLAGS):
        tf = choose_transfer_function(bricks, base, f["transfer_function"], f["colormap"],
                                      f["range"], f["opacity"])
        return (VolumeLayer(base, tf),)
    entries = file.get("volumes")
    if entries is None or (not entries and f["volume"]):
        return (VolumeLayer(base, choose_transfer_function(bricks, base)),)
    layers = []
    for i, entry in enumerate(entries):
        field = _field(bricks, entry["field"], file.at("volumes", i, "field"))
        layers.append(VolumeLayer(field, _file_transfer_function(bricks, file, i, field)))
    return tuple(layers)


def _isosurfaces(bricks, file: _SceneFile, f, base: str, base_at: str) -> tuple[IsoSurface, ...]:
    # (field, field_at, value, colour: RGB tuple or _Colour, opacity) before flags modify them
    if f["iso"] is not None:
        specs = [[base, base_at, float(v), IsoSurface.color, IsoSurface.opacity] for v in f["iso"]]
    else:
        specs = []
        for i, e in enumerate(file.get("isosurfaces", default=[])):
            colour = e.get("color", IsoSurface.color)
            if isinstance(colour, dict):
                colour = _file_colour(file, colour, "isosurfaces", i, "color")
            specs.append([e["field"], file.at("isosurfaces", i, "field"), float(e["value"]),
                          tuple(float(c) for c in colour) if isinstance(colour, list) else colour,
                          float(e.get("opacity", IsoSurface.opacity))])
    modifiers = [n for n in ("iso_color", "iso_opacity", "iso_color_field", "iso_colormap", "iso_range")
                 if f[n] is not None]
    if modifiers and not specs:
        raise ExabricksError(f"{_flag(modifiers[0])}: there is no iso-surface to apply it to "
                             "(give --iso VALUE, or isosurfaces in the scene file)")
    for spec in specs:
        if f["iso_opacity"] is not None:
            spec[4] = float(f["iso_opacity"])
        if f["iso_color"] is not None:
            spec[3] = tuple(float(c) for c in f["iso_color"])
        if f["iso_color_field"] is not None:
            old = spec[3] if isinstance(spec[3], _Colour) else _Colour("", "")
            spec[3] = _Colour(f["iso_color_field"], "--iso-color-field", old.colormap,
                              old.colormap_at or "--iso-color-field",
                              old.range if old.field == f["iso_color_field"] else None, old.range_at)
        if isinstance(spec[3], _Colour):
            if f["iso_colormap"] is not None:
                spec[3].colormap, spec[3].colormap_at = f["iso_colormap"], "--iso-colormap"
            if f["iso_range"] is not None:
                spec[3].range, spec[3].range_at = tuple(f["iso_range"]), "--iso-range"
    for name in ("iso_colormap", "iso_range"):
        if f[name] is not None and not any(isinstance(s[3], _Colour) for s in specs):
            raise ExabricksError(f"{_flag(name)}: there is no iso-surface coloured by a field to apply "
                                 "it to (give --iso-color-field NAME)")
    surfaces = []
    for field, field_at, value, colour, opacity in specs:
        field = _field(bricks, field, field_at)
        if isinstance(colour, _Colour):
            colour_field, colormap = colour.build(bricks)
            surfaces.append(IsoSurface(field, value, opacity=opacity, color_field=colour_field,
                                       colormap=colormap))
        else:
            surfaces.append(IsoSurface(field, value, color=colour, opacity=opacity))
    return tuple(surfaces)


def _slices(bricks, file: _SceneFile, f, base: str, base_at: str) -> tuple[Slice, ...]:
    # (point, normal, where, _Colour, opacity)
    if f["slice"] is not None:
        specs = [(tuple(p[:3]), tuple(p[3:]), "--slice", _Colour(base, base_at), Slice.opacity)
                 for p in f["slice"]]
    else:
        specs = [(tuple(e["point"]), tuple(e["normal"]), file.at("slices", i, "normal"),
                  _file_colour(file, e, "slices", i), float(e.get("opacity", Slice.opacity)))
                 for i, e in enumerate(file.get("slices", default=[]))]
    for name in ("slice_colormap", "slice_range"):
        if f[name] is not None and not specs:
            raise ExabricksError(f"{_flag(name)}: there is no slice to apply it to "
                                 "(give --slice PX PY PZ NX NY NZ, or slices in the scene file)")
    out = []
    for point, normal, where, colour, opacity in specs:
        if f["slice_colormap"] is not None:
            colour.colormap, colour.colormap_at = f["slice_colormap"], "--slice-colormap"
        if f["slice_range"] is not None:
            colour.range, colour.range_at = tuple(f["slice_range"]), "--slice-range"
        normal = _nonzero(normal, where)
        field, colormap = colour.build(bricks)
        out.append(Slice(tuple(float(x) for x in point), normal, field, colormap, opacity))
    return tuple(out)


def _clip(file: _SceneFile, f) -> Clip:
    if f["clip_box"] is not None:
        box, box_at = f["clip_box"], "--clip-box"
    else:
        box, box_at = file.get("clip", "box"), file.at("clip", "box")
    if box is not None:
        lo, hi = tuple(float(x) for x in box[:3]), tuple(float(x) for x in box[3:])
        if not (all(np.isfinite(lo + hi)) and all(a <= b for a, b in zip(lo, hi))):
            raise ExabricksError(f"{box_at}: expected a finite box with x0 <= x1, y0 <= y1, z0 <= z1 "
                                 f"(found {_shown(list(lo + hi))})")
        box = (lo, hi)
    if f["clip_plane"] is not None:
        planes = [(p, "--clip-plane") for p in f["clip_plane"]]
    else:
        planes = [(p, file.at("clip", "planes", i))
                  for i, p in enumerate(file.get("clip", "planes", default=[]))]
    planes = tuple((tuple(float(x) for x in p[:3]), _nonzero(p[3:], where)) for p, where in planes)
    return Clip(box, planes)


def _pick(f, flag: str, file: _SceneFile, path, default):
    """The flag's value if given, else the scene file's, else `default`."""
    if f[flag] is not None:
        return f[flag]
    return file.get(*path, default=default)


def _lighting(file: _SceneFile, f) -> Lighting:
    d = Lighting()
    ao = ("lighting", "ambient_occlusion")
    distance = _pick(f, "ao_distance", file, ao + ("distance",), d.ao_distance)
    return Lighting(
        shading=_pick(f, "shading", file, ("lighting", "shading"), d.shading),
        gradient=_pick(f, "gradient", file, ("lighting", "gradient"), d.gradient),
        specular=float(_pick(f, "specular", file, ("lighting", "specular"), d.specular)),
        shininess=float(_pick(f, "shininess", file, ("lighting", "shininess"), d.shininess)),
        ao_samples=int(_pick(f, "ao_samples", file, ao + ("samples",), d.ao_samples)),
        ao_distance=None if distance is None else float(distance))


def _background(file: _SceneFile, f) -> tuple[float, float, float, float]:
    value = _pick(f, "background", file, ("background",), None)
    if value is None:
        return Scene.background
    rgba = tuple(float(c) for c in value)
    return rgba + (1.0,) if len(rgba) == 3 else rgba  # a colour given as RGB is opaque


def _settings(file: _SceneFile, f) -> Settings:
    d = Settings()
    width, height = _pick(f, "size", file, ("size",), (d.width, d.height))
    unit_distance = _pick(f, "unit_distance", file, ("unit_distance",), d.unit_distance)
    return Settings(
        width=int(width), height=int(height),
        spp=int(_pick(f, "spp", file, ("spp",), d.spp)),
        sampling_rate=float(_pick(f, "sampling_rate", file, ("sampling_rate",), d.sampling_rate)),
        max_opacity=float(_pick(f, "max_opacity", file, ("max_opacity",), d.max_opacity)),
        seed=int(_pick(f, "seed", file, ("seed",), d.seed)),
        jitter=bool(_pick(f, "jitter", file, ("jitter",), d.jitter)),
        unit_distance=None if unit_distance is None else float(unit_distance),
        depth=bool(_pick(f, "depth", file, ("depth",), d.depth)),
        reconstruction=_pick(f, "reconstruction", file, ("reconstruction",), d.reconstruction),
        lod=float(_pick(f, "lod", file, ("lod",), d.lod)))


def scene_from_options(bricks, *, scene_path=None, camera_path=None, flags: dict | None = None) -> Scene:
    """The scene that the built-in defaults, scene file `scene_path` and `flags`
    describe, in that order of precedence (docs/scene.md).

    `bricks`: the dataset (field names and value ranges; its bounds place the
    default camera). `camera_path`: a camera file (`--camera`), which replaces
    the scene file's camera. `flags`: command-line values by the names in
    `FLAGS` (None or an empty tuple: not given). Relative paths in the scene
    file are relative to its folder. ExabricksError naming the file and key
    path, or the flag, for anything wrong.
    """
    f = _normalised_flags(flags)
    check_flags(f)
    file = _SceneFile(scene_path)
    if f["field"] is not None:
        base, base_at = f["field"], "--field"
    elif file.get("volumes"):
        base, base_at = file.doc["volumes"][0]["field"], file.at("volumes", 0, "field")
    else:
        base, base_at = bricks.fields[0], "the first field"
    base = _field(bricks, base, base_at)
    scene = Scene(
        camera=_camera(bricks, file, camera_path, f),
        volumes=_volumes(bricks, file, f, base, base_at),
        isosurfaces=_isosurfaces(bricks, file, f, base, base_at),
        slices=_slices(bricks, file, f, base, base_at),
        clip=_clip(file, f),
        lighting=_lighting(file, f),
        background=_background(file, f),
        settings=_settings(file, f),
    )
    scene.check()
    return scene


def scene_to_dict(scene: Scene) -> dict:
    """The scene as a JSON-ready scene-file object (image metadata); reading it
    back as a scene file gives the same scene. Transfer functions and colour
    maps are ParaView preset objects over their data ranges."""
    s, light = scene.settings, scene.lighting
    isosurfaces = []
    for iso in scene.isosurfaces:
        color = ({"field": iso.color_field, "colormap": iso.colormap.to_paraview_dict()}
                 if iso.color_field else list(iso.color))
        isosurfaces.append({"field": iso.field, "value": iso.value, "color": color, "opacity": iso.opacity})
    clip = {"planes": [[*p, *n] for p, n in scene.clip.planes]}
    if scene.clip.box is not None:
        clip["box"] = [*scene.clip.box[0], *scene.clip.box[1]]
    ao = {"samples": light.ao_samples}
    if light.ao_distance is not None:
        ao["distance"] = light.ao_distance
    out = {
        "camera": scene.camera.to_dict(),
        "volumes": [{"field": v.field, "transfer_function": v.transfer_function.to_paraview_dict()}
                    for v in scene.volumes],
        "isosurfaces": isosurfaces,
        "slices": [{"point": list(sl.point), "normal": list(sl.normal), "field": sl.field,
                    "colormap": sl.colormap.to_paraview_dict(), "opacity": sl.opacity}
                   for sl in scene.slices],
        "clip": clip,
        "lighting": {"shading": light.shading, "gradient": light.gradient, "specular": light.specular,
                     "shininess": light.shininess, "ambient_occlusion": ao},
        "background": list(scene.background),
        "size": [s.width, s.height],
        "spp": s.spp,
        "sampling_rate": s.sampling_rate,
        "max_opacity": s.max_opacity,
        "seed": s.seed,
        "jitter": s.jitter,
        "depth": s.depth,
        "reconstruction": s.reconstruction,
        "lod": s.lod,
    }
    if s.unit_distance is not None:
        out["unit_distance"] = s.unit_distance
    return out
