"""The optional denoiser of the film (docs/design-rendering.md, "Path tracing"):
Intel Open Image Denoise (pyoidn, `pip install 'exabricks[denoise]'`) over a
whole developed-to-be frame, for previews of the path and shadow integrators'
noisy frames. Never the default: a denoised frame is not an estimate of the
integral (its error is the network's, not 1/sqrt(spp)), so a reference image
stays raw; the image's metadata records `settings.denoise`."""

from __future__ import annotations

import numpy as np

from ..util.errors import ExabricksError

PACKAGE = "pyoidn"


def check() -> None:
    """ExabricksError, naming the package, unless the denoiser can be loaded."""
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        raise ExabricksError("--denoise needs Intel Open Image Denoise: pip install "
                             f"'exabricks[denoise]' ({PACKAGE})") from None


def denoise(rgba: np.ndarray) -> np.ndarray:
    """`rgba` (premultiplied radiance, float32 (H, W, 4)) denoised in place: its
    colour as a high-dynamic-range image, its alpha (the coverage the background
    shows through) as a grey one, kept in [0, 1], the colour non-negative."""
    check()
    import pyoidn

    colour = np.ascontiguousarray(rgba[..., :3], dtype=np.float32)
    alpha = np.ascontiguousarray(np.repeat(rgba[..., 3:4], 3, axis=-1), dtype=np.float32)
    rgba[..., :3] = np.maximum(pyoidn.denoise(colour, hdr=True), 0.0)
    rgba[..., 3] = np.clip(pyoidn.denoise(alpha).mean(axis=-1), 0.0, 1.0)
    return rgba
