"""Reading and writing rendered images (.exr float, .png 8-bit) with their metadata.

In memory an image is ``rgba`` (H, W, 4) float32, *premultiplied* colour and
alpha exactly as the integrator accumulates them (docs/design.md, "Integration
and images"); row 0 is the top of the image.

- ``.exr``: float32 channels R, G, B, A (premultiplied, no colour transform,
  ZIP compression), plus Z (float32, world units; +inf where nothing was hit)
  when a depth image is given. Each metadata entry ``KEY`` is a string header
  attribute ``exabricks:KEY`` holding the JSON encoding of the value.
- ``.png``: 8-bit RGBA with *un-premultiplied* colour: ``rgb / alpha`` where
  alpha > 0 (else 0), clipped to [0, 1] and rounded; alpha rounded. Reading
  multiplies back, so a round trip is within 1/255 per channel for valid
  premultiplied input (colour <= alpha). Metadata entries are iTXt chunks
  ``exabricks:KEY`` with the same JSON values. PNG has no depth channel and a
  second output file would break the one-output rule of the stages, so depth
  with ``.png`` is refused.

Both formats also carry the standard ``software`` attribute / ``Software``
chunk. Writes go through exabricks.output (atomic for files, direct for devices).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ExabricksError
from .output import write_output

METADATA_PREFIX = "exabricks:"
FORMATS = (".exr", ".png")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ExabricksError(
            f"{path}: unknown image format {path.suffix or '(no extension)'!r} (use .exr or .png)"
        )
    return suffix


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def _encoded_metadata(metadata: dict, path: Path) -> dict[str, str]:
    """{"exabricks:KEY": JSON text}; keys must be short printable ASCII (PNG keyword rules)."""
    out = {}
    for key, value in (metadata or {}).items():
        name = METADATA_PREFIX + str(key)
        if not isinstance(key, str) or not key or len(name) > 79 or not all(32 < ord(c) < 127 for c in key):
            raise ExabricksError(f"{path}: metadata key {key!r} must be 1-69 printable ASCII characters")
        try:
            out[name] = json.dumps(value, sort_keys=True, default=_json_default, allow_nan=True)
        except (TypeError, ValueError) as e:
            raise ExabricksError(f"{path}: metadata {key!r} cannot be written as JSON: {e}") from None
    return out


def _decoded_metadata(attributes: dict) -> dict:
    out = {}
    for name, text in attributes.items():
        if isinstance(name, str) and name.startswith(METADATA_PREFIX) and isinstance(text, str):
            try:
                out[name[len(METADATA_PREFIX):]] = json.loads(text)
            except json.JSONDecodeError:
                out[name[len(METADATA_PREFIX):]] = text  # written by another tool: keep the text
    return out


def to_png_pixels(rgba) -> np.ndarray:
    """Premultiplied float RGBA (H, W, 4) -> un-premultiplied 8-bit RGBA (H, W, 4) uint8.

    Converted in bands of rows, so a large frame needs no float64 copy."""
    rgba = np.asarray(rgba)
    out = np.empty(rgba.shape, np.uint8)
    rows = max(1, (1 << 22) // max(1, rgba.shape[1] * 4))
    for r in range(0, rgba.shape[0], rows):
        band = np.asarray(rgba[r:r + rows], dtype=np.float64)
        alpha = np.clip(band[..., 3:4], 0.0, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            rgb = np.where(alpha > 0, band[..., :3] / alpha, 0.0)
        band = np.concatenate([np.clip(rgb, 0.0, 1.0), alpha], axis=-1)
        out[r:r + rows] = np.rint(band * 255.0)
    return out


def from_png_pixels(pixels) -> np.ndarray:
    """Un-premultiplied 8-bit RGBA (H, W, 4) -> premultiplied float32 RGBA in [0, 1]."""
    p = np.asarray(pixels, dtype=np.float64) / 255.0
    return np.concatenate([p[..., :3] * p[..., 3:4], p[..., 3:4]], axis=-1).astype(np.float32)


def _checked(rgba, depth, path: Path):
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.shape[0] < 1 or rgba.shape[1] < 1:
        raise ExabricksError(f"{path}: image must be (height, width, 4) RGBA, got shape {rgba.shape}")
    rgba = np.ascontiguousarray(rgba, dtype=np.float32)
    if not np.isfinite(rgba).all():
        raise ExabricksError(f"{path}: image has {int((~np.isfinite(rgba)).sum())} non-finite values")
    if depth is not None:
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        if depth.shape != rgba.shape[:2]:
            raise ExabricksError(f"{path}: depth shape {depth.shape} does not match image {rgba.shape[:2]}")
    return rgba, depth


def write_image(path, rgba, *, metadata: dict | None = None, depth=None, inputs=()) -> None:
    """Write premultiplied `rgba` (H, W, 4) float to `path` (.exr or .png), atomically.

    `metadata`: JSON-serialisable values by short ASCII key (camera, transfer
    function, dataset, settings). `depth`: optional (H, W) float32 world-unit
    distances, .exr only (channel Z). `inputs`: paths the output must not
    replace (exabricks.output).
    """
    path = Path(path)
    suffix = _suffix(path)
    rgba, depth = _checked(rgba, depth, path)
    if depth is not None and suffix == ".png":
        raise ExabricksError(f"{path}: a depth image needs .exr output (PNG has no depth channel)")
    attributes = _encoded_metadata(metadata, path)

    def write(tmp: str) -> None:
        try:
            if suffix == ".exr":
                _write_exr(tmp, rgba, depth, attributes)
            else:
                _write_png(tmp, rgba, attributes)
        except (OSError, RuntimeError) as e:
            raise ExabricksError(f"{path}: cannot write image: "
                                 f"{getattr(e, 'strerror', None) or e}") from None

    write_output(path, write, inputs=inputs)


def _write_exr(tmp: str, rgba: np.ndarray, depth, attributes: dict) -> None:
    import OpenEXR

    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "software": f"exabricks {__version__}",
        **attributes,
    }
    channels = {name: np.ascontiguousarray(rgba[..., c]) for c, name in enumerate("RGBA")}
    if depth is not None:
        channels["Z"] = depth
    with OpenEXR.File(header, channels) as f:
        f.write(tmp)


def _write_png(tmp: str, rgba: np.ndarray, attributes: dict) -> None:
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_text("Software", f"exabricks {__version__}")
    for name, text in attributes.items():
        info.add_itxt(name, text)
    Image.fromarray(to_png_pixels(rgba)).save(tmp, format="PNG", pnginfo=info)


def read_image(path):
    """Read an .exr or .png image: ``(rgba (H, W, 4) float32 premultiplied, metadata dict)``.

    EXR without an A channel is opaque (alpha 1); PNG grey or palette images
    are converted to RGBA. ExabricksError naming the file if missing or corrupt.
    """
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise ExabricksError(f"{path}: no such image file")
    if suffix == ".exr":
        rgba, metadata, _ = _read_exr(path)
        return rgba, metadata
    return _read_png(path)


def read_depth(path) -> np.ndarray | None:
    """The Z channel (H, W) float32 of an .exr written with depth, else None."""
    path = Path(path)
    if _suffix(path) != ".exr":
        return None
    if not path.is_file():
        raise ExabricksError(f"{path}: no such image file")
    return _read_exr(path)[2]


def _read_exr(path: Path):
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            header = dict(f.header())
            channels = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as e:  # OpenEXR raises RuntimeError/ValueError/... for bad files
        raise ExabricksError(f"{path}: cannot read EXR image: {e}") from None
    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise ExabricksError(
            f"{path}: EXR image has no {', '.join(missing)} channel(s) (found {', '.join(sorted(channels)) or 'none'})"
        )
    alpha = channels.get("A")
    if alpha is None:
        alpha = np.ones_like(channels["R"])
    rgba = np.stack([channels["R"], channels["G"], channels["B"], alpha], axis=-1).astype(np.float32)
    depth = channels["Z"].astype(np.float32) if "Z" in channels else None
    return rgba, _decoded_metadata(header), depth


def _read_png(path: Path):
    from PIL import Image

    try:
        with Image.open(path) as image:
            image.load()
            if image.format != "PNG":
                raise ExabricksError(f"{path}: not a PNG file (found {image.format})")
            text = dict(getattr(image, "text", {}) or {})
            pixels = np.asarray(image.convert("RGBA"))
    except ExabricksError:
        raise
    except Exception as e:  # Pillow raises UnidentifiedImageError/OSError/SyntaxError/...
        raise ExabricksError(f"{path}: cannot read PNG image: {e}") from None
    return from_png_pixels(pixels), _decoded_metadata(text)
