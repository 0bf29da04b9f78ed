"""Reading and writing rendered images (.exr float, .png 8-bit) with their metadata.

In memory an image is ``rgba`` (H, W, 4) float32, *premultiplied* colour and
alpha exactly as the integrator accumulates them (docs/design-rendering.md, "Integration
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
chunk. Writes go through exabricks.util.output (atomic for files, direct for devices).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..util.version import __version__
from ..util.errors import ExabricksError
from ..util.jsonfile import json_default
from ..util.output import write_output

METADATA_PREFIX = "exabricks:"
FORMATS = (".exr", ".png")


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ExabricksError(
            f"{path}: unknown image format {path.suffix or '(no extension)'!r} (use .exr or .png)"
        )
    return suffix


def _encoded_metadata(metadata: dict, path: Path) -> dict[str, str]:
    """{"exabricks:KEY": JSON text}; keys must be short printable ASCII (PNG keyword rules)."""
    out = {}
    for key, value in (metadata or {}).items():
        name = METADATA_PREFIX + str(key)
        if not isinstance(key, str) or not key or len(name) > 79 or not all(32 < ord(c) < 127 for c in key):
            raise ExabricksError(f"{path}: metadata key {key!r} must be 1-69 printable ASCII characters")
        try:
            out[name] = json.dumps(value, sort_keys=True, default=json_default, allow_nan=True)
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


def to_png_pixels(rgba, backdrop=None) -> np.ndarray:
    """Premultiplied float RGBA (H, W, 4) -> un-premultiplied 8-bit RGBA (H, W, 4) uint8;
    with `backdrop` (opaque RGB in [0, 1]), composited over it first: opaque.

    Converted in bands of rows, so a large frame needs no float64 copy."""
    rgba = np.asarray(rgba)
    out = np.empty(rgba.shape, np.uint8)
    rows = max(1, (1 << 16) // max(1, rgba.shape[1] * 4))
    for r in range(0, rgba.shape[0], rows):
        band = np.asarray(rgba[r:r + rows], dtype=np.float64)
        if backdrop is not None:
            band = np.concatenate([band[..., :3] + (1.0 - np.clip(band[..., 3:4], 0.0, 1.0))
                                   * np.asarray(backdrop, np.float64), np.ones_like(band[..., 3:4])], axis=-1)
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


def write_image(path, rgba, *, metadata: dict | None = None, depth=None, inputs=(),
                backdrop=None) -> None:
    """Write premultiplied `rgba` (H, W, 4) float to `path` (.exr or .png), atomically.

    `metadata`: JSON-serialisable values by short ASCII key (camera, transfer
    function, dataset, settings). `depth`: optional (H, W) float32 world-unit
    distances, .exr only (channel Z). `inputs`: paths the output must not
    replace (exabricks.util.output). `backdrop`: the opaque RGB a .png is composited
    over (None: the .png keeps the alpha); an .exr is never composited.
    """
    path = Path(path)
    rgba, depth = _checked(rgba, depth, path)
    height, width = rgba.shape[:2]

    def bands():
        rows = _band_rows(width)
        for r in range(0, height, rows):
            yield rgba[r:r + rows], None if depth is None else depth[r:r + rows]

    _write_bands(path, width, height, bands, depth is not None, metadata, inputs, backdrop)


def _band_rows(width: int) -> int:
    """Rows of the bands an image is written in: about 1 MiB of float RGBA, a
    multiple of the 16 scanlines of an EXR ZIP block."""
    return max(EXR_BLOCK, (1 << 20) // (16 * width) // EXR_BLOCK * EXR_BLOCK)


def _check_depth(path: Path, has_depth: bool) -> str:
    """The image format of `path` (_suffix), refusing depth with .png."""
    suffix = _suffix(path)
    if has_depth and suffix == ".png":
        raise ExabricksError(f"{path}: a depth image needs .exr output (PNG has no depth channel)")
    return suffix


def _write_bands(path: Path, width: int, height: int, bands, has_depth: bool, metadata,
                 inputs, backdrop=None) -> None:
    """Write the image that `bands()` yields as (rgba, depth or None) bands of
    _band_rows rows, top to bottom, to `path`, atomically (write_image)."""
    suffix = _check_depth(path, has_depth)
    attributes = _encoded_metadata(metadata, path)

    def write(tmp: str) -> None:
        try:
            with open(tmp, "wb") as f:
                if suffix == ".exr":
                    _write_exr(f, width, height, bands(), has_depth, attributes)
                else:
                    _write_png(f, width, height, bands(), attributes, backdrop)
        except (OSError, RuntimeError) as e:
            raise ExabricksError(f"{path}: cannot write image: "
                                 f"{getattr(e, 'strerror', None) or e}") from None

    write_output(path, write, inputs=inputs)


class FrameFile:
    """A frame put together band by band in a scratch file beside its output
    (exabricks.util.output.scratch), so that a frame far larger than memory (a
    poster drawn tile by tile) is never whole in memory; `write` then writes it
    as .exr or .png with its metadata, bands of rows not yet put being
    `background`. Use as a context manager: the scratch file goes on leaving."""

    def __init__(self, path, width: int, height: int, *, depth: bool = False,
                 background=(0.0, 0.0, 0.0, 0.0), backdrop=None):
        self.path, self.width, self.height = Path(path), int(width), int(height)
        self.backdrop = backdrop  # write_image's
        self.depth = bool(depth)
        _check_depth(self.path, self.depth)
        r, g, b, a = (float(c) for c in background)
        self.background = np.array([r * a, g * a, b * a, a], np.float32)
        self.rows = 0  # rows put, from the top
        self._scratch = None

    def __enter__(self):
        from ..util.output import scratch

        self._scratch = scratch(self.path)
        name = self._scratch.__enter__()
        try:
            self._fd = os.open(name, os.O_RDWR)
        except OSError as e:
            self._scratch.__exit__(None, None, None)
            raise ExabricksError(f"{self.path}: cannot open a scratch file: {e.strerror}") from None
        return self

    def __exit__(self, *exc):
        os.close(self._fd)
        self._scratch.__exit__(*exc)

    def _pixel_bytes(self) -> int:
        return 20 if self.depth else 16

    def put(self, row0: int, rgba: np.ndarray, depth=None) -> None:
        """Rows row0.. of the frame (float32 premultiplied (n, width, 4), and (n,
        width) depth when the frame has it); bands go top to bottom."""
        rgba = np.ascontiguousarray(rgba, np.float32)
        if rgba.ndim != 3 or rgba.shape[1:] != (self.width, 4) or row0 != self.rows \
                or row0 + len(rgba) > self.height:
            raise ExabricksError(f"{self.path}: band of shape {rgba.shape} at row {row0} does "
                                 f"not continue the {self.width}-wide frame at row {self.rows}")
        if not np.isfinite(rgba).all():
            raise ExabricksError(f"{self.path}: image has non-finite values")
        parts = [rgba.reshape(len(rgba), -1)]
        if self.depth:
            parts.append(np.ascontiguousarray(depth, np.float32).reshape(len(rgba), -1))
        data = np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
        offset = row0 * self.width * self._pixel_bytes()
        try:
            view = memoryview(data).cast("B")
            while view:
                done = os.pwrite(self._fd, view, offset)
                view, offset = view[done:], offset + done
        except OSError as e:
            raise ExabricksError(f"{self.path}: cannot write the scratch file: "
                                 f"{e.strerror}") from None
        self.rows += len(rgba)
        _drop_cache(self._fd)

    def _bands(self):
        rows = _band_rows(self.width)
        for r in range(0, self.height, rows):
            n = min(rows, self.height - r)
            done = max(0, min(n, self.rows - r))
            rgba = np.empty((n, self.width, 4), np.float32)
            depth = np.full((n, self.width), np.inf, np.float32) if self.depth else None
            rgba[done:] = self.background
            if done:
                raw = os.pread(self._fd, done * self.width * self._pixel_bytes(),
                               r * self.width * self._pixel_bytes())
                data = np.frombuffer(raw, np.float32).reshape(done, -1)
                rgba[:done] = data[:, :4 * self.width].reshape(done, self.width, 4)
                if self.depth:
                    depth[:done] = data[:, 4 * self.width:]
            _drop_cache(self._fd)
            yield rgba, depth

    def write(self, *, metadata: dict | None = None, inputs=()) -> None:
        """Write the frame so far to the output, atomically."""
        _write_bands(self.path, self.width, self.height, self._bands, self.depth, metadata,
                     inputs, self.backdrop)


def _drop_cache(fd: int) -> None:
    """Hand the scratch file's cached pages back to the system (they are not the
    process's memory, but need not crowd the page cache either)."""
    if hasattr(os, "posix_fadvise"):
        try:
            os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        except OSError:
            pass


