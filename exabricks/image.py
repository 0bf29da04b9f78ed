"""`eb.Image`: one rendered frame in memory, as `render` writes it to a file."""

from __future__ import annotations

import os

import numpy as np


class Image:
    """A rendered frame.

    rgba:     (H, W, 4) float32, premultiplied colour and opacity, row 0 at the top
              (docs/design.md, "Integration and images").
    depth:    (H, W) float32 world distance to the first opaque hit (+inf: none), or
              None when the frame was drawn without `depth=True`.
    metadata: what the image file carries: software, camera, dataset, settings
              (samples, ms, device), scene, transfer function.
    """

    def __init__(self, rgba: np.ndarray, depth: np.ndarray | None = None, metadata: dict | None = None):
        self.rgba = rgba
        self.depth = depth
        self.metadata = metadata or {}

    @classmethod
    def read(cls, path: str | os.PathLike) -> Image:
        """The image in an .exr or .png file that `render` wrote (depth from an .exr)."""
        from .image_io import read_depth, read_image

        rgba, metadata = read_image(path)
        return cls(rgba, read_depth(path), metadata)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.rgba.shape[1], self.rgba.shape[0]

    def save(self, path: str | os.PathLike) -> None:
        """Write the frame as `render -o path` does: .exr (float RGBA, and Z with a
        depth) or .png (8-bit), with the metadata, atomically."""
        from .image_io import write_image

        write_image(path, self.rgba, metadata=self.metadata, depth=self.depth)

    def to_rgba8(self) -> np.ndarray:
        """(H, W, 4) uint8, un-premultiplied, as the .png holds it."""
        from .image_io import to_png_pixels

        return to_png_pixels(self.rgba)

    def _repr_png_(self) -> bytes:
        """The frame as PNG bytes, for Jupyter's rich display."""
        import io

        from PIL import Image as PILImage

        out = io.BytesIO()
        PILImage.fromarray(self.to_rgba8(), "RGBA").save(out, format="PNG")
        return out.getvalue()

    def __repr__(self) -> str:
        settings = self.metadata.get("settings", {})
        ms = f", {settings['ms']:.1f} ms" if "ms" in settings else ""
        return f"<exabricks.Image {self.size[0]}x{self.size[1]}{ms}>"
