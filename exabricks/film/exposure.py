"""The automatic exposure: the film's light meter (docs/scene.md, "Exposure").

As yt normalises its volume renderings, the automatic picture is brought to
the display's range: the METER_QUANTILE of the luminance over the pixels that
hold data (opacity at least DATA_ALPHA, before the background) is placed at
TARGET_LUMINANCE, so that the brightest structure is near white whatever the
translucency of the medium. It is measured on the frame's own premultiplied
radiance (every domain, sample and tile composited), at most `MAX_PIXELS`
pixels of it evenly strided, and given in stops within [MIN_STOPS, MAX_STOPS];
`--exposure` adds to it.
"""

from __future__ import annotations

import math

import numpy as np

# Rec. 709 luminance of linear RGB.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)
# Pixels at least this opaque hold data.
DATA_ALPHA = 0.05
# The luminance quantile over the data placed at TARGET_LUMINANCE: the brightest
# structure, less the brightest hundredth (a few hot pixels do not set it).
METER_QUANTILE = 0.99
TARGET_LUMINANCE = 0.9
# Fewer data pixels than this: nothing to meter (0 stops).
MIN_PIXELS = 16
MIN_STOPS, MAX_STOPS = -4.0, 4.0
MAX_PIXELS = 1 << 20


def metered_stops(rgba: np.ndarray) -> float:
    """The automatic exposure of the premultiplied radiance `rgba` (float32
    (H, W, 4), before the background), in stops (module docstring)."""
    pixels = rgba.reshape(-1, 4)
    stride = max(1, -(-len(pixels) // MAX_PIXELS))
    pixels = pixels[::stride]
    seen = pixels[pixels[:, 3] >= DATA_ALPHA, :3] @ LUMINANCE
    if len(seen) < MIN_PIXELS:
        return 0.0
    level = float(np.quantile(seen, METER_QUANTILE))
    if not (level > 0.0 and math.isfinite(level)):
        return 0.0
    return float(np.clip(math.log2(TARGET_LUMINANCE / level), MIN_STOPS, MAX_STOPS))


def fixed_exposure(scene, stops: float):
    """`scene` with `stops` metered once added to settings.exposure and the
    automatic exposure turned off: frames that must share one exposure (the
    bands of a tiled frame, the frames of a series) develop with it alike."""
    from dataclasses import replace

    s = scene.settings
    return scene.replace(settings=replace(s, auto_exposure=False, exposure=float(s.exposure) + stops))
