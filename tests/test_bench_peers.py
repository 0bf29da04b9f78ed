"""workflows/bench_peers.py: the uniform-grid ceiling renders what exabricks renders, the
yt settings (camera width, transfer-function tables, image orientation) match ours, and the
exabricks worker (regions, cell location and the ceiling, interleaved) and the report work."""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
import pytest
from conftest import ROOT

sys.path.insert(0, str(ROOT / "workflows"))

import bench_peers  # noqa: E402
import make_big  # noqa: E402

from exabricks import schema  # noqa: E402
from exabricks.camera import Camera, default_camera  # noqa: E402
from exabricks.stages.brick import build_bricks  # noqa: E402
from exabricks.stages.bvh import build_bvh  # noqa: E402
from exabricks.stages.compare import compare_images  # noqa: E402
from exabricks.stages.regions import build_regions  # noqa: E402
from exabricks.stages.render import Renderer  # noqa: E402
from exabricks.stages.scene import DeviceScene  # noqa: E402
from exabricks.transfer_function import TransferFunction, default_transfer_function  # noqa: E402

SIZE = 64


@pytest.fixture(scope="module")
def single_level(tmp_path_factory):
    """make_big's multi-scale field on a ragged 40 x 36 x 28 grid as level-0 cells only
    (no merging) in a non-trivial world frame: (cells, volume (Z, Y, X) float32)."""
    shape = (28, 36, 40)  # (Z, Y, X)
    path = tmp_path_factory.mktemp("peers") / "vol.raw"
    make_big.generate(path, 40, 7)
    volume = np.fromfile(path, "<f4").reshape(40, 40, 40)[: shape[0], : shape[1], : shape[2]].copy()
    k, j, i = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    cells = schema.Cells(
        fields=("value",), origin_world=np.array([-1.0, 2.0, 0.5], np.float64),
        spacing_world=np.array([0.25, 0.25, 0.25], np.float64),
        lower_lattice=np.column_stack([i.ravel(), j.ravel(), k.ravel()]).astype(np.int32),
        level=np.zeros(volume.size, np.int8), values=volume.reshape(1, -1).astype(np.float32))
    return cells, volume


def _scene(cells, max_brick_width):
    bricks = build_bricks(cells, max_brick_width=max_brick_width)
    regions = build_regions(bricks)
    return bricks, regions, build_bvh(regions)


def test_resample_reproduces_cells_and_finest_grid(single_level):
    cells, volume = single_level
    lower, dims = bench_peers.finest_grid(cells)
    assert lower.tolist() == [0, 0, 0] and dims.tolist() == [40, 36, 28]
    resampled = bench_peers.resample_uniform(DeviceScene(*_scene(cells, 16)), lower, dims)
    # At a cell centre only that cell's hat is non-zero: the basis value is the cell value.
    np.testing.assert_allclose(resampled, volume, rtol=1e-6, atol=1e-7)


def _both(cells, volume, max_brick_width):
    """(exabricks RenderResult, uniform rgba, uniform samples, regions) of one view."""
    bricks, regions, bvh = _scene(cells, max_brick_width)
    lo, hi = schema.world_bounds(cells)
    camera = default_camera(lo, hi)
    tf = default_transfer_function((float(volume.min()), float(volume.max())))
    unit = 0.5  # two cells: dense enough that the front of the volume dominates
    ours = Renderer(bricks, regions, bvh).render(
        camera=camera, transfer_function=tf, width=SIZE, height=SIZE, sampling_rate=2.0,
        jitter=False, shading="none", unit_distance=unit)
    marcher = bench_peers.UniformGridRenderer(volume, np.zeros(3), cells.origin_world,
                                              cells.spacing_world)
    rgba, samples, _ = marcher.render(camera=camera, transfer_function=tf, width=SIZE,
                                      height=SIZE, sampling_rate=2.0, jitter=False,
                                      unit_distance=unit)
    assert ours.rgba[..., 3].max() > 0.5 and (ours.rgba[..., 3] == 0).any()
    return ours, rgba, samples, regions


def test_uniform_grid_equals_exabricks_render_on_one_region(single_level):
    ours, rgba, samples, regions = _both(*single_level, max_brick_width=64)
    assert regions.n_regions == 1
    # One region: the same sample points, values and weights; float32 rounding only.
    assert samples == ours.stats["samples"]
    metrics = compare_images(ours.rgba, rgba)
    assert metrics["max_abs"] < 1e-5, metrics


