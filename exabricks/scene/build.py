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

from ..picture.camera import Camera
from ..util.errors import ExabricksError, quoted
from ..picture.field_statistics import field_range
from ..picture.transfer_function import TransferFunction, matplotlib_colormap
from .applies import check_applies
from .file import SceneFile, shown
from .model import (DEFAULT_COLORMAP, DEFAULT_FOVY, Clip, Instance, IsoSurface, Lighting, MeshLayer, Scene,
                    Settings, Slice, VolumeLayer)
from .options import SCENE_OPTIONS, VOLUME_FLAGS, check_flags, flag_name, normalised_flags


# Geometry of embedded-boundary (cut-cell) plotfiles: volume and area fractions,
# centroids; not what a user means by "the data" (lower-case prefixes).
GEOMETRY_FIELDS = ("vfrac", "volfrac", "volume_fraction", "afrac", "areafrac", "area_frac", "apx",
                   "apy", "apz", "fcx", "fcy", "fcz", "centroid", "bcent", "bnorm", "barea")


# Fields drawn first when present, as yt's create_scene draws ("gas", "density"):
# the names codes give the mass density (lower case).
DENSITY_FIELDS = ("density", "rho", "dens")


def default_field(fields) -> str:
    """The field drawn when none is named: the mass density where the data has
    one (`DENSITY_FIELDS`), else the first field that is not embedded-boundary
    geometry (`GEOMETRY_FIELDS`), else the first."""
    for name in fields:
        if name.lower() in DENSITY_FIELDS:
            return name
    for name in fields:
        if not name.lower().replace("-", "_").startswith(GEOMETRY_FIELDS):
            return name
    return fields[0]


def _data_range(bricks, field: str) -> tuple[float, float]:
    from ..picture.transfer_function import widen_degenerate_range

    return widen_degenerate_range(field_range(bricks, field))


def choose_transfer_function(bricks, field, preset=None, colormap=None, value_range=None,
                             opacity=None, scale=None, *, builtin: bool | None = None) -> TransferFunction:
    """The transfer function of `--transfer-function`, `--colormap`, `--range`,
    `--opacity` and `--scale` for `field` (docs/scene.md):

    - `colormap` with `opacity`: that matplotlib colormap over `value_range`
      (default: the field's finite range) with the `opacity` knots spread evenly
      over it, both on the axis of `scale` (exabricks.picture.scaling; default auto);
    - `preset` naming a built-in preset (and no such file): its shape stretched
      over `value_range` or the field's range on that axis;
    - `preset` naming a preset file: used as stored, or rescaled to `value_range`;
    - neither, or `colormap` alone: the automatic transfer function
      (exabricks.picture.auto_transfer) in that colormap (default viridis).

    `builtin`: whether `preset` is a built-in name (None: where no such file exists).
    """
    from ..picture.auto_transfer import automatic_transfer_function, field_axis
    from ..picture.scaling import scaled_range
    from ..picture.transfer_function import builtin_presets, preset_path

    if preset and colormap:
        raise ExabricksError("give --transfer-function or --colormap, not both")
    if opacity and not colormap:
        raise ExabricksError("--opacity goes with --colormap")
    if preset is None and not opacity:
        return automatic_transfer_function(bricks, field, scale=scale, value_range=value_range,
                                           colormap=colormap or DEFAULT_COLORMAP)
    if builtin is None and preset is not None:
        builtin = not Path(preset).exists() and preset in builtin_presets()
    if preset is not None and not builtin:
        tf = TransferFunction.from_paraview(preset)
        return tf.rescaled(value_range) if value_range else tf
    scale, threshold, data_range, floor = field_axis(bricks, field, scale)
    axis = scale, threshold
    span = scaled_range(tuple(value_range) if value_range else data_range, *axis, floor)
    if colormap:
        shape = TransferFunction.from_colormap(colormap, span, opacity=opacity)
    else:  # built-in presets are shapes over [0, 1]: stretched over the data (ParaView's rescale)
        shape = TransferFunction.from_paraview(preset_path(preset)).rescaled(span)
    return shape.on_scale(*axis)


def _within(where: str, build, *args, **kw):
    """`build(*args, **kw)`, with `where` put in front of its ExabricksError."""
    try:
        return build(*args, **kw)
    except ExabricksError as e:
        raise ExabricksError(f"{where}: {e}") from None


def _field(bricks, name: str, where: str) -> str:
    if name not in bricks.fields:
        raise ExabricksError(f"{where}: no field {quoted(name)} (fields: "
                             f"{', '.join(bricks.fields) or 'none'})")
    return name


def _value_range(value, where: str):
    """(low, high) from a scene file or flag, or None; low < high."""
    if value is None:
        return None
    lo, hi = (float(v) for v in value)
    if np.isfinite(lo) and np.isfinite(hi) and lo >= hi:
        raise ExabricksError(f"{where}: low {lo:g} {'>' if lo > hi else '='} high {hi:g} (expected low < high, "
                             "the low end first)")
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


