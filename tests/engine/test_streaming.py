"""Rendering under a memory budget, progressively and against a time limit
(exabricks.engine.streaming, issue 11).

A budgeted frame is drawn domain by domain, each domain's rays continuing from the
image composited in front of it, so it takes the in-memory frame's samples and
equals it up to float rounding (the issue's bound: RMSE at most 1e-5 of the
maximum), early ray termination included."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from exabricks.util.errors import ExabricksError
from exabricks.film.image_io import read_image
from exabricks.util.sizes import parse_size
from exabricks.engine.renderer import Renderer
from exabricks.engine.budget_bytes import HELD, SLACK, fixed_bytes, image_bytes
from exabricks.engine.streaming import Budgeted, Resident, render_steps

from helpers import GERRIS, assert_one_error_line, peak_rss
from helpers.mpi import files_of
from helpers.frames import DATASETS, loaded, renderer, scene_for
from helpers.streaming import budget_for, same, tiled

EB = [sys.executable, "-m", "exabricks.cli.main"]


def _after_rewrites(args, count: int, check) -> tuple[int, str]:
    """Run `exabricks -v ARGS`, call `check()` after each of its first `count`
    progressive rewrites (the event: the "so far" line it logs once a rewrite is in
    place), then send SIGTERM: (exit status, the rest of stderr)."""
    proc = subprocess.Popen([*EB, "-v", *map(str, args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    seen = 0
    try:
        for line in proc.stderr:
            if ": so far " in line:
                check()
                seen += 1
                if seen == count:
                    break
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    assert seen == count, f"{seen} rewrites before the end: {err}"
    return proc.returncode, err


def test_sizes_parse_like_slurm_and_numfmt():
    assert parse_size("1048576") == 1 << 20
    assert parse_size("512MiB") == parse_size("512M") == parse_size("512m") == 512 << 20
    assert parse_size("2G") == parse_size("2GiB") == 2 << 30
    assert parse_size("1.5GB") == 1_500_000_000
    assert parse_size("3kB") == 3000 and parse_size("3K") == 3072
    for bad in ("", "0", "-5M", "nanG", "12Q", "G", "inf", "1e400"):
        with pytest.raises(ExabricksError, match="memory budget"):
            parse_size(bad)


CASES = [("gerris", "emission", 2), ("gerris", "emission", 8),
         pytest.param("gerris", "emission", 32, marks=pytest.mark.slow),
         ("amrex", "central", 8), pytest.param("athena", "spp", 8, marks=pytest.mark.slow),
         pytest.param("enzo", "clip-slice", 8, marks=pytest.mark.slow), ("enzo", "clip-slice", 3),
         ("amrex", "two-layers", 3),
         pytest.param("gerris", "nearest", 4, marks=pytest.mark.slow), ("enzo", "emission", 4)]


@pytest.mark.parametrize("name,mode,n", CASES)
# Without early termination every case again (make test-all; the fast suite keeps the default).
@pytest.mark.parametrize("max_opacity", [pytest.param(1.0, marks=pytest.mark.slow), 0.98])
def test_budgeted_frame_equals_the_in_memory_frame(name, mode, n, max_opacity):
    built = loaded(name)[0]
    scene = scene_for(name, mode)
    scene = scene.replace(settings=dataclasses.replace(scene.settings, max_opacity=max_opacity))
    whole = Renderer(built.bricks, built.regions, built.bvh, fields=DATASETS[name][1])
    reference = whole.render_scene(scene)
    domains = Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, n))
    assert domains.n_domains >= n
    result = render_steps(domains, scene)
    same(result.rgba, reference.rgba)
    # The same samples, but where a ray's opacity comes within float rounding of 1
    # at a domain's boundary: the front image stores 1 - T, which rounds to 1 and
    # stops the next domain, where the whole frame's T stays above 0 (and at
    # max_opacity < 1 rounding can move a stop the same way). Those samples
    # weigh under 1e-7 each.
    assert abs(result.stats["samples"] - reference.stats["samples"]) \
        <= 1e-3 * reference.stats["samples"]
    assert result.stats["pieces"] == domains.n_domains
    assert result.stats["progress"] == {"complete": True, "samples": [scene.settings.spp] * 2,
                                        "pieces": [domains.n_domains] * 2}


@pytest.mark.slow  # one of the budget's cases; make test keeps the others
def test_early_termination_carries_across_domains():
    """An opaque front domain stops the rays: the domains behind take no samples."""
    name = "gerris"
    built = loaded(name)[0]
    scene = scene_for(name, "emission")
    opaque = scene.replace(settings=dataclasses.replace(scene.settings, max_opacity=0.5))
    domains = Budgeted(built.bricks, built.regions, opaque, budget_for(name, opaque, 8))
    full = render_steps(domains, opaque.replace(
        settings=dataclasses.replace(opaque.settings, max_opacity=1.0)))
    stopped = render_steps(domains, opaque)
    assert stopped.stats["samples"] < full.stats["samples"]
    whole = Renderer(built.bricks, built.regions, built.bvh, fields=DATASETS[name][1])
    same(stopped.rgba, whole.render_scene(opaque).rgba)


def test_surfaces_and_depth_need_one_domain():
    name = "amrex"
    built = loaded(name)[0]
    scene = scene_for(name, "iso")
    with pytest.raises(ExabricksError, match="iso-surfaces need the whole dataset"):
        Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, 4))
    one = Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, 1) * 2)
    assert one.n_domains == 1
    whole = Renderer(built.bricks, built.regions, built.bvh, fields=DATASETS[name][1])
    same(render_steps(one, scene).rgba, whole.render_scene(scene).rgba)


def test_a_budget_too_small_says_what_it_needs():
    name = "gerris"
    built = loaded(name)[0]
    scene = scene_for(name, "emission")
    with pytest.raises(ExabricksError, match="leaves nothing for the data"):
        Budgeted(built.bricks, built.regions, scene, image_bytes(scene))
    with pytest.raises(ExabricksError, match="too small for this dataset: the smallest domain"):
        Budgeted(built.bricks, built.regions, scene,
                 fixed_bytes(scene, built.bricks.n_bricks) + 200)


def test_steps_offer_every_image_so_far_and_stop_at_the_deadline():
    name = "athena"
    built = loaded(name)[0]
    scene = scene_for(name, "spp")
    spp = scene.settings.spp
    domains = Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, 3))
    seen = []
    result = render_steps(domains, scene, on_image=lambda rgba, p: seen.append((rgba.copy(), p)))
    assert len(seen) == spp * domains.n_domains - 1
    assert seen[0][1] == {"complete": False, "samples": [0, spp], "pieces": [1, domains.n_domains]}
    assert seen[-1][1]["samples"] == [spp - 1, spp]
    assert all(np.isfinite(r).all() for r, _ in seen)
    one = render_steps(Resident(Renderer(built.bricks, built.regions, built.bvh,
                                         fields=DATASETS[name][1])), scene)
    same(result.rgba, one.rgba)
    late = render_steps(domains, scene, deadline=time.perf_counter())
    assert late.stats["progress"]["complete"] is False
    assert late.stats["progress"]["samples"][0] < spp


@pytest.fixture(scope="module")
def gerris_files(tmp_path_factory):
    return files_of(tmp_path_factory, GERRIS, "T")


FLAGS = ["--size", 64, 64, "--max-opacity", 1, "--shading", "none"]


@pytest.mark.slow
def test_cli_budget_from_the_environment_gives_the_same_image(gerris_files, cli, tmp_path):
    cli("render", *gerris_files, "-o", tmp_path / "a.exr", *FLAGS, check=0)
    proc = cli("render", *gerris_files, "-o", tmp_path / "b.exr", *FLAGS,
               env={"EXABRICKS_MEMORY_BUDGET": "1M"}, check=0)
    assert proc.stderr == ""
    a, _ = read_image(tmp_path / "a.exr")
    b, meta = read_image(tmp_path / "b.exr")
    same(b, a)
    assert meta["settings"]["memory_budget"] == 1 << 20
    assert meta["settings"]["pieces"] > 1
    assert meta["settings"]["progress"]["complete"] is True
    bad = cli("render", *gerris_files, "-o", tmp_path / "c.exr", "--memory-budget", "12 parsecs")
    assert bad.returncode == 2 and "memory budget" in bad.stderr
    assert not (tmp_path / "c.exr").exists()
    proc = cli("render", *gerris_files, "-o", tmp_path / "d.exr", *FLAGS, "--memory-budget", "280k")
    assert_one_error_line(proc, "a memory budget of 280.0 KiB leaves nothing for the data")
    from exabricks import schema

    other = tmp_path / "renamed.npz"  # bricks of another field name: not these regions'
    bricks = schema.load(gerris_files[0])
    schema.save(other, bricks.replace(fields=("X",)))
    proc = cli("render", other, *gerris_files[1:], "-o", tmp_path / "d.exr", *FLAGS,
               "--memory-budget", "1M")
    assert_one_error_line(proc, str(gerris_files[1]), "not built from the same dataset")
    proc = cli("render", *gerris_files, "-o", tmp_path / "d.exr", *FLAGS, "--memory-budget",
               "1M", "--iso", 0.4)
    assert_one_error_line(proc, "iso-surfaces need the whole dataset")
    assert not (tmp_path / "d.exr").exists()


def test_cli_time_limit_writes_the_best_image_so_far(gerris_files, cli, tmp_path):
    cli("render", *gerris_files, "-o", tmp_path / "t.png", *FLAGS, "--spp", 64,
        "--memory-budget", "1M", "--time-limit", "0.001", check=0)
    image, meta = read_image(tmp_path / "t.png")
    progress = meta["settings"]["progress"]
    assert progress["complete"] is False and progress["samples"][0] < 64
    assert np.isfinite(image).all()


@pytest.mark.slow
def test_peak_memory_stays_under_budget_plus_baseline(gerris_files, tmp_path):
    """The baseline: the same budgeted command on a dataset of 64 cells; the
    Gerris structures are several times the budget's share for data."""
    from benchmarks.bench_budget import tiny_scene

    tiny = tiny_scene(tmp_path, "T")
    flags = ["--size", 128, 128, "--field", "T", "--range", 0, 1, "--max-opacity", 1]
    budget = 2 << 20
    baseline = peak_rss(["render", *tiny, "-o", tmp_path / "tiny.exr", *flags,
                         "--memory-budget", budget])
    used = peak_rss(["render", *gerris_files, "-o", tmp_path / "g.exr", *flags,
                     "--memory-budget", budget])
    meta = read_image(tmp_path / "g.exr")[1]
    assert meta["settings"]["pieces"] >= 4
    assert used <= baseline + budget, (used, baseline, budget)