def test_uniform_grid_matches_exabricks_render_across_regions(single_level):
    ours, rgba, samples, regions = _both(*single_level, max_brick_width=16)
    assert regions.n_regions > 1
    # Each region face a ray crosses splits one step into two sub-intervals sampled at
    # their midpoints (one extra sample): a different midpoint-rule quadrature of the
    # same integral, not a different image.
    assert samples < ours.stats["samples"] <= samples * 1.2
    metrics = compare_images(ours.rgba, rgba)
    assert metrics["max_abs"] < 5e-3 and metrics["psnr"] > 80, metrics


def test_yt_transfer_function_reproduces_ours_at_its_nodes():
    pytest.importorskip("yt")
    tf = TransferFunction([[0.0, 0.1, 0.2, 0.9], [2.0, 1.0, 0.5, 0.0], [3.0, 0.3, 0.3, 0.3]],
                          [[0.5, 0.0], [1.5, 0.8], [3.0, 1.0]])
    bounds = bench_peers.yt_bounds((0.0, 3.0))
    assert bounds[0] < 0.0 and bounds[1] > 3.0  # yt drops values on or outside its bounds
    ytf = bench_peers.yt_transfer_function(tf, bounds, ray_length=7.0, unit_distance=0.5)
    assert ytf.grey_opacity
    x = ytf.funcs[0].x
    np.testing.assert_allclose(x, np.linspace(bounds[0], bounds[1], bench_peers.YT_NBINS))
    ref = tf.evaluate(x)
    for c in range(3):
        np.testing.assert_array_equal(ytf.funcs[c].y, ref[:, c])
    alpha = np.minimum(ref[:, 3], bench_peers.ALPHA_CLIP)
    np.testing.assert_allclose(ytf.funcs[3].y, -np.log(1.0 - alpha) * 7.0 / 0.5, rtol=1e-12)
    # yt's step opacity dt * sigma is the linearisation of ours, 1 - (1 - alpha)^(dt / unit).
    dt_t = 1e-6
    mid = np.searchsorted(x, 1.0)
    ours = 1.0 - (1.0 - ref[mid, 3]) ** (dt_t * 7.0 / 0.5)
    assert ytf.funcs[3].y[mid] * dt_t == pytest.approx(ours, rel=1e-5)


def test_yt_perspective_rays_are_our_pixel_centres():
    yt = pytest.importorskip("yt")
    from yt.visualization.volume_rendering.api import Scene, create_volume_source

    n = 17
    ds = yt.load_uniform_grid({"density": (np.ones((8, 8, 8)), "")}, (8, 8, 8), length_unit=1.0,
                              bbox=np.array([[0.0, 1.0]] * 3))
    camera = Camera((2.5, 1.7, 3.1), (0.4, 0.55, 0.5), (0.1, 1.0, 0.2), 35.0)
    sc = Scene()
    source = create_volume_source(ds.all_data(), ("stream", "density"))
    sc.add_source(source)
    cam = sc.add_camera(ds, lens_type="perspective")
    cam.resolution = (n, n)
    cam.focus = ds.arr(camera.look_at, "code_length")
    cam.set_position(ds.arr(camera.position, "code_length"), north_vector=np.asarray(camera.up))
    cam.width = ds.arr(bench_peers.yt_camera_width(camera, n, n, 9.0), "code_length")
    params = cam.lens._get_sampler_params(cam, source)
    yt_dirs = np.asarray(params["vp_dir"], np.float64)
    yt_dirs /= np.linalg.norm(yt_dirs, axis=-1, keepdims=True)
    _, ours = camera.rays(n, n)
    # yt's ray [i, j] runs along east = -right and north = up: our pixel (n-1-j, n-1-i).
    np.testing.assert_allclose(yt_dirs, ours[::-1, ::-1].transpose(1, 0, 2), atol=1e-12)
    np.testing.assert_allclose(np.asarray(params["vp_pos"])[0, 0], camera.position)
    with pytest.raises(ValueError, match="square"):
        bench_peers.yt_camera_width(camera, 20, 10, 1.0)