# Scanlines of one ZIP_COMPRESSION block of an OpenEXR file.
EXR_BLOCK = 16


def _exr_attribute(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _write_exr(f, width: int, height: int, bands, has_depth: bool, attributes: dict) -> None:
    """A single-part scanline OpenEXR file, float32 channels A, B, G, R (and Z),
    ZIP compression, written block by block from `bands` (the file layout of
    openexr.com, "OpenEXR File Layout"); read back with the OpenEXR library."""
    channels = sorted("RGBA" + ("Z" if has_depth else ""))
    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1)
                      for c in channels) + b"\0"
    box = struct.pack("<4i", 0, 0, width - 1, height - 1)
    header = [
        _exr_attribute("channels", "chlist", chlist),
        _exr_attribute("compression", "compression", bytes([3])),  # ZIP, 16 lines
        _exr_attribute("dataWindow", "box2i", box),
        _exr_attribute("displayWindow", "box2i", box),
        _exr_attribute("lineOrder", "lineOrder", bytes([0])),  # increasing y
        _exr_attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        _exr_attribute("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0)),
        _exr_attribute("screenWindowWidth", "float", struct.pack("<f", 1.0)),
        _exr_attribute("software", "string", f"exabricks {__version__}".encode()),
    ]
    header += [_exr_attribute(name, "string", text.encode()) for name, text in attributes.items()]
    f.write(struct.pack("<ii", 20000630, 2) + b"".join(header) + b"\0")
    n_blocks = -(-height // EXR_BLOCK)
    table = f.tell()
    f.write(bytes(8 * n_blocks))
    offsets = []
    row = 0
    for rgba, depth in bands:
        planes = {c: rgba[..., i] for i, c in enumerate("RGBA")}
        if has_depth:
            planes["Z"] = depth
        for r in range(0, len(rgba), EXR_BLOCK):
            # each scanline holds its channels one after the other, in name order
            block = np.stack([planes[c][r:r + EXR_BLOCK] for c in channels], axis=1)
            raw = np.ascontiguousarray(block, "<f4").view(np.uint8).ravel()
            data = _exr_zip(raw)
            offsets.append(f.tell())
            f.write(struct.pack("<ii", row + r, len(data)) + data)
        row += len(rgba)
    f.seek(table)
    f.write(np.asarray(offsets, "<u8").tobytes())


def _exr_zip(raw: np.ndarray) -> bytes:
    """OpenEXR's ZIP block: bytes split into even and odd halves, then a delta
    predictor, then zlib; the raw bytes where that is not smaller."""
    order = np.concatenate([raw[0::2], raw[1::2]])
    delta = np.empty_like(order)
    delta[0] = order[0]
    np.subtract(order[1:], order[:-1], out=delta[1:])  # uint8: modulo 256
    delta[1:] += 128
    del order
    packed = zlib.compress(delta, 4)  # OpenEXR's default level
    return packed if len(packed) < raw.size else raw.tobytes()


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + \
        struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))


