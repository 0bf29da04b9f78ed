"""`exabricks movie`: frames (PNG, EXR) into .mp4 / .gif, natural frame order, refusals."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from exabricks.film.image_io import to_png_pixels, write_image
from exabricks.stages.movie import natural_sorted, video_frame

from helpers import assert_one_error_line, run_cli

W, H = 34, 20


def colour(i: int) -> tuple[int, int, int]:
    """A distinct, well-separated colour per frame index (survives H.264 at CRF 18)."""
    return (20 * i % 256, 240 - 20 * i % 256, 128)


def write_frames(directory: Path, n: int = 10, size=(W, H), name="frame_{}.png") -> list[Path]:
    from PIL import Image

    directory.mkdir(exist_ok=True)
    paths = []
    for i in range(n):
        pixels = np.empty((size[1], size[0], 3), np.uint8)
        pixels[...] = colour(i)
        path = directory / name.format(i)
        Image.fromarray(pixels).save(path)
        paths.append(path)
    return paths


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def read_mp4(path) -> np.ndarray:
    import imageio.v2 as imageio

    return np.stack(imageio.mimread(str(path), format="FFMPEG"))


def read_gif(path) -> np.ndarray:
    import imageio.v3 as iio

    return iio.imread(path, index=None, mode="RGB")


def test_natural_order():
    names = ["f10.png", "f2.png", "F1.png", "f1.png", "a/f3.png", "f02.png", "x"]
    assert natural_sorted(names) == ["a/f3.png", "F1.png", "f1.png", "f02.png", "f2.png",
                                     "f10.png", "x"]


def test_video_frame_composites_rounds_and_pads():
    rgba = np.zeros((3, 5, 4), np.float32)
    rgba[0, 0] = (0.25, 0.5, 0.0, 0.5)  # premultiplied: colour (0.5, 1, 0) at half alpha
    rgba[1, 1] = (0.2, 0.4, 0.6, 1.0)
    out = video_frame(rgba, (0.0, 0.0, 1.0), even=True)
    assert out.shape == (4, 6, 3) and out.dtype == np.uint8
    assert tuple(out[0, 0]) == (64, 128, 128)          # 0.25, 0.5, 0 + 0.5 * blue
    assert tuple(out[1, 1]) == tuple(to_png_pixels(rgba[1:2, 1:2])[0, 0, :3])
    assert np.all(out[3, :] == (0, 0, 255)) and np.all(out[:, 5] == (0, 0, 255))  # padding
    assert video_frame(rgba).shape == (3, 5, 3)


def test_mp4_round_trip(tmp_path):
    write_frames(tmp_path / "frames")
    out = tmp_path / "movie.mp4"
    run_cli("movie", tmp_path / "frames" / "*.png", "-o", out, "--fps", "30", check=0)
    frames = read_mp4(out)
    assert frames.shape == (10, H, W, 3)
    for i, frame in enumerate(frames):
        assert np.abs(frame[4:-4, 4:-4].astype(int) - colour(i)).max() <= 8, i
    assert not leftovers(tmp_path)


def test_odd_sizes_are_padded_with_the_background(tmp_path):
    from PIL import Image

    (tmp_path / "f").mkdir()
    for i in range(2):
        Image.fromarray(np.zeros((21, 35, 3), np.uint8)).save(tmp_path / "f" / f"{i}.png")
    out = tmp_path / "m.mp4"
    run_cli("movie", tmp_path / "f" / "*.png", "-o", out, "--background", "1,1,1", check=0)
    frames = read_mp4(out)
    assert frames.shape == (2, 22, 36, 3)
    assert frames[:, :20, :34].max() < 40              # the black frames, not rescaled
    assert frames[:, :20, 35].min() > 215 and frames[:, 21, :34].min() > 215  # white padding


def test_numeric_order_gif_and_exr_over_background(tmp_path):
    # 12 frames: in byte order frame_10 and frame_11 would come before frame_2.
    paths = write_frames(tmp_path / "f", n=12)
    out = tmp_path / "m.gif"
    run_cli("movie", *sorted(paths), "-o", out, "--fps", "10", check=0)  # shell's order
    frames = read_gif(out)
    assert frames.shape == (12, H, W, 3)
    assert [tuple(f[5, 5]) for f in frames] == [colour(i) for i in range(12)]

    rgba = np.zeros((H, W, 4), np.float32)
    rgba[...] = (0.5, 0.0, 0.0, 0.5)  # premultiplied half-transparent pure red
    exr = [tmp_path / f"e{i}.exr" for i in range(2)]
    for p in exr:
        write_image(p, rgba)
    run_cli("movie", tmp_path / "e*.exr", "-o", out, "--background", "0,0,1", check=0)
    assert np.all(read_gif(out) == (128, 0, 128))


def test_no_matching_frames(tmp_path):
    pattern = str(tmp_path / "frames" / "*.png")
    proc = run_cli("movie", pattern, "-o", tmp_path / "m.mp4")
    assert_one_error_line(proc)
    assert proc.stderr.strip() == f"error: {pattern}: no frames match"
    assert_one_error_line(run_cli("movie", tmp_path / "f.png", "-o", tmp_path / "m.mp4"),
                          "f.png", "no such file")
    assert list(tmp_path.iterdir()) == []


def test_a_frame_of_another_size_is_named(tmp_path):
    write_frames(tmp_path / "f", n=4)
    write_frames(tmp_path / "f", n=1, size=(36, 20), name="frame_2.png")
    write_frames(tmp_path / "f", n=1, size=(34, 22), name="frame_3.png")
    for suffix in (".mp4", ".gif"):
        out = tmp_path / f"m{suffix}"
        proc = run_cli("movie", tmp_path / "f" / "*.png", "-o", out)
        assert_one_error_line(proc, "frame_2.png", "36x20", "frame_0.png", "34x20")
        assert not out.exists() and not leftovers(tmp_path)


def test_a_corrupt_frame_leaves_nothing_behind(tmp_path):
    paths = write_frames(tmp_path, n=6)
    paths[4].write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    out = tmp_path / "m.mp4"
    out.write_bytes(b"an older movie")
    assert_one_error_line(run_cli("movie", tmp_path / "*.png", "-o", out), "frame_4.png")
    assert out.read_bytes() == b"an older movie" and not leftovers(tmp_path)


def test_outputs_that_are_refused(tmp_path):
    paths = write_frames(tmp_path / "f", n=2)
    before = paths[0].read_bytes()
    link = tmp_path / "alias.mp4"
    link.symlink_to(paths[0])
    assert_one_error_line(run_cli("movie", *paths, "-o", link), "would overwrite the input")
    assert paths[0].read_bytes() == before

    assert_one_error_line(run_cli("movie", *paths, "-o", tmp_path / "m.avi"),
                          "m.avi", "unknown movie format")
    directory = tmp_path / "d.mp4"
    directory.mkdir()
    proc = run_cli("movie", *paths, "-o", directory)
    assert proc.returncode == 2 and "is a directory" in proc.stderr  # click's usage error
    proc = run_cli("movie", *paths, "-o", tmp_path / "m.gif", "--crf", "20")
    assert proc.returncode == 2 and "--crf" in proc.stderr
    assert_one_error_line(run_cli("movie", tmp_path / "f", "-o", tmp_path / "m.mp4"),
                          "is a directory")
    assert not leftovers(tmp_path) and not (tmp_path / "m.mp4").exists()


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
@pytest.mark.parametrize("fps", ["0", "-1", "nan", "inf", "0.001", "1e-9", "1001"])
def test_fps_must_lie_in_the_range_both_encoders_take(fps, suffix, tmp_path):
    """--fps 0.001 was "internal error: OverflowError" in a GIF (its delay is a 16-bit
    count of hundredths of a second) and 1e-9 ffmpeg's internals: refused when the
    options are parsed, the one error line saying the range."""
    paths = write_frames(tmp_path, n=1)
    proc = run_cli("movie", *paths, "-o", tmp_path / f"m{suffix}", "--fps", fps)
    assert proc.returncode == 2, proc.stderr
    (error,) = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert "--fps" in error and "[0.01, 1000]" in error and "Traceback" not in proc.stderr
    assert not (tmp_path / f"m{suffix}").exists()


def test_series_fps_is_refused_before_drawing(tmp_path):
    from helpers import GERRIS

    proc = run_cli("series", GERRIS, "-o", tmp_path / "frames", "--fps", "0.001", "--movie",
                   tmp_path / "s.gif")
    assert proc.returncode == 2 and "[0.01, 1000]" in proc.stderr
    assert not (tmp_path / "frames").exists()
    import exabricks as eb
    with pytest.raises(eb.ExabricksError, match=r"--fps: .*\[0.01, 1000\]"):
        eb.render_series([GERRIS], tmp_path / "frames", movie=tmp_path / "s.gif", fps=0.001)
    assert not (tmp_path / "frames").exists()


def test_a_gif_refuses_a_still_longer_than_it_can_show(tmp_path):
    """Pillow adds up the delays of identical frames in a row: 7 of 100 s each are
    more than the 655.35 s a GIF shows one frame (OverflowError, before)."""
    paths = write_frames(tmp_path / "f", n=1) * 7
    out = tmp_path / "m.gif"
    assert_one_error_line(run_cli("movie", *paths, "-o", out, "--fps", "0.01"), str(out),
                          "7 identical frames", "655.35 s")
    assert not out.exists() and not leftovers(tmp_path)
    run_cli("movie", *paths[:6], "-o", out, "--fps", "0.01", check=0)
    assert len(read_gif(out)) == 1  # shown once, for 600 s


def test_h265(tmp_path):
    paths = write_frames(tmp_path, n=3)
    out = tmp_path / "m.mp4"
    run_cli("movie", *paths, "-o", out, "--codec", "h265", "--crf", "20", check=0)
    frames = read_mp4(out)
    assert frames.shape == (3, H, W, 3)
    assert np.abs(frames[1, 4:-4, 4:-4].astype(int) - colour(1)).max() <= 10
    assert os.path.getsize(out) > 0
