"""`compare_images` metrics against closed forms and a brute-force SSIM; the CLI's exit statuses."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers import run_cli

from exabricks.util.errors import ExabricksError
from exabricks.film.image_io import read_image, write_image
from exabricks.stages.compare import compare_images, diff_image, ssim


def _ssim_brute_force(a, b):
    """Wang et al. 2004 SSIM, one 11x11 window at a time in float64 (no separable filters)."""
    y, x = np.mgrid[-5:6, -5:6].astype(np.float64)
    w = np.exp(-(x * x + y * y) / (2 * 1.5 ** 2))
    w /= w.sum()
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    per_channel = []
    for c in range(a.shape[2]):
        values = []
        for i in range(a.shape[0] - 10):
            for j in range(a.shape[1] - 10):
                pa = a[i:i + 11, j:j + 11, c].astype(np.float64)
                pb = b[i:i + 11, j:j + 11, c].astype(np.float64)
                ma, mb = (w * pa).sum(), (w * pb).sum()
                va, vb = (w * (pa - ma) ** 2).sum(), (w * (pb - mb) ** 2).sum()
                cov = (w * (pa - ma) * (pb - mb)).sum()
                values.append((2 * ma * mb + c1) * (2 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2)))
        per_channel.append(np.mean(values))
    return float(np.mean(per_channel))


def test_identical_images():
    a = np.random.default_rng(1).random((20, 24, 4)).astype(np.float32)
    m = compare_images(a, a.copy())
    assert m == {"rmse": 0.0, "psnr": math.inf, "max_abs": 0.0, "ssim": pytest.approx(1.0, abs=1e-12)}


def test_known_offset_gives_known_rmse_psnr_and_max_abs():
    a = np.random.default_rng(2).uniform(0.2, 0.8, (16, 16, 4))
    b = a.copy()
    b[..., 0] += 0.1  # one channel of four shifted by 0.1: mse = 0.01 / 4
    m = compare_images(a, b)
    assert m["rmse"] == pytest.approx(0.05, rel=1e-12)
    assert m["psnr"] == pytest.approx(10 * math.log10(4 / 0.01), rel=1e-12)
    assert m["max_abs"] == pytest.approx(0.1, rel=1e-12)
    b = a - 0.25
    m = compare_images(a, b)
    assert m["rmse"] == pytest.approx(0.25) and m["psnr"] == pytest.approx(-20 * math.log10(0.25))


@pytest.mark.parametrize("shape", [(11, 11, 1), (14, 19, 4), (23, 12, 2)])
def test_ssim_matches_brute_force(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.random(shape)
    b = np.clip(0.7 * a + 0.3 * rng.random(shape) + 0.05, 0, 1)  # correlated, biased, noisier
    assert ssim(a, b) == pytest.approx(_ssim_brute_force(a, b), abs=1e-12)
    smooth = np.cumsum(rng.random(shape), axis=1) / shape[1]
    assert ssim(smooth, smooth[::-1]) == pytest.approx(_ssim_brute_force(smooth, smooth[::-1]), abs=1e-12)


def test_ssim_of_constant_images_and_small_images():
    a = np.full((12, 12, 4), 0.5)
    assert ssim(a, a) == pytest.approx(1.0)
    # constant images: only the luminance term remains, (2 m1 m2 + c1) / (m1^2 + m2^2 + c1)
    c1 = 0.01 ** 2
    assert ssim(a, a * 0.5) == pytest.approx((2 * 0.5 * 0.25 + c1) / (0.25 + 0.0625 + c1))
    assert compare_images(a[:10], a[:10])["ssim"] is None


def test_shape_mismatch_names_both_shapes():
    with pytest.raises(ExabricksError, match=r"a\.exr is 5x4 \(4 channels\), b\.exr is 4x5 \(4 channels\)"):
        compare_images(np.zeros((4, 5, 4)), np.zeros((5, 4, 4)), names=("a.exr", "b.exr"))


def test_diff_image_scales_the_largest_difference_to_white():
    a = np.zeros((3, 4, 4), dtype=np.float32)
    b = a.copy()
    b[1, 2, 3] = 0.2
    b[0, 0, 0] = -0.05
    d = diff_image(a, b)
    assert d.shape == (3, 4, 4) and d.dtype == np.float32
    np.testing.assert_allclose(d[..., 3], 1.0)
    np.testing.assert_allclose(d[1, 2, :3], 1.0)
    np.testing.assert_allclose(d[0, 0, :3], 0.25)
    assert d[..., :3].sum() == pytest.approx(3 * 1.25)
    np.testing.assert_array_equal(diff_image(a, a)[..., :3], 0.0)
    np.testing.assert_allclose(diff_image(a, b, scale=2.0)[0, 0, 0], 0.1)


# ---------------------------------------------------------------------------------------
# CLI


@pytest.fixture
def images(tmp_path):
    rng = np.random.default_rng(3)
    a = rng.random((24, 32, 4)).astype(np.float32)
    a[..., :3] *= a[..., 3:]
    b = a.copy()
    b[..., 1] = np.clip(b[..., 1] + 0.02, 0, None)
    b[..., :3] = np.minimum(b[..., :3], b[..., 3:])
    paths = {"a": tmp_path / "a.exr", "b": tmp_path / "b.exr", "small": tmp_path / "small.exr"}
    write_image(paths["a"], a, metadata={})
    write_image(paths["b"], b, metadata={})
    write_image(paths["small"], a[:8, :8], metadata={})
    return paths, compare_images(a, b)


def test_cli_passes_within_thresholds_and_reports_metrics(images):
    paths, m = images
    proc = run_cli("compare", paths["a"], paths["b"], "--max-rmse", m["rmse"] * 1.01,
                   "--min-psnr", m["psnr"] - 0.1, "--max-abs", 0.03, "--min-ssim", 0.5, check=0)
    assert f"rmse     {m['rmse']:.6g}" in proc.stdout and "FAIL" not in proc.stdout
    proc = run_cli("compare", paths["a"], paths["a"], "--json", check=0)
    out = json.loads(proc.stdout)
    assert set(out) == {"a", "b", "width", "height", "rmse", "psnr", "max_abs", "ssim",
                        "thresholds", "failed", "passed"}
    assert out["psnr"] == "inf" and out["rmse"] == 0 and out["passed"] is True
    assert (out["width"], out["height"]) == (32, 24)


def test_cli_names_each_exceeded_threshold_and_exits_1(images, tmp_path):
    paths, m = images
    proc = run_cli("compare", paths["a"], paths["b"], "--max-rmse", m["rmse"] * 0.99, "--max-abs", 1.0,
                   "--min-psnr", m["psnr"] + 1, "--min-ssim", 1.0, check=1)
    fails = [line for line in proc.stdout.splitlines() if line.startswith("FAIL")]
    assert [line.split()[1] for line in fails] == ["rmse", "psnr", "ssim"]
    assert "--max-rmse" in fails[0] and proc.stderr == ""
    proc = run_cli("compare", paths["a"], paths["b"], "--max-rmse", 0, "--json",
                   "--diff", tmp_path / "diff.png", check=1)
    out = json.loads(proc.stdout)
    assert out["failed"] == ["rmse"] and out["passed"] is False and out["thresholds"] == {"max_rmse": 0.0}
    assert out["rmse"] == pytest.approx(m["rmse"], rel=1e-12)
    diff, meta = read_image(tmp_path / "diff.png")
    assert diff.shape == (24, 32, 4) and diff[..., 3].min() == 1.0 and diff[..., :3].max() == 1.0
    assert meta["compare"]["rmse"] == pytest.approx(m["rmse"])


@pytest.mark.parametrize("case", ["missing", "size", "corrupt", "ssim-too-small", "bad-diff"])
def test_cli_trouble_exits_2_with_one_error_line(images, tmp_path, case):
    paths, _ = images
    corrupt = tmp_path / "corrupt.png"
    corrupt.write_bytes(b"not a png")
    args, needles = {
        "missing": ([paths["a"], tmp_path / "nope.exr"], ["nope.exr", "no such image file"]),
        "size": ([paths["a"], paths["small"]], ["differ in size", "a.exr is 32x24", "small.exr is 8x8"]),
        "corrupt": ([corrupt, paths["a"]], ["corrupt.png", "cannot read PNG"]),
        "ssim-too-small": ([paths["small"], paths["small"], "--min-ssim", 0.9], ["SSIM needs", "11x11"]),
        "bad-diff": ([paths["a"], paths["b"], "--diff", tmp_path / "diff.tiff"], ["diff.tiff", "unknown image format"]),
    }[case]
    proc = run_cli("compare", *args, check=2)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in proc.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert proc.stdout == ""
    assert not (tmp_path / "diff.tiff").exists()