def test_yt_image_is_transposed_ours():
    """An off-centre opaque cube lands on the pixel our projection predicts, in yt's image
    transposed (what bench_peers does to yt's image)."""
    yt = pytest.importorskip("yt")
    from yt.visualization.volume_rendering.api import Scene, create_volume_source
    from yt.visualization.volume_rendering.transfer_functions import ColorTransferFunction

    n = 33
    x = (np.arange(32) + 0.5) / 32
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    centre = np.array([0.75, 0.6, 0.3])
    data = (np.abs(np.stack([X, Y, Z], -1) - centre) < 0.07).all(-1).astype(np.float64)
    ds = yt.load_uniform_grid({"density": (data, "")}, data.shape, length_unit=1.0,
                              bbox=np.array([[0.0, 1.0]] * 3))
    camera = default_camera([0, 0, 0], [1, 1, 1])
    sc = Scene()
    source = create_volume_source(ds.all_data(), ("stream", "density"))
    source.log_field = False
    tf = ColorTransferFunction((0.5, 1.5), grey_opacity=True)
    for table in tf.funcs:
        table.y[:] = 100.0
    source.transfer_function = tf
    sc.add_source(source)
    cam = sc.add_camera(ds, lens_type="perspective")
    cam.resolution = (n, n)
    cam.focus = ds.arr(camera.look_at, "code_length")
    cam.set_position(ds.arr(camera.position, "code_length"), north_vector=np.asarray(camera.up))
    cam.width = ds.arr(bench_peers.yt_camera_width(camera, n, n, 10.0), "code_length")
    alpha = np.asarray(sc.render())[..., 3].transpose()
    origin, forward, du, dv = camera.frame(n, n)
    d = centre - origin
    u = (d @ du) / (du @ du) / (d @ forward)
    v = (d @ dv) / (dv @ dv) / (d @ forward)
    col, row = (u + 1) / 2 * n - 0.5, (1 - v) / 2 * n - 0.5
    rows, cols = np.nonzero(alpha > 0.5)
    assert math.hypot(rows.mean() - row, cols.mean() - col) < 1.0


def test_yt_amr_grids_hold_exactly_our_leaves():
    """The Gerris plume (ExaJet, 5 levels) as nested yt grids: same leaves, same values."""
    yt = pytest.importorskip("yt")
    from conftest import GERRIS

    from exabricks import readers

    cells = readers.read(GERRIS, fields=["T"])
    grids, top = bench_peers.yt_amr_grids(cells)
    lo, hi = (np.asarray(b) for b in schema.world_bounds(cells))
    root = np.rint((hi - lo) / cells.spacing_world / (1 << top)).astype(int)
    ds = yt.load_amr_grids(grids, root, bbox=np.column_stack([lo, hi]), length_unit=1.0)
    ad = ds.all_data()
    width = np.left_shift(1, cells.level.astype(np.int64))[:, None] * cells.spacing_world
    ours = cells.origin_world + cells.lower_lattice * cells.spacing_world + 0.5 * width
    theirs = np.column_stack([ad["index", a].d for a in "xyz"])
    assert theirs.shape == ours.shape
    o = np.lexsort(ours.T)
    t = np.lexsort(theirs.T)
    np.testing.assert_array_equal(theirs[t], ours[o])
    np.testing.assert_array_equal(ad["stream", "T"].d[t], cells.values[0][o].astype(np.float64))
    np.testing.assert_array_equal(ad["index", "dx"].d[t], width[o, 0])


def test_yt_amr_grids_refuses_incomplete_octree():
    cells = schema.Cells(
        fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.int32),  # 2 of 8 children
        level=np.array([0, 0, 1], np.int8), values=np.ones((1, 3), np.float32))
    with pytest.raises(ValueError, match="octree-complete"):
        bench_peers.yt_amr_grids(cells)


def test_yt_composites_the_far_sample_in_front():
    """What bench_peers reports as yt's remaining difference: along a ray through two
    opaque slabs, yt's pixel takes the colour of the slab *further* from the camera."""
    yt = pytest.importorskip("yt")
    from yt.visualization.volume_rendering.api import Scene, create_volume_source
    from yt.visualization.volume_rendering.transfer_functions import ColorTransferFunction

    x = (np.arange(16) + 0.5) / 16
    X = np.broadcast_to(x[:, None, None], (16, 16, 16))
    data = np.where(X < 0.5, 1.0, 2.0)  # value 1 near the camera (x < 0.5), 2 behind
    ds = yt.load_uniform_grid({"density": (data, "")}, data.shape, length_unit=1.0,
                              bbox=np.array([[0.0, 1.0]] * 3))
    sc = Scene()
    source = create_volume_source(ds.all_data(), ("stream", "density"))
    source.log_field = False
    tf = ColorTransferFunction((0.5, 2.5), grey_opacity=True)
    near, far = np.abs(tf.funcs[0].x - 1.0) < 0.4, np.abs(tf.funcs[0].x - 2.0) < 0.4
    tf.funcs[0].y[:] = near   # red: value 1
    tf.funcs[2].y[:] = far    # blue: value 2
    tf.funcs[3].y[:] = 1000.0 * (near | far)
    source.transfer_function = tf
    sc.add_source(source)
    cam = sc.add_camera(ds, lens_type="perspective")
    cam.resolution = (9, 9)
    cam.focus = ds.arr([0.5, 0.5, 0.5], "code_length")
    cam.set_position(ds.arr([-3.0, 0.5, 0.5], "code_length"), north_vector=np.array([0.0, 0.0, 1.0]))
    cam.width = ds.arr([0.1, 0.1, 1.0], "code_length")
    centre = np.asarray(sc.render())[4, 4]
    assert centre[3] > 0.99
    assert centre[2] > 0.99 and centre[0] < 0.01  # the far (blue) slab wins


