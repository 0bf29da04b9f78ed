"""A scene as a scene-file object (the image metadata's `scene`; docs/scene.md)."""

from __future__ import annotations

from .model import Scene
from .options import SCENE_OPTIONS


def scene_to_dict(scene: Scene) -> dict:
    """The scene as a JSON-ready scene-file object (image metadata); reading it
    back as a scene file gives the same scene. Transfer functions and colour
    maps are ParaView preset objects over their data ranges; the declared scalar
    options (exabricks.scene.options, `Option.target`) sit at their key paths,
    left out where the model holds None (its default, computed at render time)."""
    isosurfaces = []
    for iso in scene.isosurfaces:
        color = ({"field": iso.color_field, "colormap": iso.colormap.to_paraview_dict()}
                 if iso.color_field else list(iso.color))
        isosurfaces.append({"field": iso.field, "value": iso.value, "color": color, "opacity": iso.opacity})
    clip = {"planes": [[*p, *n] for p, n in scene.clip.planes]}
    if scene.clip.box is not None:
        clip["box"] = [*scene.clip.box[0], *scene.clip.box[1]]
    out = {
        "camera": scene.camera.to_dict(),
        "volumes": [{"field": v.field, "transfer_function": v.transfer_function.to_paraview_dict()}
                    for v in scene.volumes],
        "isosurfaces": isosurfaces,
        "slices": [{"point": list(sl.point), "normal": list(sl.normal), "field": sl.field,
                    "colormap": sl.colormap.to_paraview_dict(), "opacity": sl.opacity}
                   for sl in scene.slices],
        "meshes": [{"path": m.path, "opacity": m.opacity,
                    "color": ({"field": m.color_field, "colormap": m.colormap.to_paraview_dict()}
                              if m.color_field else list(m.color))} for m in scene.meshes],
        "instances": [_instance(i) for i in scene.instances],
        "clip": clip,
        "lighting": {},
        "background": list(scene.background),
        "size": [scene.settings.width, scene.settings.height],
    }
    for option in SCENE_OPTIONS:
        if option.target:
            value = option.value_in(scene)
            if value is not None:
                node = out
                for key in option.key[:-1]:
                    node = node.setdefault(key, {})
                node[option.key[-1]] = list(value) if isinstance(value, tuple) else value
    return out


def _instance(instance) -> dict:
    out = {"translate": list(instance.translate)}
    if instance.mirror is not None:
        out["mirror"] = list(instance.mirror)
    if instance.rotate is not None:
        out["rotate"] = list(instance.rotate)
    return out
