"""The film: where a frame's integrated radiance becomes its picture (as pbrt-v4's
`Film`).

Every way of drawing a frame (resident, in tiles, streamed domain by domain
under a memory budget, progressive, MPI in data or image mode, instanced)
composites the premultiplied radiance (float32 RGBA) of all its domains,
samples and tiles first (`Renderer.integrate` and the compositing that follows
it), and then develops it here, once: the exposure (the automatic one,
exposure.py, measured on the composited frame, plus --exposure), the optional denoiser
(denoise.py, whole frames only), then the background.  What is applied pixel by
pixel is the same whether the frame is developed whole or a tile or band at a
time.  The 8-bit encoding of a PNG (image_io.to_png_pixels)
and the annotations (annotate) work on the developed frame; an EXR keeps it in
float.
"""

from __future__ import annotations

import numpy as np

from .denoise import denoise
from .exposure import metered_stops


def develop(rgba: np.ndarray, scene, stats: dict | None = None) -> np.ndarray:
    """`rgba` (premultiplied radiance, float32 (..., 4), composited over every
    domain and sample) developed in place for `scene` (exabricks.scene.Scene):
    its colour scaled by 2**(the automatic exposure + settings.exposure), the
    automatic exposure `metered_stops` of `rgba` where settings.auto_exposure
    (else 0) and recorded in `stats` as "metered_exposure"; denoised with
    settings.denoise (a whole frame), then composited over the background.
    Returns `rgba`."""
    exposure = float(scene.settings.exposure)
    if scene.settings.auto_exposure:
        metered = metered_stops(rgba)
        exposure += metered
        if stats is not None:
            stats["metered_exposure"] = metered
    if exposure:
        rgba[..., :3] *= np.float32(2.0 ** exposure)
    if scene.settings.denoise:
        denoise(rgba)
    return over_background(rgba, scene.background)


def over_background(rgba: np.ndarray, background) -> np.ndarray:
    """`rgba` (premultiplied) composited over the RGBA `background`, in place."""
    r, g, b, a = (float(c) for c in background)
    if a > 0.0:
        behind = 1.0 - rgba[..., 3:4]
        rgba += behind * np.array([r * a, g * a, b * a, a], np.float32)
    return rgba
