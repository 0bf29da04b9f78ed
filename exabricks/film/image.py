"""`eb.Image`: one rendered frame in memory, as `render` writes it to a file."""

from __future__ import annotations

import os

import numpy as np


class Image:
    """A rendered frame. Each parameter is kept as the attribute of its name.

    Parameters
    ----------
    rgba
        (H, W, 4) float32, premultiplied colour and opacity, row 0 at the top
        (docs/design-rendering.md, "Integration and images").
    depth
        (H, W) float32 world distance to the first opaque hit (+inf: none), or
        None when the frame was drawn without `depth=True`.
    metadata
        What the image file carries: software, camera, dataset, settings
        (samples, ms, device), scene, transfer function (None: {}).
    scene
        The eb.Scene it was drawn with (None for an image read from a file).
    facts
        What the source says of itself (simulation time, units;
        exabricks.film.layout.facts_from_meta), for `annotated`.
    inputs
        The files it was drawn from, which `save` never replaces
        (exabricks.util.output); kept as a tuple.
    """

    def __init__(self, rgba: np.ndarray, depth: np.ndarray | None = None, metadata: dict | None = None,
                 *, scene=None, facts: dict | None = None, inputs=()):
        self.rgba = rgba
        self.depth = depth
        self.metadata = metadata or {}
        self.scene = scene
        self.facts = facts
        self.inputs = tuple(inputs)

    @classmethod
    def read(cls, path: str | os.PathLike) -> Image:
        """The image in an .exr or .png file that `render` wrote (depth from an .exr).

        Parameters
        ----------
        path
            An .exr or .png file.

        Returns
        -------
        Image
            Its pixels (premultiplied) and metadata, with no scene and no facts.

        Raises
        ------
        ExabricksError
            Another suffix, or the file is missing or corrupt.
        """
        from .image_io import read_depth, read_image

        rgba, metadata = read_image(path)
        return cls(rgba, read_depth(path), metadata)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.rgba.shape[1], self.rgba.shape[0]

    def save(self, path: str | os.PathLike, *, annotate: bool = False, title: str | None = None) -> None:
        """Write the frame as `render -o path` does: .exr (float RGBA, and Z with a
        depth) or .png (8-bit), with the metadata, atomically; `annotate` (a .png)
        as `render --annotate [--title]` does.

        Parameters
        ----------
        path
            The file: .exr, or .png composited over the scene's background (black
            for a fully transparent one) unless its settings are `transparent`; the
            .png of an image read from a file keeps its alpha.
        annotate
            Write `annotated(title=title)` instead of the frame (.png only).
        title
            With `annotate`: the line above the frame.

        Raises
        ------
        ExabricksError
            `title` without `annotate`; `annotate` to other than a .png; a suffix
            other than .exr or .png; a depth to a .png; `path` names one of
            `inputs` or cannot be written; `annotated`'s errors.
        """
        from pathlib import Path

        from ..util.errors import ExabricksError
        from .image_io import write_image

        if title is not None and not annotate:
            raise ExabricksError("title goes with annotate=True")
        if annotate and Path(path).suffix.lower() != ".png":
            raise ExabricksError(f"{path}: an annotated picture is a .png; an .exr stays the raw "
                                 "integration")
        from .annotate import png_backdrop

        image = self.annotated(title=title) if annotate else self
        write_image(path, image.rgba, metadata=self.metadata, depth=image.depth,
                    backdrop=png_backdrop(self.scene), inputs=self.inputs)

    def annotated(self, *, title: str | None = None) -> Image:
        """The picture with colour bars (the volume's with its opacity curve), field
        names and units, the simulation time, a scale bar and an axes triad beside
        the frame (docs/annotate.md): an opaque Image, without depth.

        Parameters
        ----------
        title
            One line of text above the frame, in bold (stripped; None or blank: none).

        Returns
        -------
        Image
            The frame with the margins around it, and this image's metadata, scene,
            facts and inputs.

        Raises
        ------
        ExabricksError
            The image has no scene (it was read from a file), or `title` is not
            text or longer than one line holds (200 characters).
        """
        from .annotate import annotate
        from ..util.errors import ExabricksError
        from .image_io import from_png_pixels

        if self.scene is None:
            raise ExabricksError("an image read from a file has no scene to annotate: render it "
                                 "with eb.render, or with `exabricks render --annotate`")
        pixels = annotate(self.rgba, self.scene, facts=self.facts, title=title)
        return Image(from_png_pixels(pixels), None, self.metadata, scene=self.scene, facts=self.facts,
                     inputs=self.inputs)

    def to_rgba8(self) -> np.ndarray:
        """(H, W, 4) uint8, un-premultiplied: the frame with its own alpha, over no
        background (the .png of a transparent scene; `shown` lays the background).

        Returns
        -------
        numpy.ndarray
            (H, W, 4) uint8, rounded; the frame's own alpha, over no background
            (`shown` composites it).
        """
        from .image_io import to_png_pixels

        return to_png_pixels(self.rgba)

    def shown(self) -> np.ndarray:
        """(H, W, 3) uint8: the frame over its scene's background made opaque (black
        behind a transparent one, as yt shows a frame), as a notebook displays it.

        Returns
        -------
        numpy.ndarray
            (H, W, 3) uint8; opaque pixels as `to_rgba8` gives them (black behind an
            image without a scene).
        """
        from .layout import backdrop_color
        from .annotate import frame_pixels

        background = self.scene.background if self.scene is not None else (0.0, 0.0, 0.0, 0.0)
        return frame_pixels(self.rgba, backdrop_color(background))

    def _repr_png_(self) -> bytes:
        """`shown()` as PNG bytes, for Jupyter's rich display."""
        import io

        from PIL import Image as PILImage

        out = io.BytesIO()
        PILImage.fromarray(self.shown(), "RGB").save(out, format="PNG")
        return out.getvalue()

    def __repr__(self) -> str:
        settings = self.metadata.get("settings", {})
        ms = f", {settings['ms']:.1f} ms" if "ms" in settings else ""
        return f"<exabricks.Image {self.size[0]}x{self.size[1]}{ms}>"
