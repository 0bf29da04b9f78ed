"""Frames into a movie: frame order, video pixels, and the .mp4 / .gif encoders.

A frame is an image as exabricks.film.image_io holds it: ``rgba`` (H, W, 4) float32,
premultiplied, row 0 at the top. A movie has no alpha, so each frame is
composited over an opaque background colour and then rounded to 8 bits exactly as
the PNG writer rounds (`image_io.to_png_pixels`): a movie of PNG frames shows the
PNGs' own 8-bit colours.

- ``.mp4``: H.264 (libx264) or H.265 (libx265) in yuv420p, the pixel format every
  player decodes, at a constant rate factor (CRF). yuv420p needs an even width
  and height: an odd one is padded by one column (right) or row (bottom) of the
  background colour, never rescaled.
- ``.gif``: Pillow, an adaptive 256-colour palette per frame, looping forever;
  GIF delays are whole hundredths of a second.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ..util.errors import ExabricksError
from ..film.image_io import to_png_pixels

FORMATS = (".mp4", ".gif")
CODECS = {"h264": "libx264", "h265": "libx265"}
DEFAULT_CRF = 18
# Frames per second a movie may have. A GIF's delay is a 16-bit count of hundredths
# of a second (655.35 s at most: Pillow overflowed at 0.001) and ffmpeg refuses
# rates below about 1e-5; one range for both, checked before any frame is drawn.
MIN_FPS, MAX_FPS = 0.01, 1000.0
# The longest a GIF shows one frame, in hundredths of a second (Pillow adds up the
# delays of identical frames in a row into one).
GIF_MAX_DELAY = 0xFFFF


def movie_format(path) -> str:
    """The container of an output `path` from its suffix (".mp4" or ".gif"), else an error."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ExabricksError(f"{path}: unknown movie format {Path(path).suffix or '(no extension)'!r} "
                             "(use .mp4 or .gif)")
    return suffix


def fps_problem(fps) -> str | None:
    """What is wrong with a movie's frames per second, or None (`MIN_FPS`, `MAX_FPS`)."""
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not math.isfinite(fps) \
            or not MIN_FPS <= fps <= MAX_FPS:
        return f"frames per second must lie in [{MIN_FPS:g}, {MAX_FPS:g}], got {fps!r}"
    return None


def check_fps(fps) -> None:
    """ExabricksError `--fps: ...` unless `fps_problem` finds none."""
    problem = fps_problem(fps)
    if problem is not None:
        raise ExabricksError(f"--fps: {problem}")


def natural_key(name: str):
    """Sort key that orders the digit runs of `name` by value: frame_2 before frame_10."""
    parts = re.split(r"([0-9]+)", str(name))
    # Digit runs sit at the odd positions, so like positions always compare like types.
    return [int(p) if i % 2 else p.casefold() for i, p in enumerate(parts)], str(name)


def natural_sorted(names: Iterable) -> list:
    return sorted(names, key=natural_key)


def video_frame(rgba, background=(0.0, 0.0, 0.0), *, even: bool = False) -> np.ndarray:
    """Premultiplied float ``rgba`` (H, W, 4) over the opaque RGB `background` (each in
    [0, 1]) -> (H', W', 3) uint8, rounded as the PNG writer rounds.

    `even`: pad an odd width (height) with one column (row) of the background on the
    right (bottom), as yuv420p needs; H' = H and W' = W otherwise.
    """
    rgba = np.asarray(rgba, dtype=np.float32)
    h, w = rgba.shape[:2]
    height, width = (h + h % 2, w + w % 2) if even else (h, w)
    opaque = np.empty((height, width, 4), np.float32)
    opaque[..., :3] = np.asarray(background, np.float32)
    opaque[..., 3] = 1.0
    behind = 1.0 - np.clip(rgba[..., 3:4], 0.0, 1.0)
    opaque[:h, :w, :3] = rgba[..., :3] + behind * opaque[:h, :w, :3]
    return to_png_pixels(opaque)[..., :3]


def write_mp4(path, frames: Iterator[np.ndarray], *, fps: float, crf: int = DEFAULT_CRF,
              codec: str = "h264", name=None) -> int:
    """Encode uint8 RGB `frames` (H, W, 3), all of the first one's size (even), into an
    MP4 file `path` (any name: the container is given to ffmpeg, not guessed from it).
    Returns the number of frames written; errors name `name` (default `path`).

    ffmpeg is the binary that the imageio-ffmpeg wheel ships. It is driven here rather
    than through imageio's writer, which picks the format from the file name (ours is
    a temporary one), lets ffmpeg's messages through to stderr and does not check
    ffmpeg's exit status: a movie that failed at the last step would look written.
    """
    process = log = size = None
    count = 0

    def failure(what: str) -> ExabricksError:
        log.seek(0)
        lines = [line.strip() for line in log.read().decode(errors="replace").splitlines()
                 if line.strip()]
        return ExabricksError(f"{name or path}: ffmpeg {what}: "
                              f"{lines[-1] if lines else 'no message'}")

    try:
        for frame in frames:
            frame = np.ascontiguousarray(frame, dtype=np.uint8)
            if process is None:
                size = frame.shape
                process, log = _start_ffmpeg(path, size, fps=fps, crf=crf, codec=codec, name=name)
            if frame.shape != size:
                raise ExabricksError(f"{name or path}: frame {count} is {frame.shape}, not {size}")
            try:
                process.stdin.write(frame.data)
            except BrokenPipeError:
                process.wait()
                raise failure(f"stopped at frame {count} (exit status {process.returncode})") from None
            count += 1
        if process is None:
            raise ExabricksError(f"{name or path}: no frames to encode")
        try:
            process.stdin.close()
        except BrokenPipeError:
            pass  # ffmpeg has gone: its exit status tells why
        if process.wait() != 0:
            raise failure(f"failed (exit status {process.returncode})")
        return count
    finally:
        if process is not None and process.poll() is None:  # an error or a signal: stop it
            process.kill()
            process.wait()
        if log is not None:
            log.close()