@pytest.fixture(scope="module")
def layouts(tmp_path_factory):
    """make_big.py's octree-like, block-structured and thin-shell layouts at test
    size (benchmarks.bench_budget.make_layouts)."""
    from benchmarks.bench_budget import make_layouts

    return make_layouts(tmp_path_factory.mktemp("layouts"))


@pytest.mark.slow
def test_the_budget_holds_on_every_layout(layouts, tmp_path):
    """Peak resident memory minus the baseline (the same budgeted command on a
    64-cell dataset, docs/design.md) stays within the budget, for layouts and
    budgets drawn at random; each budget is at most half the structure files."""
    from hypothesis import HealthCheck, given, settings, strategies as st

    from benchmarks.bench_budget import tiny_scene

    @settings(max_examples=6, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(st.sampled_from(sorted(layouts)), st.integers(8, 16), st.sampled_from([160, 256]))
    def holds(name, mib, size):
        (files, field), budget = layouts[name], mib << 20
        flags = ["--size", size, size, "--max-opacity", 1, "--memory-budget", budget]
        tiny = tiny_scene(tmp_path, field)
        baseline = peak_rss(["render", *tiny, "-o", tmp_path / "tiny.exr", "--field", field, *flags])
        used = peak_rss(["render", *files, "-o", tmp_path / "l.exr", "--field", field, *flags])
        pieces = read_image(tmp_path / "l.exr")[1]["settings"]["pieces"]
        assert pieces >= 2, (name, mib, size, pieces)
        assert used - baseline <= budget, (name, mib, size, used - baseline, budget)

    holds()


def test_progressive_rewrites_are_whole_images_and_a_kill_leaves_one(gerris_files, tmp_path):
    out = tmp_path / "p.png"
    args = ["render", *gerris_files, "-o", out, *FLAGS, "--size", 128, 128, "--spp", 512,
            "--memory-budget", "2M", "--progressive", "0.05"]

    def check():  # every rewrite is a whole image
        image, meta = read_image(out)
        assert image.shape == (128, 128, 4)
        assert meta["settings"]["progress"]["complete"] is False

    status, err = _after_rewrites(args, 3, check)
    assert status == 143 and "interrupted" in err
    image, meta = read_image(out)  # the last rewrite stays, whole
    assert np.isfinite(image).all() and meta["settings"]["progress"]["complete"] is False
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_budget_progressive_and_time_limit_are_refused_under_mpi(gerris_files, tmp_path):
    from helpers.mpi import mpirun

    proc = mpirun(2, "render", *gerris_files, "-o", tmp_path / "m.exr", *FLAGS,
                  "--memory-budget", "1G", "--tile", 64, 64)
    assert_one_error_line(proc, "--memory-budget, --tile: not under MPI")


# -- frames tile by tile (--tile) ------------------------------------------------------------


@pytest.mark.parametrize("name,mode", [("gerris", "spp"), ("amrex", "iso"), ("enzo", "clip-slice"),
                                       ("athena", "two-layers")])
def test_tiles_are_the_very_pixels_of_the_whole_frame(name, mode):
    """Each pixel's rays and jitter come from its place in the frame, not in its tile."""
    scene = scene_for(name, mode)
    whole = render_steps(Resident(renderer(name, None)), scene)
    rgba, depth, stats = tiled(Resident(renderer(name, None)), scene, (29, 13))
    np.testing.assert_array_equal(rgba, whole.rgba)
    assert stats["samples"] == whole.stats["samples"] > 0
    assert stats["progress"] == {"complete": True, "samples": [scene.settings.spp] * 2,
                                 "pieces": [1, 1], "rows": [scene.settings.height] * 2}
    if whole.depth is not None:
        np.testing.assert_array_equal(depth, whole.depth)


@pytest.mark.parametrize("name,mode", [("gerris", "emission"), ("amrex", "central")])
@pytest.mark.slow
def test_tiled_budgeted_frame_equals_the_in_memory_frame(name, mode):
    built = loaded(name)[0]
    scene = scene_for(name, mode)
    scene = scene.replace(settings=dataclasses.replace(scene.settings, max_opacity=1.0))
    tile = (24, 16)
    domains = Budgeted(built.bricks, built.regions, scene,
                     budget_for(name, scene, 8) - image_bytes(scene) + image_bytes(scene, tile),
                     tile=tile)
    assert domains.n_domains >= 8
    rgba, _, stats = tiled(domains, scene, tile)
    same(rgba, renderer(name, None).render_scene(scene).rgba)
    assert stats["pieces"] == domains.n_domains and stats["progress"]["complete"]
    # each band reads the domains that meet it once, not once per tile
    bands = -(-scene.settings.height // tile[1])
    assert domains.reads <= bands * domains.n_domains


@pytest.mark.slow
def test_domains_out_of_view_are_never_read():
    name = "amrex"
    built, camera, lo, hi, _ = loaded(name)
    scene = scene_for(name, "emission")
    domains = Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, 16))
    centre = 0.5 * (lo + hi)
    corner = camera.with_overrides(look_at=tuple(lo + 0.1 * (hi - lo)), fovy=8.0)
    near = scene.replace(camera=corner)
    result = render_steps(domains, near)
    assert 0 < domains.reads < domains.n_domains, (domains.reads, domains.n_domains)
    same(result.rgba, renderer(name, None).render_scene(near).rgba)
    away = scene.replace(camera=camera.with_overrides(look_at=tuple(
        2 * np.asarray(camera.position) - centre)))
    domains.reads = 0
    empty = render_steps(domains, away)
    assert float(np.abs(empty.rgba).max()) == 0.0 and empty.stats["samples"] == 0
    assert domains.reads <= 1 and empty.stats["width"] == scene.settings.width


