"""Building a scene from a scene file and command-line flags (docs/scene.md).

Precedence: built-in defaults < scene file < flags. The file is validated
against data/scene.schema.json first (exabricks.scene.file), so the builders
below only check what a schema cannot say (field names, files, low < high,
non-zero normals) -- each with the file and key path (or the flag) where the
value came from.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import ExabricksError
from ..transfer_function import TransferFunction
from .file import SceneFile, shown
from .model import (DEFAULT_COLORMAP, DEFAULT_FOVY, Clip, Instance, IsoSurface, Lighting, MeshLayer, Scene,
                    Settings, Slice, VolumeLayer)
from .options import SCENE_OPTIONS, VOLUME_FLAGS, check_flags, flag_name, normalised_flags


def field_range(bricks, field: str | None) -> tuple[float, float]:
    """(min, max) of the finite values of `field` (None: the first field);
    ExabricksError if it has none."""
    from ..schema import reduce_chunks

    def extent(chunk):
        finite = chunk[np.isfinite(chunk)]
        return (float(finite.min()), float(finite.max())) if finite.size else (np.inf, -np.inf)

    lo, hi = reduce_chunks(bricks.values[bricks.field_index(field)], extent,
                           lambda a, b: (min(a[0], b[0]), max(a[1], b[1])))
    if lo > hi:
        raise ExabricksError(f"field {field or bricks.fields[0]!r} has no finite values")
    return lo, hi


def _data_range(bricks, field: str) -> tuple[float, float]:
    from ..transfer_function import widen_degenerate_range

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
    from ..transfer_function import builtin_presets, default_transfer_function, preset_path

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
        raise ExabricksError(f"{where}: expected [low, high] with low < high (found {shown([lo, hi])})")
    return lo, hi


def _nonzero(vector, where: str, what: str = "normal"):
    v = tuple(float(x) for x in vector)
    if not all(np.isfinite(v)) or not any(v):
        raise ExabricksError(f"{where}: expected a finite, non-zero {what} (found {shown(list(v))})")
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


def _file_colour(file: SceneFile, spec: dict, *path) -> _Colour:
    return _Colour(spec["field"], file.at(*path, "field"),
                   spec.get("colormap", DEFAULT_COLORMAP), file.at(*path, "colormap"),
                   spec.get("range"), file.at(*path, "range"))


def _camera(bricks, file: SceneFile, camera_path, f, instances=()) -> Camera:
    from .. import schema
    from ..camera import box_corners, default_camera

    inline = file.get("camera")
    if camera_path is not None:
        camera = Camera.from_json(camera_path)
    elif isinstance(inline, dict):
        camera = Camera.from_dict({"fovy": DEFAULT_FOVY, **inline}, source=file.at("camera"))
    elif inline is not None:
        camera = _within(file.at("camera"), Camera.from_json, file.camera_file())
    else:
        corners = box_corners(*schema.world_bounds(bricks))
        placed = np.concatenate([corners] + [corners @ r.T + t for r, t in
                                             (i.affine() for i in instances)])
        camera = default_camera(placed.min(0), placed.max(0))  # on every copy
    return camera.with_overrides(position=f["position"], look_at=f["look_at"], up=f["up"], fovy=f["fovy"])


def _file_transfer_function(bricks, file: SceneFile, i: int, field: str) -> TransferFunction:
    from ..transfer_function import DEFAULT_PRESET, preset_path

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


def _volumes(bricks, file: SceneFile, f, base: str, base_at: str) -> tuple[VolumeLayer, ...]:
    if f["volume"] is False:
        return ()
    if any(f[name] is not None for name in VOLUME_FLAGS):
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


def _isosurfaces(bricks, file: SceneFile, f, base: str, base_at: str) -> tuple[IsoSurface, ...]:
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
        raise ExabricksError(f"{flag_name(modifiers[0])}: there is no iso-surface to apply it to "
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
            raise ExabricksError(f"{flag_name(name)}: there is no iso-surface coloured by a field to apply "
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


def _meshes(bricks, file: SceneFile, f) -> tuple[MeshLayer, ...]:
    # (path, colour: RGB tuple or _Colour, opacity) before flags modify them
    if f["mesh"] is not None:
        specs = [[str(path), MeshLayer.color, MeshLayer.opacity] for path in f["mesh"]]
    else:
        specs = []
        for i, e in enumerate(file.get("meshes", default=[])):
            colour = e.get("color", MeshLayer.color)
            colour = (_file_colour(file, colour, "meshes", i, "color") if isinstance(colour, dict)
                      else tuple(float(c) for c in colour))
            specs.append([str(file.mesh_file(i)), colour, float(e.get("opacity", MeshLayer.opacity))])
    for name in ("mesh_color", "mesh_color_field", "mesh_opacity"):
        if f[name] is not None and not specs:
            raise ExabricksError(f"{flag_name(name)}: there is no mesh to apply it to "
                                 "(give --mesh FILE, or meshes in the scene file)")
    out = []
    for path, colour, opacity in specs:
        if f["mesh_opacity"] is not None:
            opacity = float(f["mesh_opacity"])
        if f["mesh_color"] is not None:
            colour = tuple(float(c) for c in f["mesh_color"])
        if f["mesh_color_field"] is not None:
            colour = _Colour(f["mesh_color_field"], "--mesh-color-field")
        if isinstance(colour, _Colour):
            field, colormap = colour.build(bricks)
            out.append(MeshLayer(path, opacity=opacity, color_field=field, colormap=colormap))
        else:
            out.append(MeshLayer(path, color=colour, opacity=opacity))
    return tuple(out)


def _slices(bricks, file: SceneFile, f, base: str, base_at: str) -> tuple[Slice, ...]:
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
            raise ExabricksError(f"{flag_name(name)}: there is no slice to apply it to "
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


def _clip(file: SceneFile, f) -> Clip:
    if f["clip_box"] is not None:
        box, box_at = f["clip_box"], "--clip-box"
    else:
        box, box_at = file.get("clip", "box"), file.at("clip", "box")
    if box is not None:
        lo, hi = tuple(float(x) for x in box[:3]), tuple(float(x) for x in box[3:])
        if not (all(np.isfinite(lo + hi)) and all(a <= b for a, b in zip(lo, hi))):
            raise ExabricksError(f"{box_at}: expected a finite box with x0 <= x1, y0 <= y1, z0 <= z1 "
                                 f"(found {shown(list(lo + hi))})")
        box = (lo, hi)
    if f["clip_plane"] is not None:
        planes = [(p, "--clip-plane") for p in f["clip_plane"]]
    else:
        planes = [(p, file.at("clip", "planes", i))
                  for i, p in enumerate(file.get("clip", "planes", default=[]))]
    planes = tuple((tuple(float(x) for x in p[:3]), _nonzero(p[3:], where)) for p, where in planes)
    return Clip(box, planes)


def _instances(file: SceneFile, f) -> tuple[Instance, ...]:
    if f["mirror"] is not None:
        option = next(o for o in SCENE_OPTIONS if o.name == "mirror")
        out = tuple(Instance(mirror=plane) for plane in option.coerce(f["mirror"]))
        for instance in out:
            _within("--mirror", instance.check)
        return out
    out = []
    for i, e in enumerate(file.get("instances", default=[])):
        mirror = e.get("mirror")
        out.append(Instance(mirror=None if mirror is None else (mirror[0], float(mirror[1])),
                            rotate=None if "rotate" not in e else tuple(map(float, e["rotate"])),
                            translate=tuple(map(float, e.get("translate", Instance.translate)))))
        _within(file.at("instances", i), out[-1].check)
    return tuple(out)


def _pick(f, flag: str, file: SceneFile, path, default):
    """The flag's value if given, else the scene file's, else `default`."""
    if f[flag] is not None:
        return f[flag]
    return file.get(*path, default=default)


_CONVERT = {"float": float, "int": int, "flag": bool, "choice": str}


def _declared(part: str, file: SceneFile, f) -> dict:
    """The attributes of model part `part` ("lighting" or "settings") that declared
    options set (exabricks.scene.options, `Option.target`): each from its flag,
    else the scene file, left out (the model's default) when neither gives it."""
    out = {}
    for option in SCENE_OPTIONS:
        owner, _, attribute = (option.target or "").partition(".")
        if owner == part:
            value = _pick(f, option.name, file, option.key, None)
            if value is not None:
                out[attribute] = _CONVERT[option.kind](value)
    return out


def _lighting(file: SceneFile, f) -> Lighting:
    return Lighting(**_declared("lighting", file, f))


def _background(file: SceneFile, f) -> tuple[float, float, float, float]:
    value = _pick(f, "background", file, ("background",), None)
    if value is None:
        return Scene.background
    rgba = tuple(float(c) for c in value)
    return rgba + (1.0,) if len(rgba) == 3 else rgba  # a colour given as RGB is opaque


def _settings(file: SceneFile, f) -> Settings:
    d = Settings()
    width, height = _pick(f, "size", file, ("size",), (d.width, d.height))
    return Settings(width=int(width), height=int(height), **_declared("settings", file, f))


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
    f = normalised_flags(flags)
    check_flags(f)
    file = SceneFile(scene_path)
    if f["field"] is not None:
        base, base_at = f["field"], "--field"
    elif file.get("volumes"):
        base, base_at = file.doc["volumes"][0]["field"], file.at("volumes", 0, "field")
    else:
        base, base_at = bricks.fields[0], "the first field"
    base = _field(bricks, base, base_at)
    instances = _instances(file, f)
    scene = Scene(
        camera=_camera(bricks, file, camera_path, f, instances),
        volumes=_volumes(bricks, file, f, base, base_at),
        isosurfaces=_isosurfaces(bricks, file, f, base, base_at),
        slices=_slices(bricks, file, f, base, base_at),
        meshes=_meshes(bricks, file, f),
        instances=instances,
        clip=_clip(file, f),
        lighting=_lighting(file, f),
        background=_background(file, f),
        settings=_settings(file, f),
    )
    scene.check()
    return scene
