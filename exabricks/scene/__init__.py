"""The picture as one object: camera, volume layers, iso-surfaces, slices,
clipping, lighting, background and render settings (docs/scene.md).

- `model`: `Scene` and its parts, the modes and the limits of one frame;
- `options`: every render option declared once (flags, keywords, help);
- `file`: scene files, validated against the JSON Schema, with their errors;
- `build`: a `Scene` from the defaults, a scene file and flags (`scene_from_options`);
- `serialise`: a `Scene` as a scene-file object (`scene_to_dict`).
"""

from .build import choose_transfer_function, field_range, scene_from_options
from .file import read_scene_file, scene_file_references, scene_schema
from .model import (DEFAULT_COLORMAP, DEFAULT_FOVY, Clip, Instance, IsoSurface, Lighting, MeshLayer,
                    Scene, Settings, Slice, VolumeLayer)
from .modes import (GRADIENTS, MAX_AO_SAMPLES, MAX_CLIP_PLANES, MAX_ISOSURFACES, MAX_SLICES, MAX_VOLUMES,
                    RECONSTRUCTIONS, SHADING_MODES)
from .options import FLAGS, JOB_OPTIONS, SCENE_OPTIONS, Option, check_flags
from .serialise import scene_to_dict

__all__ = [
    "DEFAULT_COLORMAP", "DEFAULT_FOVY", "FLAGS", "GRADIENTS", "JOB_OPTIONS", "MAX_AO_SAMPLES",
    "MAX_CLIP_PLANES", "MAX_ISOSURFACES", "MAX_SLICES", "MAX_VOLUMES", "RECONSTRUCTIONS",
    "SCENE_OPTIONS", "SHADING_MODES", "Clip", "Instance", "IsoSurface", "Lighting", "Option", "Scene",
    "MeshLayer", "Settings", "Slice", "VolumeLayer", "check_flags", "choose_transfer_function", "field_range",
    "read_scene_file", "scene_file_references", "scene_from_options", "scene_schema",
    "scene_to_dict",
]