def _write_png(f, width: int, height: int, bands, attributes: dict, backdrop=None) -> None:
    """An 8-bit RGBA PNG (un-premultiplied, to_png_pixels) written band by band:
    the Software text, the metadata as iTXt chunks, then the rows (Sub filter)
    deflated as they come."""
    f.write(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height,
                                                                      8, 6, 0, 0, 0)))
    f.write(_png_chunk(b"tEXt", b"Software\0" + f"exabricks {__version__}".encode("latin-1")))
    for name, text in attributes.items():
        f.write(_png_chunk(b"iTXt", name.encode("latin-1") + b"\0\0\0\0\0" + text.encode()))
    deflate = zlib.compressobj(6)
    for rgba, _ in bands:
        pixels = to_png_pixels(rgba, backdrop).reshape(len(rgba), width * 4)
        rows = np.empty((len(rgba), width * 4 + 1), np.uint8)
        rows[:, 0] = 1  # Sub: each byte minus the same channel of the pixel to its left
        rows[:, 1:5] = pixels[:, :4]
        rows[:, 5:] = pixels[:, 4:] - pixels[:, :-4]
        packed = deflate.compress(rows.tobytes())
        if packed:
            f.write(_png_chunk(b"IDAT", packed))
    f.write(_png_chunk(b"IDAT", deflate.flush()) + _png_chunk(b"IEND", b""))


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

    # our own frames go up to 32768^2 (render --size), beyond Pillow's guard
    # against decompression bombs in untrusted files
    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, 32768 * 32768
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
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    return from_png_pixels(pixels), _decoded_metadata(text)