def _start_ffmpeg(path, shape, *, fps: float, crf: int, codec: str, name=None):
    """ffmpeg reading raw RGB frames of `shape` (H, W, 3) on stdin, writing MP4 `path`;
    its messages go to an anonymous file (a pipe could fill up and stall it)."""
    import imageio_ffmpeg

    try:
        exe = imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as e:
        raise ExabricksError(f"{name or path}: no ffmpeg binary: {e}") from None
    height, width = shape[:2]
    if height % 2 or width % 2:
        raise ExabricksError(f"{name or path}: yuv420p needs an even width and height, "
                             f"got {width}x{height}")
    command = [
        exe, "-hide_banner", "-loglevel", "error", "-y",
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}", "-framerate", repr(float(fps)),
        "-i", "pipe:0", "-an",
        "-c:v", CODECS[codec], "-pix_fmt", "yuv420p", "-crf", str(int(crf)),
        *(["-tag:v", "hvc1"] if codec == "h265" else []),  # what QuickTime needs for H.265 in MP4
        "-movflags", "+faststart", "-f", "mp4",
        "file:" + os.fspath(path),  # never read as another protocol ("name:...")
    ]
    log = tempfile.TemporaryFile()
    try:
        process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                   stderr=log)
    except OSError as e:
        log.close()
        raise ExabricksError(f"{name or path}: cannot run ffmpeg ({exe}): {e.strerror or e}") from None
    return process, log


def write_gif(path, frames: Iterator[np.ndarray], *, fps: float, name=None) -> int:
    """Encode uint8 RGB `frames` into a looping GIF file `path`; returns the frame count.

    Each frame is reduced to its own 256-colour palette as it arrives (one byte per
    pixel kept in memory); the delay is 1/fps rounded to hundredths of a second.
    Identical frames in a row show as one for their delays together, at most
    GIF_MAX_DELAY: a longer run is refused naming `name` (default `path`)."""
    from PIL import Image

    check_fps(fps)
    delay = max(1, round(100.0 / fps))  # hundredths of a second
    images, previous, run = [], None, 0
    for frame in frames:
        run = run + 1 if previous is not None and np.array_equal(frame, previous) else 1
        if run * delay > GIF_MAX_DELAY:
            raise ExabricksError(
                f"{name or path}: {run} identical frames in a row at --fps {fps:g} would show "
                f"for {run * delay / 100:g} s, longer than a GIF shows one frame "
                f"({GIF_MAX_DELAY / 100:g} s); use a higher --fps or .mp4")
        previous = frame
        images.append(Image.fromarray(frame).quantize(256))
    if not images:
        return 0
    try:
        images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                       duration=10 * delay, loop=0, disposal=1)
    except OverflowError:  # frames that differ but share their 256 colours, merged by Pillow
        raise ExabricksError(f"{name or path}: frames alike in a row at --fps {fps:g} would show "
                             f"longer than a GIF shows one frame ({GIF_MAX_DELAY / 100:g} s); "
                             "use a higher --fps or .mp4") from None
    return len(images)


def make_movie(paths, output, *, fps: float, crf: int | None = None, codec: str | None = None,
               background=(0.0, 0.0, 0.0)) -> None:
    """`exabricks movie`: the images `paths` (.png or .exr, all of one size, in this
    order) into the movie `output` (.mp4 or .gif by its suffix), transparent pixels
    over `background`, atomically, with a progress bar on a terminal."""
    from ..util import progress
    from ..film.image_io import read_image
    from ..util.output import check_output, write_output

    kind = movie_format(output)
    check_fps(fps)
    check_output(output, paths)

    def frames_of(bar):
        first = None
        for path in paths:
            rgba, _ = read_image(path)
            if first is None:
                first = (path, rgba.shape)
            elif rgba.shape != first[1]:
                raise ExabricksError(
                    f"{path}: {rgba.shape[1]}x{rgba.shape[0]} pixels, but {first[0]} is "
                    f"{first[1][1]}x{first[1][0]} (all frames must have one size)")
            bad = int(np.count_nonzero(~np.isfinite(rgba)))
            if bad:
                raise ExabricksError(f"{path}: {bad} non-finite values")
            yield video_frame(rgba, background, even=kind == ".mp4")
            bar.update()

    def write(tmp):
        with progress.bar(total=len(paths), desc="movie", unit="frame") as bar:
            if kind == ".mp4":
                write_mp4(tmp, frames_of(bar), fps=fps, crf=DEFAULT_CRF if crf is None else crf,
                          codec=codec or "h264", name=output)
                return
            try:
                write_gif(tmp, frames_of(bar), fps=fps, name=output)
            except (OSError, ValueError) as e:  # Pillow's
                raise ExabricksError(f"{output}: cannot write the GIF: "
                                     f"{getattr(e, 'strerror', None) or e}") from None

    write_output(output, write, inputs=paths)
