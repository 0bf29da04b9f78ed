"""Checks of the pictures that documents show or their examples make."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def assert_visible_png(path: Path, least: float = 0.05) -> None:
    """`path` is an opaque PNG in which at least `least` of the pixels stand out from
    its most common colour (the background) by more than 16 of 255."""
    from PIL import Image

    with Image.open(path) as im:
        assert im.format == "PNG", (path, im.format)
        rgba = np.asarray(im.convert("RGBA")).astype(np.int16)
    assert (rgba[..., 3] == 255).all(), f"{path.name}: not opaque"
    colours, counts = np.unique(rgba[..., :3].reshape(-1, 3), axis=0, return_counts=True)
    background = colours[counts.argmax()]
    shown = (np.abs(rgba[..., :3] - background).max(axis=-1) > 16).mean()
    assert shown >= least, f"{path.name}: {shown:.1%} of the pixels show data (at least {least:.0%})"
