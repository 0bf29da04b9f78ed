"""Image comparison: RMSE, PSNR, max abs difference and SSIM of two RGBA images.

All metrics run on float64 copies of premultiplied RGBA arrays (H, W, 4) in
[0, 1] (any channel count works, as long as both images agree):

- ``rmse``: sqrt of the mean squared difference over all pixels and channels.
- ``max_abs``: the largest absolute difference of any channel of any pixel.
- ``psnr``: ``10 log10(1 / mse)`` in dB (peak 1.0); ``inf`` for identical images.
- ``ssim``: structural similarity (Wang, Bovik, Sheikh & Simoncelli 2004):
  11x11 Gaussian window with sigma 1.5 (normalised to sum 1), K1 = 0.01,
  K2 = 0.03, dynamic range L = 1; the SSIM map is averaged over the windows
  that lie fully inside the image (the paper's MATLAB code, filter 'valid'),
  per channel, then over channels. ``None`` for images smaller than 11x11.
"""

from __future__ import annotations

import math

import numpy as np

from ..util.errors import ExabricksError

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_L = 1.0


def _pair(a, b, names):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ExabricksError(
            f"images differ in size: {names[0]} is {_shape(a.shape)}, {names[1]} is {_shape(b.shape)}"
        )
    if a.ndim != 3 or a.size == 0:
        raise ExabricksError(f"images must be (height, width, channels), got {a.shape}")
    for name, x in zip(names, (a, b)):
        if not np.isfinite(x).all():
            raise ExabricksError(f"{name} has {int((~np.isfinite(x)).sum())} non-finite values")
    return a, b


def _shape(shape) -> str:
    if len(shape) == 3:
        return f"{shape[1]}x{shape[0]} ({shape[2]} channels)"
    return str(shape)


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """The 1-D Gaussian (size,) float64, normalised to sum 1; its outer product is the 2-D window."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return g / g.sum()


def _filter_valid(x: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Separable 'valid' correlation of (H, W, C) with g x g: (H - n + 1, W - n + 1, C)."""
    n = len(g)
    rows = x.shape[0] - n + 1
    cols = x.shape[1] - n + 1
    tmp = sum(g[k] * x[k:k + rows] for k in range(n))
    return sum(g[k] * tmp[:, k:k + cols] for k in range(n))


def ssim(a, b) -> float | None:
    """Mean SSIM of (H, W, C) float images in [0, 1] (module docstring); None if < 11x11."""
    a, b = _pair(a, b, ("first image", "second image"))
    if min(a.shape[:2]) < SSIM_WINDOW:
        return None
    g = gaussian_window()
    c1 = (SSIM_K1 * SSIM_L) ** 2
    c2 = (SSIM_K2 * SSIM_L) ** 2
    mu_a = _filter_valid(a, g)
    mu_b = _filter_valid(b, g)
    var_a = _filter_valid(a * a, g) - mu_a * mu_a
    var_b = _filter_valid(b * b, g) - mu_b * mu_b
    cov = _filter_valid(a * b, g) - mu_a * mu_b
    ssim_map = ((2.0 * mu_a * mu_b + c1) * (2.0 * cov + c2)) / (
        (mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2))
    return float(ssim_map.mean(axis=(0, 1)).mean())


def compare_images(a, b, *, names=("first image", "second image")) -> dict:
    """Metrics of two images of the same shape (H, W, C) float.

    Returns ``{"rmse", "psnr", "max_abs", "ssim"}`` as Python floats (psnr
    may be inf, ssim None for images under 11x11). `names` label the images
    in error messages (e.g. their file names).
    """
    a, b = _pair(a, b, names)
    diff = a - b
    mse = float(np.mean(diff * diff))
    return {
        "rmse": math.sqrt(mse),
        "psnr": math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse),
        "max_abs": float(np.max(np.abs(diff))),
        "ssim": ssim(a, b),
    }


def diff_image(a, b, *, scale: float | None = None) -> np.ndarray:
    """An opaque grey visualisation (H, W, 4) float32 of where two images differ.

    Each pixel's grey level is the largest absolute difference over its
    channels times `scale`, clipped to [0, 1]; the default scale maps the
    image's largest difference to white (an all-black image when identical).
    Alpha is 1, so the same pixels are written to .exr and .png.
    """
    a, b = _pair(a, b, ("first image", "second image"))
    d = np.abs(a - b).max(axis=-1)
    if scale is None:
        peak = float(d.max())
        scale = 1.0 / peak if peak > 0 else 1.0
    grey = np.clip(d * float(scale), 0.0, 1.0)
    return np.stack([grey, grey, grey, np.ones_like(grey)], axis=-1).astype(np.float32)