def _camera(bricks, file: SceneFile, camera_path, f, instances=(), volumes=(), aspect=1.0) -> Camera:
    from ..picture.framing import framed_camera, view_axes, visible_points

    inline = file.get("camera")
    if camera_path is not None:
        camera = Camera.from_json(camera_path)
    elif isinstance(inline, dict):
        camera = Camera.from_dict({"fovy": DEFAULT_FOVY, **inline}, source=file.at("camera"))
    elif inline is not None:
        camera = _within(file.at("camera"), Camera.from_json, file.camera_file())
    elif f["position"] is not None and f["look_at"] is not None:
        # The flags place the camera whole: nothing to frame (a pass over the data saved).
        from ..picture.camera import DEFAULT_UP

        camera = Camera(tuple(f["position"]), tuple(f["look_at"]), DEFAULT_UP, DEFAULT_FOVY)
    else:
        # What the volume layers make visible (else the whole dataset), on every copy:
        # boxes along the view's axes (tightest) unless copies turn them.
        corners = visible_points(bricks, volumes, axes=None if instances else view_axes())
        placed = np.concatenate([corners] + [corners @ r.T + t for r, t in
                                             (i.affine() for i in instances)])
        camera = framed_camera(placed, aspect=aspect)
    return camera.with_overrides(position=f["position"], look_at=f["look_at"], up=f["up"], fovy=f["fovy"])


def _file_transfer_function(bricks, file: SceneFile, i: int, field: str) -> TransferFunction:
    where = file.at("volumes", i, "transfer_function")
    entry = file.doc["volumes"][i]
    spec = entry.get("transfer_function")
    value_range = _value_range(entry.get("range"), file.at("volumes", i, "range"))
    scale = entry.get("scale")
    if isinstance(spec, dict) and "colormap" not in spec:
        tf = TransferFunction.from_paraview_dict(spec, source=where)
        return tf.rescaled(value_range) if value_range else tf
    if isinstance(spec, dict):
        colormap, opacity, preset = spec["colormap"], spec.get("opacity"), None
    else:
        colormap, opacity = None, None
        preset = None if spec is None else file.preset_file(spec, "volumes", i, "transfer_function")
    builtin = isinstance(spec, str) and preset is None
    return _within(where, choose_transfer_function, bricks, field, spec if builtin else preset,
                   colormap, value_range, opacity and tuple(opacity), scale, builtin=builtin)


def _volumes(bricks, file: SceneFile, f, base: str, base_at: str) -> tuple[VolumeLayer, ...]:
    if f["volume"] is False:
        return ()
    if any(f[name] is not None for name in VOLUME_FLAGS):
        # the flags' own faults name the flag, not the field they apply to
        if f["colormap"] is not None:
            _within(flag_name("colormap"), matplotlib_colormap, f["colormap"])
        value_range = _value_range(f["range"], flag_name("range"))
        tf = _within(base_at if f["field"] is None else "--field", choose_transfer_function, bricks, base,
                     f["transfer_function"], f["colormap"], value_range, f["opacity"], f["scale"])
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
                vector = option.nargs > 1 or option.kind == "numbers"
                out[attribute] = (tuple(float(v) for v in value) if vector
                                  else _CONVERT[option.kind](value))
    return out


def _lighting(file: SceneFile, f) -> Lighting:
    lighting = Lighting(**_declared("lighting", file, f))
    if lighting.light is not None and not any(lighting.light):
        where = "--light" if f["light"] is not None else file.at("lighting", "light", "direction")
        raise ExabricksError(f"{where}: the direction toward the light is zero")
    return lighting


def _background(file: SceneFile, f) -> tuple[float, float, float, float]:
    value = _pick(f, "background", file, ("background",), None)
    if value is None:
        return Scene.background
    rgba = tuple(float(c) for c in value)
    return rgba + (1.0,) if len(rgba) == 3 else rgba  # a colour given as RGB is opaque


def _settings(file: SceneFile, f, volumes) -> Settings:
    """The settings. Where every volume layer's transfer function is the
    automatic one, and neither the flags nor the file say otherwise, the frame
    is exposed automatically and sampled at AUTOMATIC_SAMPLING_RATE: its
    layers and equalised colours change faster with the value than most
    hand-made functions (docs/scene.md, "Defaults that show the data")."""
    from ..picture.auto_transfer import AUTOMATIC_SAMPLING_RATE, DEFAULT_NAME

    d = Settings()
    width, height = _pick(f, "size", file, ("size",), (d.width, d.height))
    declared = _declared("settings", file, f)
    if volumes and all(v.transfer_function.name == DEFAULT_NAME for v in volumes):
        declared.setdefault("auto_exposure", True)
        declared.setdefault("sampling_rate", AUTOMATIC_SAMPLING_RATE)
    return Settings(width=int(width), height=int(height), **declared)


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
        base, base_at = default_field(bricks.fields), "the default field"
    base = _field(bricks, base, base_at)
    instances = _instances(file, f)
    volumes = _volumes(bricks, file, f, base, base_at)
    settings = _settings(file, f, volumes)
    scene = Scene(
        camera=_camera(bricks, file, camera_path, f, instances, volumes, settings.width / settings.height),
        volumes=volumes,
        isosurfaces=_isosurfaces(bricks, file, f, base, base_at),
        slices=_slices(bricks, file, f, base, base_at),
        meshes=_meshes(bricks, file, f),
        instances=instances,
        clip=_clip(file, f),
        lighting=_lighting(file, f),
        background=_background(file, f),
        settings=settings,
    )
    scene.check()
    check_applies(scene, SCENE_OPTIONS, f)
    return scene