def test_footprints_hold_every_ray_that_meets_the_box():
    from exabricks.picture.camera import Camera

    rng = np.random.default_rng(7)
    camera = Camera((5.0, 4.0, 3.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 40.0)
    width, height = 64, 48
    origin, forward, du, dv = camera.frame(width, height)
    for _ in range(100):
        lo = rng.uniform(-2.0, 1.0, 3)
        hi = lo + rng.uniform(0.01, 1.5, 3)
        rect = camera.footprint(lo, hi, width, height)
        x, y = rng.uniform(0, width, 4000), rng.uniform(0, height, 4000)
        d = forward + (2 * x / width - 1)[:, None] * du + (1 - 2 * y / height)[:, None] * dv
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (lo - origin) / d, (hi - origin) / d
        enter = np.nanmax(np.minimum(t0, t1), axis=1)
        leave = np.nanmin(np.maximum(t0, t1), axis=1)
        hit = (enter <= leave) & (leave > 0)
        if not hit.any():
            continue
        assert rect is not None
        c0, r0, c1, r1 = rect
        cols, rows = np.floor(x[hit]), np.floor(y[hit])
        assert ((cols >= c0) & (cols < c1) & (rows >= r0) & (rows < r1)).all()
    behind = camera.footprint((4.0, 3.0, 2.0), (6.0, 5.0, 4.0), width, height)
    assert behind == (0, 0, width, height)  # the eye inside the box: every pixel


@pytest.mark.slow  # the library's tiled frames are in the fast suite
def test_cli_tiles_write_the_same_image_in_bands(gerris_files, cli, tmp_path):
    # A fixed exposure: the automatic one of a tiled frame is metered on a preview
    # (streaming.metered_scene), a whole frame's on itself; below, they agree closely.
    flags = [*FLAGS, "--size", 150, 70, "--spp", 2, "--no-auto-exposure"]
    for suffix in (".exr", ".png"):
        cli("render", *gerris_files, "-o", tmp_path / f"a{suffix}", *flags, check=0)
        cli("render", *gerris_files, "-o", tmp_path / f"t{suffix}", *flags, "--tile", 64, 16,
            check=0)
        a, _ = read_image(tmp_path / f"a{suffix}")
        t, meta = read_image(tmp_path / f"t{suffix}")
        np.testing.assert_array_equal(t, a)
        assert meta["settings"]["tile"] == [64, 16]
        assert meta["settings"]["progress"]["rows"] == [70, 70]
    cli("render", *gerris_files, "-o", tmp_path / "b.exr", *flags, "--tile", 64, 16,
        "--memory-budget", "1M", check=0)
    b, meta = read_image(tmp_path / "b.exr")
    same(b, read_image(tmp_path / "a.exr")[0])
    assert meta["settings"]["pieces"] > 1
    metered = []
    for name, extra in (("auto.exr", ()), ("auto-tiled.exr", ("--tile", 64, 16))):
        cli("render", *gerris_files, "-o", tmp_path / name, *flags[:-1], *extra, check=0)
        metered.append(read_image(tmp_path / name)[1]["settings"]["metered_exposure"])
    assert metered[0] > 0 and metered[1] == pytest.approx(metered[0], abs=0.25)
    cli("render", *gerris_files, "-o", tmp_path / "c.png", *flags, "--spp", 64,
        "--tile", 150, 8, "--time-limit", "0.001", "--background", "1,0,0", check=0)
    c, meta = read_image(tmp_path / "c.png")
    progress = meta["settings"]["progress"]
    assert progress["complete"] is False and 8 <= progress["rows"][0] < 70
    assert (c[progress["rows"][0]:] == np.float32([1, 0, 0, 1])).all()  # the background
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
def test_a_poster_in_tiles_stays_under_budget_plus_baseline(gerris_files, tmp_path):
    """A frame whose float image alone is 20x the budget. The baseline is the
    issue's: the same command on a dataset of 64 cells at the same image size
    (and tiles); tiles keep that baseline itself far below a whole frame."""
    from benchmarks.bench_budget import tiny_scene

    tiny = tiny_scene(tmp_path, "T")
    flags = ["--field", "T", "--range", 0, 1, "--max-opacity", 1, "--memory-budget", 4 << 20]
    poster = ["--size", 2560, 2048, "--tile", 1024, 16]
    small = peak_rss(["render", *tiny, "-o", tmp_path / "tiny.png", *flags, "--size", 128, 128])
    baseline = peak_rss(["render", *tiny, "-o", tmp_path / "tiny.png", *flags, *poster])
    # the kernels cached by a small frame of the same tiles (a poster takes minutes)
    warm = ["render", *gerris_files, "-o", tmp_path / "g.png", *flags, "--size", 256, 64, "--tile", 128, 16]
    used = peak_rss(["render", *gerris_files, "-o", tmp_path / "g.png", *flags, *poster], warm=warm)
    image, meta = read_image(tmp_path / "g.png")
    assert image.shape == (2048, 2560, 4) and image[..., 3].max() > 0.1
    frame = 2560 * 2048 * 16
    assert frame >= 20 * (4 << 20) and meta["settings"]["pieces"] >= 2
    assert used <= baseline + (4 << 20), (used, baseline)
    assert baseline - small < frame / 4, (baseline, small, frame)


@pytest.mark.slow
def test_tiled_progressive_rewrites_are_whole_images_and_a_kill_leaves_one(gerris_files,
                                                                           tmp_path):
    out = tmp_path / "p.exr"
    args = ["render", *gerris_files, "-o", out, *FLAGS, "--size", 256, 256, "--spp", 64,
            "--tile", 64, 8, "--progressive", "0.05"]
    rows = []

    def check():
        image, meta = read_image(out)
        assert image.shape == (256, 256, 4)
        progress = meta["settings"]["progress"]
        assert progress["complete"] is False
        rows.append(progress["rows"][0])

    status, err = _after_rewrites(args, 3, check)
    assert rows == sorted(rows)
    assert status == 143 and "interrupted" in err
    image, meta = read_image(out)
    assert np.isfinite(image).all() and meta["settings"]["progress"]["complete"] is False
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
def test_samples_share_a_domain_read():
    """Without a deadline or images so far, a domain is made once for the samples a
    quarter of the budget has images for (here all 4), not once per sample; the
    frame is the same as drawn sample after sample."""
    built = loaded("gerris")[0]
    scene = scene_for("gerris", "emission")
    scene = scene.replace(settings=dataclasses.replace(scene.settings, spp=4))
    reference = Renderer(built.bricks, built.regions, built.bvh,
                         fields=DATASETS["gerris"][1]).render_scene(scene)
    budget = budget_for("gerris", scene, 4) + 3 * image_bytes(scene) // 4
    batch = Budgeted(built.bricks, built.regions, scene, budget)
    assert batch.samples_per_read == 4 and batch.n_domains >= 2
    result = render_steps(batch, scene)
    assert result.stats["domain_reads"] == batch.n_domains
    same(result.rgba, reference.rgba)
    stepwise = Budgeted(built.bricks, built.regions, scene, budget)
    seen = []
    steps = render_steps(stepwise, scene, on_image=lambda rgba, progress: seen.append(progress))
    # sample after sample: each domain once per sample at most (those the budget holds
    # beside the next one stay: test_resident_domains_are_given_up_in_belady_order)
    assert stepwise.n_domains <= steps.stats["domain_reads"] <= 4 * stepwise.n_domains and seen
    np.testing.assert_allclose(steps.rgba, result.rgba, rtol=0, atol=1e-6)


def _optimal_misses(sequence, size: int, after=()) -> int:
    """Belady's misses of a cache of `size` equal entries over `sequence`, with
    `after` expected to follow it (reference)."""
    held, misses = [], 0
    sequence = list(sequence)
    for k, index in enumerate(sequence):
        if index in held:
            continue
        misses += 1
        if len(held) == size:
            rest = sequence[k + 1:] + list(after)
            held.remove(max(held, key=lambda i: rest.index(i) if i in rest else len(rest)))
        held.append(index)
    return misses


def test_resident_domains_are_given_up_in_belady_order(monkeypatch):
    """Domains stay resident while the budget holds them (HELD times their bytes)
    beside a domain being made (SLACK times its bytes); the one given up is the
    one asked for last. A
    cyclic sweep (every sample, band or frame asks for the domains in one order)
    then reads as few as the optimal cache does, where least-recently-used would
    read every domain every time."""
    from collections import deque
    from types import SimpleNamespace

    from exabricks.engine import streaming

    made = []
    monkeypatch.setattr(streaming, "domain_data", lambda b, r, lo, hi, **_: made.append(lo) or (None,) * 3)
    monkeypatch.setattr(streaming, "Renderer", lambda *a, **k: object())
    monkeypatch.setattr(streaming.schema, "release", lambda whole: None)
    monkeypatch.setattr(streaming.schema, "trim_heap", lambda: None)
    monkeypatch.setattr(streaming.gc, "collect", lambda: 0)  # (this process's heap: 40 ms each)
    n, nbytes = 6, 1000
    for resident in (1, 2, 3, 6):
        domains = Budgeted.__new__(Budgeted)
        domains.__dict__.update(
            partition=SimpleNamespace(nbytes=np.full(n, nbytes), n_domains=n, lower=np.arange(n),
                                      upper=np.arange(n) + 1),
            capacity=int(((resident - 1) * HELD + SLACK) * nbytes), n_domains=n, reads=0, prefetched=0,
            prefetch=False, _cache={}, _future=deque(), _cycle=[], _last=None, _pending=None,
            bricks=None, regions=None, fields=None, where=None, blocks=None, room=nbytes,
            options={}, device=None, scale=None, light=None)
        sweep = [0, 1, 2, 3, 4, 5, 5, 5]  # a domain's tiles and samples in a row count once
        domains.expect(sweep * 2)
        asked = [i for _ in range(3) for i in sweep]  # two sweeps expected, and one more frame
        for index in asked:
            domains.domain(index, None)
            assert len(domains._cache) <= resident
        runs = streaming._runs(asked)  # and after them, the expected order again
        assert domains.reads == _optimal_misses(runs, resident, after=runs[:6] + runs[:12]), resident
    assert domains.reads == n  # five beside the one made: each read once


@pytest.mark.parametrize("name,tile", [("gerris", None),
                                       pytest.param("amrex", (40, 24), marks=pytest.mark.slow)])
def test_prefetched_domains_give_the_same_frame(name, tile):
    """With prefetch, each next domain is made on a thread while the one before it
    draws; the frame (whole, or in bands of tiles) equals the in-memory one, and
    the domains are planned so that the budget holds both."""
    built = loaded(name)[0]
    scene = scene_for(name, "emission")
    budget = budget_for(name, scene, 4)
    domains = Budgeted(built.bricks, built.regions, scene, budget, tile=tile, prefetch=True)
    assert domains.n_domains >= 4 and domains.room * (SLACK + HELD) <= domains.capacity
    if tile is None:
        rgba = render_steps(domains, scene).rgba
    else:
        rgba = tiled(domains, scene, tile)[0]
    same(rgba, renderer(name, None).render_scene(scene).rgba)
    assert 0 < domains.prefetched < domains.reads