@pytest.fixture(scope="module")
def gerris_row(tmp_path_factory):
    """bench_peers' prepare and exabricks workers run in this process on the Gerris plume
    (16 x 16 frames, 2 rounds): a row as bench_dataset makes it."""
    path, field, _ = bench_peers.DATASETS["gerris"]
    tmp = tmp_path_factory.mktemp("peers-gerris")
    base = {"name": "gerris", "path": str(path), "field": field, "size": 16, "runs": 2,
            "image_prefix": str(tmp / "gerris"), "max_voxels": bench_peers.MAX_VOXELS,
            "alpha_scale": bench_peers.ALPHA_SCALE}
    prep = bench_peers.worker_prepare(base)
    ours = bench_peers.worker_exabricks({**base, **{k: prep[k] for k in (
        "camera", "transfer_function", "value_range", "unit_distance")}})
    return {"name": "gerris", "field": field, "prep": prep, "ours": ours,
            "uniform": ours.pop("uniform"), "cell_location": ours.pop("cell_location"),
            "yt": {"error": bench_peers.yt_skip_reason(prep["cells"], 1000)}}


def test_worker_interleaves_regions_cell_location_and_uniform(gerris_row):
    ours, located, uniform = gerris_row["ours"], gerris_row["cell_location"], gerris_row["uniform"]
    assert located["tree_nodes"] == 2 * gerris_row["prep"]["bricks"] - 1  # one brick per leaf
    for rate in ("2.0", "10.0"):
        a, b, u = ours["rates"][rate], located["rates"][rate], uniform["rates"][rate]
        assert len(a["kernel_s"]) == len(b["kernel_s"]) == len(u["kernel_s"]) == 2
        # The same samples, summed alike: the same frame.
        assert b["samples"] == a["samples"] > 0 and b["max_abs_vs_regions"] == 0.0
        assert u["samples"] > 0
    assert ours["rates"]["10.0"]["samples"] > ours["rates"]["2.0"]["samples"]


def test_yt_is_skipped_above_the_cell_cap():
    assert bench_peers.yt_skip_reason(505_856, bench_peers.YT_MAX_CELLS) is None
    reason = bench_peers.yt_skip_reason(23_600_000, bench_peers.YT_MAX_CELLS)  # "big"
    assert reason.startswith("skipped: 23,600,000 cells > --yt-max-cells")


def test_report_goes_into_its_docs_section(gerris_row, tmp_path):
    docs = tmp_path / "benchmarks.md"
    docs.write_text("# Benchmarks\n\n## render (PoCL)\n\nkept\n")
    args = argparse.Namespace(
        datasets="gerris", size=16, runs=2, no_yt=False, yt_max_cells=1000,
        alpha_scale=bench_peers.ALPHA_SCALE, max_voxels=bench_peers.MAX_VOXELS,
        images=str(tmp_path / "images"), docs=str(docs))
    body = "\n".join(bench_peers.report([gerris_row], "test machine", args))
    table3 = body[body.index("### regions vs cell location (paper Table 3)"):
                  body.index("### exabricks vs the uniform-grid ceiling")]
    rows = [line for line in table3.splitlines() if line.startswith("| gerris |")]
    assert len(rows) == 2  # rates 2 and 10
    a, b = (gerris_row[k]["rates"]["2.0"]["kernel_s"] for k in ("ours", "cell_location"))
    assert f"| {np.median(b) / np.median(a):.2f}x (" in rows[0] and "| yes (0.0e+00) |" in rows[0]
    assert "skipped: 67,712 cells > --yt-max-cells 1,000" in body
    # The targets summary: the same speed-up as the table, judged against 2x; no yt figure.
    speedup = np.median(b) / np.median(a)
    line = next(x for x in body.splitlines() if x.startswith("- cell location / regions"))
    assert f"gerris rate 2 {speedup:.2f}x" in line
    assert ("met on every one" in line) == (min(
        np.median(gerris_row["cell_location"]["rates"][r]["kernel_s"])
        / np.median(gerris_row["ours"]["rates"][r]["kernel_s"]) for r in ("2.0", "10.0")) >= 2)
    assert "- yt / ours, each at its default sampling (target 5x): not measured" in body
    bench_peers.benchdoc.replace_section(bench_peers.SECTION, body, docs)
    text = docs.read_text()
    assert "## render (PoCL)\n\nkept" in text and f"## {bench_peers.SECTION}\n" in text
