"""A scene as a scene-file object (the image metadata's `scene`; docs/scene.md)."""

from __future__ import annotations

from .model import Scene


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
