"""The shadow integrator's directional light of a scene, resolved (docs/design-rendering.md,
"Lights and shadows"): the direction toward it (the scene's, else the camera's key
light), its colour times its intensity, and the ambient term, as the kernels take
them (kernels/light.cl) and the float64 references use them."""

from __future__ import annotations

import math

import numpy as np

from ..util.vectors import unit

# The key light when the scene names no direction: KEY_ELEVATION degrees above the
# view, KEY_AZIMUTH degrees to its left, from in front of the data (behind the
# camera): from the side enough that what faces away from it, and what lies in
# the shadow of denser matter, darkens in sight of the camera.
KEY_ELEVATION = 35.0
KEY_AZIMUTH = 60.0
# Where a surface hit's shadow ray starts, in finest cell widths off the surface
# along its normal: past the bisection's tolerance (1e-3 of a cell) and the
# surface's cell-scale bumps (the field's terraces), so that a ray that grazes
# the surface does not shadow it with itself ("shadow acne").
SHADOW_BIAS_CELLS = 0.5


def light_direction(scene) -> np.ndarray:
    """The unit world direction toward the light of `scene` (exabricks.scene.Scene), float64."""
    if scene.lighting.light is not None:
        return unit(scene.lighting.light)
    _, forward, du, dv = scene.camera.frame(1, 1)
    right, up = du / np.linalg.norm(du), dv / np.linalg.norm(dv)
    elevation, azimuth = math.radians(KEY_ELEVATION), math.radians(KEY_AZIMUTH)
    d = (math.cos(elevation) * (math.cos(azimuth) * -forward - math.sin(azimuth) * right)
         + math.sin(elevation) * up)
    return d / np.linalg.norm(d)


def light_params(scene, finest_width: float) -> dict:
    """The eb_params members of the light (kernel_abi.PARAMS: light_dir, light_rgb) of a
    dataset whose finest cells are `finest_width` wide (world)."""
    lighting = scene.lighting
    rgb = np.asarray(lighting.light_color, np.float64) * lighting.light_intensity
    return {"light_dir": (*light_direction(scene), SHADOW_BIAS_CELLS * finest_width),
            "light_rgb": (*rgb, lighting.ambient)}
