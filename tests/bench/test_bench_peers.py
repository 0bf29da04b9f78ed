"""The uniform-grid ceiling (benchmarks/uniform_grid.py) against a float64 NumPy march
and against exabricks' own frames; the yt bridge's nested grids against hand-computed
grids and yt's leaves; benchmarks/bench_peers.py's yt and VTK settings (benchmarks/peers/yt.py,
vtk.py), its exabricks worker (ours.py) and the figures its report (report.py) is made of,
against hand-computed values."""

from __future__ import annotations

import argparse
import math

import sys

import numpy as np
import pytest
from helpers import DEVICES, GERRIS


from benchmarks import kernel_resources
from benchmarks import make_big
from benchmarks.peers import common
from benchmarks.peers import ours as peer_ours
from benchmarks.peers import report as peer_report
from benchmarks.peers import vtk as peer_vtk
from benchmarks.peers import yt as peer_yt

from exabricks import schema  # noqa: E402
from exabricks.picture.camera import Camera, default_camera  # noqa: E402
from exabricks.util.errors import ExabricksError  # noqa: E402
from exabricks.readers import yt_grids  # noqa: E402
from benchmarks import uniform_grid
from exabricks.builders.bricks import build_bricks  # noqa: E402
from exabricks.builders.bvh import build_bvh  # noqa: E402
from exabricks.stages.compare import compare_images  # noqa: E402
from exabricks.builders.regions import build_regions  # noqa: E402
from exabricks.engine.renderer import Renderer  # noqa: E402
from exabricks.engine.device_data import DeviceDataset  # noqa: E402
from exabricks.picture.transfer_function import TransferFunction, default_transfer_function  # noqa: E402

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


# ---------------------------------------------------------------------------
# the uniform grid: its box, its resampling, its marcher


def test_finest_grid_of_two_levels_by_hand():
    # A level-1 cell at (2, 0, 0) spans [2, 4) x [0, 2) x [0, 2); a level-0 cell at
    # (-1, 3, 0) spans [-1, 0) x [3, 4) x [0, 1): the box is [-1, 4) x [0, 4) x [0, 2).
    cells = schema.Cells(
        fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.array([[2, 0, 0], [-1, 3, 0]], np.int32),
        level=np.array([1, 0], np.int8), values=np.ones((1, 2), np.float32))
    lower, dims = uniform_grid.finest_grid(cells)
    assert lower.tolist() == [-1, 0, 0] and dims.tolist() == [5, 4, 2]
    # Bricks: a 3 x 1 x 1 brick of level-1 cells at (0, 0, 0) spans [0, 6) x [0, 2) x [0, 2).
    bricks = schema.Bricks(
        fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.array([[0, 0, 0]], np.int32), level=np.array([1], np.int8),
        dims=np.array([[3, 1, 1]], np.int32), offset=np.array([0], np.int64),
        values=np.ones((1, 3), np.float32))
    lower, dims = uniform_grid.finest_grid(bricks)
    assert lower.tolist() == [0, 0, 0] and dims.tolist() == [6, 2, 2]


@pytest.mark.slow
def test_resample_reproduces_cells_and_finest_grid(single_level):
    cells, volume = single_level
    lower, dims = uniform_grid.finest_grid(cells)
    assert lower.tolist() == [0, 0, 0] and dims.tolist() == [40, 36, 28]
    # A chunk smaller than one z-slab still fills every slab.
    resampled = uniform_grid.resample(DeviceDataset(*_scene(cells, 16)), lower, dims, chunk=1000)
    # At a cell centre only that cell's hat is non-zero: the basis value is the cell value.
    np.testing.assert_allclose(resampled, volume, rtol=1e-6, atol=1e-7)


def _mix(a, b, f):
    return a + (b - a) * f  # as OpenCL's mix: NaN in either end gives NaN


def _trilinear(volume, x):
    """float64 trilinear value of `volume` (Z, Y, X) at voxel coordinates x (N, 3) (centres
    at integers), clamped to the edge voxels."""
    n = np.array(volume.shape[::-1])
    fl = np.floor(x)
    f = x - fl
    i0 = fl.astype(np.int64)
    lo, hi = np.clip(i0, 0, n - 1), np.clip(i0 + 1, 0, n - 1)

    def at(ix, iy, iz):
        return volume[iz, iy, ix]

    c = {}
    for dz, z in ((0, lo[:, 2]), (1, hi[:, 2])):
        for dy, y in ((0, lo[:, 1]), (1, hi[:, 1])):
            c[dy, dz] = _mix(at(lo[:, 0], y, z), at(hi[:, 0], y, z), f[:, 0])
    return _mix(_mix(c[0, 0], c[1, 0], f[:, 1]), _mix(c[0, 1], c[1, 1], f[:, 1]), f[:, 2])


def numpy_uniform_march(volume, lower_lattice, origin_world, spacing_world, camera, tf,
                        width, height, sampling_rate, unit_distance):
    """float64 reference of the marcher without jitter or early termination.

    Per pixel-centre ray: the interval through the voxels' support box (lattice
    [lower - 1/2, lower + dims + 1/2]), delimiters (k + 1/2) dt (dt = finest spacing /
    sampling rate) splitting it into sub-intervals sampled at their midpoints,
    trilinear values, opacity 1 - (1 - alpha)^(length / unit), front-to-back
    compositing; NaN samples transparent. Returns rgba (H, W, 4) premultiplied and
    the samples per pixel (H, W).
    """
    volume = np.asarray(volume, np.float64)
    spacing = np.asarray(spacing_world, np.float64)
    dims = np.array(volume.shape[::-1], np.float64)
    origins, directions = camera.rays(width, height)
    org = (origins - origin_world) / spacing - np.asarray(lower_lattice, np.float64) - 0.5
    step = directions / spacing
    dt = spacing.min() / sampling_rate
    rgba = np.zeros((height, width, 4))
    samples = np.zeros((height, width), np.int64)
    for row, col in np.ndindex(height, width):
        o, d = org[row, col], step[row, col]
        with np.errstate(divide="ignore"):
            t0, t1 = (-1.0 - o) / d, (dims - o) / d
        t_in, t_out = max(np.minimum(t0, t1).max(), 0.0), np.maximum(t0, t1).min()
        if not t_out > t_in:
            continue
        first = (math.ceil(t_in / dt - 0.5) + 0.5) * dt
        cuts = first + dt * np.arange(int((t_out - first) / dt) + 2)
        edges = np.concatenate([[t_in], cuts[(cuts > t_in) & (cuts < t_out)], [t_out]])
        mids, lengths = 0.5 * (edges[:-1] + edges[1:]), np.diff(edges)
        values = _trilinear(volume, o + mids[:, None] * d)
        samples[row, col] = len(mids)
        colour, transmittance = np.zeros(3), 1.0
        for value, length in zip(values, lengths):
            if np.isnan(value):
                continue
            r, g, b, a = tf.evaluate(np.array([value]))[0]
            a = 1.0 - (1.0 - a) ** (length / unit_distance)
            colour += transmittance * a * np.array([r, g, b])
            transmittance *= 1.0 - a
        rgba[row, col] = (*colour, 1.0 - transmittance)
    return rgba, samples


@pytest.mark.parametrize("device", DEVICES)
def test_uniform_grid_marcher_equals_float64_numpy_march(device):
    """A 6 x 5 x 4 grid with one NaN voxel, anisotropic spacing, a lattice offset and a
    non-square image that is no multiple of the 8 x 8 tiles."""
    rng = np.random.default_rng(5)
    volume = rng.uniform(0.0, 1.0, (4, 5, 6)).astype(np.float32)
    volume[3, 4, 5] = np.nan
    lower = np.array([3, -2, 5])
    origin, spacing = np.array([1.0, -2.0, 0.5]), np.array([0.5, 0.25, 0.4])
    lo_world = origin + spacing * (lower - 0.5)
    hi_world = origin + spacing * (lower + np.array([6, 5, 4]) + 0.5)
    camera = default_camera(lo_world, hi_world)
    # Opacity at most 0.3 per unit: the frame never nears full opacity, so the kernel's
    # early termination (max_opacity 1) never cuts a ray that the reference goes on with.
    tf = TransferFunction([[0.0, 0.1, 0.2, 0.9], [0.6, 1.0, 0.5, 0.0], [1.0, 0.3, 0.8, 0.3]],
                          [[0.0, 0.05], [0.5, 0.3], [1.0, 0.1]])
    width, height, rate, unit = 21, 13, 3.0, 0.7
    marcher = uniform_grid.UniformGridRenderer(volume, lower, origin, spacing, device=device)
    rgba, samples, seconds = marcher.render(
        camera=camera, transfer_function=tf, width=width, height=height, sampling_rate=rate,
        max_opacity=1.0, unit_distance=unit, jitter=False)
    ref, ref_samples = numpy_uniform_march(volume, lower, origin, spacing, camera, tf,
                                           width, height, rate, unit)
    assert rgba.shape == (height, width, 4) and rgba.dtype == np.float32 and seconds >= 0
    assert samples == int(ref_samples.sum()) and ref_samples.min() == 0  # some rays miss
    assert ref[..., 3].max() > 0.3  # the frame is not nearly empty
    np.testing.assert_allclose(rgba, ref, rtol=0, atol=2e-6)


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
    marcher = uniform_grid.UniformGridRenderer(volume, np.zeros(3), cells.origin_world,
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


def test_uniform_grid_refuses_a_volume_that_is_not_3d():
    with pytest.raises(ExabricksError, match="3D"):
        uniform_grid.UniformGridRenderer(np.zeros((4, 4)), np.zeros(3), np.zeros(3), np.ones(3))


# ---------------------------------------------------------------------------
# leaf cells as yt's nested grids (exabricks.readers.yt_grids.to_amr_grids)


def test_to_amr_grids_by_hand():
    """A level-1 cell refined into 8 level-0 cells (values 1..8, x fastest) beside a
    level-1 cell of value 20: yt level 0 is one 2 x 1 x 1 grid (the refined cell's mean
    4.5, then 20), yt level 1 one 2 x 2 x 2 grid of the children."""
    fine = [(i, j, k) for k in range(2) for j in range(2) for i in range(2)]
    cells = schema.Cells(
        fields=("v",), origin_world=np.array([10.0, 20.0, 30.0]), spacing_world=np.full(3, 0.5),
        lower_lattice=np.array(fine + [(2, 0, 0)], np.int32),
        level=np.array([0] * 8 + [1], np.int8),
        values=np.array([[1, 2, 3, 4, 5, 6, 7, 8, 20]], np.float32))
    grids, top = yt_grids.to_amr_grids(cells)
    assert top == 1 and len(grids) == 2
    coarse, child = grids
    assert coarse["level"] == 0 and child["level"] == 1
    np.testing.assert_array_equal(coarse["left_edge"], [10.0, 20.0, 30.0])
    np.testing.assert_array_equal(coarse["right_edge"], [12.0, 21.0, 31.0])
    np.testing.assert_array_equal(coarse["dimensions"], [2, 1, 1])
    np.testing.assert_array_equal(coarse["v"][0], np.array([4.5, 20.0]).reshape(2, 1, 1))
    assert coarse["v"][1] == ""
    np.testing.assert_array_equal(child["left_edge"], [10.0, 20.0, 30.0])
    np.testing.assert_array_equal(child["right_edge"], [11.0, 21.0, 31.0])
    np.testing.assert_array_equal(child["dimensions"], [2, 2, 2])
    i, j, k = np.meshgrid(np.arange(2), np.arange(2), np.arange(2), indexing="ij")
    np.testing.assert_array_equal(child["v"][0], 1 + i + 2 * j + 4 * k)  # [i, j, k] = (x, y, z)


def test_to_amr_grids_hold_exactly_our_leaves():
    """The Gerris plume (ExaJet, 5 levels) as nested yt grids: same leaves, same values."""
    yt = pytest.importorskip("yt")
    from exabricks import readers

    cells = readers.read(GERRIS, fields=["T"])
    grids, top = yt_grids.to_amr_grids(cells)
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


def test_to_amr_grids_refuses_incomplete_octree():
    cells = schema.Cells(
        fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.int32),  # 2 of 8 children
        level=np.array([0, 0, 1], np.int8), values=np.ones((1, 3), np.float32))
    with pytest.raises(ExabricksError, match="toy: not octree-complete at level 0"):
        yt_grids.to_amr_grids(cells, source="toy")


# ---------------------------------------------------------------------------
# bench_peers' yt settings


def test_yt_helpers_by_hand():
    # Extinction per unit ray parameter: -ln(1 - alpha) L / unit, alpha clipped below 1.
    np.testing.assert_allclose(
        peer_yt.yt_extinction([0.0, 0.5, 1.0], ray_length=7.0, unit_distance=0.5),
        [0.0, 14.0 * math.log(2.0), 14.0 * 6.0 * math.log(10.0)], rtol=1e-9)
    # Bounds widened by 1e-3 of the range (of max(1, |value|) for a constant field).
    assert peer_yt.yt_bounds((0.0, 3.0)) == pytest.approx((-0.003, 3.003), rel=1e-12)
    assert peer_yt.yt_bounds((2.0, 2.0)) == pytest.approx((1.998, 2.002), rel=1e-12)
    assert peer_yt.yt_bounds((-0.25, -0.25)) == pytest.approx((-0.251, -0.249), rel=1e-12)
    # fovy 90: tan 45 = 1, so w0 = 2 depth (N - 1) / N.
    camera = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 90.0)
    assert peer_yt.yt_camera_width(camera, 17, 17, 9.0) == pytest.approx(
        [18.0 * 16 / 17, 18.0 * 16 / 17, 9.0], rel=1e-12)
    with pytest.raises(ValueError, match="square"):
        peer_yt.yt_camera_width(camera, 20, 10, 1.0)
    # yt's image [i, j] is our pixel (row j, col i).
    image = np.arange(3 * 3 * 4, dtype=np.float64).reshape(3, 3, 4)
    ours = peer_yt.yt_image_to_ours(image)
    assert ours.dtype == np.float32 and ours.flags.c_contiguous
    np.testing.assert_array_equal(ours[1, 2], image[2, 1])


def test_yt_transfer_function_reproduces_ours_at_its_nodes():
    pytest.importorskip("yt")
    tf = TransferFunction([[0.0, 0.1, 0.2, 0.9], [2.0, 1.0, 0.5, 0.0], [3.0, 0.3, 0.3, 0.3]],
                          [[0.5, 0.0], [1.5, 0.8], [3.0, 1.0]])
    bounds = peer_yt.yt_bounds((0.0, 3.0))
    ytf = peer_yt.yt_transfer_function(tf, bounds, ray_length=7.0, unit_distance=0.5)
    assert ytf.grey_opacity
    x = ytf.funcs[0].x
    assert len(x) == peer_yt.YT_NBINS
    ref = tf.evaluate(x)
    for c in range(3):
        np.testing.assert_array_equal(ytf.funcs[c].y, ref[:, c])
    alpha = np.minimum(ref[:, 3], peer_yt.ALPHA_CLIP)
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
    cam.width = ds.arr(peer_yt.yt_camera_width(camera, n, n, 9.0), "code_length")
    params = cam.lens._get_sampler_params(cam, source)
    yt_dirs = np.asarray(params["vp_dir"], np.float64)
    yt_dirs /= np.linalg.norm(yt_dirs, axis=-1, keepdims=True)
    _, ours = camera.rays(n, n)
    # yt's ray [i, j] runs along east = -right and north = up: our pixel (n-1-j, n-1-i).
    np.testing.assert_allclose(yt_dirs, ours[::-1, ::-1].transpose(1, 0, 2), atol=1e-12)
    np.testing.assert_allclose(np.asarray(params["vp_pos"])[0, 0], camera.position)


def test_yt_image_as_ours_puts_a_cube_where_our_projection_does():
    """An off-centre opaque cube lands, in yt's image turned into ours
    (`yt_image_to_ours`), on the pixel our projection predicts."""
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
    cam.width = ds.arr(peer_yt.yt_camera_width(camera, n, n, 10.0), "code_length")
    alpha = peer_yt.yt_image_to_ours(np.asarray(sc.render()))[..., 3]
    origin, forward, du, dv = camera.frame(n, n)
    d = centre - origin
    u = (d @ du) / (du @ du) / (d @ forward)
    v = (d @ dv) / (dv @ dv) / (d @ forward)
    col, row = (u + 1) / 2 * n - 0.5, (1 - v) / 2 * n - 0.5
    rows, cols = np.nonzero(alpha > 0.5)
    assert math.hypot(rows.mean() - row, cols.mean() - col) < 1.0


def test_yt_is_skipped_only_above_the_cell_cap():
    assert peer_yt.yt_skip_reason(1000, 1000) is None
    assert peer_yt.yt_skip_reason(999, 1000) is None
    assert peer_yt.yt_skip_reason(1001, 1000) is not None


# ---------------------------------------------------------------------------
# VTK: the finest grid, the transfer function, the camera, the image layout


def test_vtk_finest_grid_by_hand():
    # [0, 1]^3 with 1/128 cells: 128 centres from 1/256 to 1 - 1/256.
    dims, sampling = peer_vtk.vtk_finest_grid([0, 1, 0, 1, 0, 1], [1 / 128] * 3)
    assert dims == [128, 128, 128]
    assert sampling == pytest.approx([1 / 256, 1 - 1 / 256] * 3)
    # A ragged box: [-1, 4) x [0, 2) x [0.5, 1.25) with 0.25 cells.
    dims, sampling = peer_vtk.vtk_finest_grid([-1, 4, 0, 2, 0.5, 1.25], [0.25, 0.25, 0.25])
    assert dims == [20, 8, 3]
    assert sampling == pytest.approx([-0.875, 3.875, 0.125, 1.875, 0.625, 1.125])
    with pytest.raises(ValueError):
        peer_vtk.vtk_finest_grid([0, 1, 0, 1, 0, 1], [0.0, 0.1, 0.1])
    with pytest.raises(ValueError):
        peer_vtk.vtk_finest_grid([0, 0.01, 0, 1, 0, 1], [0.1, 0.1, 0.1])


def test_vtk_readers_and_skips(tmp_path):
    for name in ("gerris", "big"):
        assert peer_vtk.vtk_skip_reason(name, tmp_path / "x.cells") == "no VTK reader"
    assert peer_vtk.vtk_source("amrex", tmp_path) == tmp_path
    assert peer_vtk.vtk_skip_reason("amrex", tmp_path) is None
    # Enzo opens the .hierarchy, Athena++ the .athdf.xdmf sidecar.
    assert peer_vtk.vtk_source("enzo", tmp_path / "run_0010") == tmp_path / "run_0010.hierarchy"
    athdf = tmp_path / "nowhere" / "Blast.athdf"
    assert peer_vtk.vtk_source("athena", athdf) == athdf.parent / "Blast.athdf.xdmf"
    assert "Blast.athdf.xdmf missing" in peer_vtk.vtk_skip_reason("athena", athdf)


def test_parse_amr_resampler_log():
    # vtkAMRResampleFilter's own report (vtkAMRResampleFilter.cxx), as the worker captures it.
    text = ("Running Resampler\nRequest Grid Dim : 128, 128, 128\n"
            "Computed Grid Dim: 48, 58, 46\nAdjusted Grid Dim: 48, 58, 46\n"
            "Requested Max Level = 1\n********* Resample Stats *************\n"
            "Average Level: 0.803879\nNumber Of Failed Points: 0\n")
    assert peer_vtk.parse_amr_resampler_log(text) == {
        "requested_dims": [128, 128, 128], "computed_dims": [48, 58, 46],
        "adjusted_dims": [48, 58, 46], "requested_max_level": 1,
        "average_level": pytest.approx(0.803879), "failed_points": 0}
    assert peer_vtk.parse_amr_resampler_log("") == {}


def test_vtk_image_to_ours_flips_rows():
    pixels = np.arange(2 * 3 * 4, dtype=np.float64)  # VTK: bottom row first
    image = peer_vtk.vtk_image_to_ours(pixels, 3, 2)
    assert image.shape == (2, 3, 4) and image.dtype == np.float32
    assert image[1, 0].tolist() == [0, 1, 2, 3]      # VTK's first pixel: bottom left
    assert image[0, 2].tolist() == [20, 21, 22, 23]  # its last: top right


def test_vtk_volume_property_reproduces_ours_at_and_between_knots():
    pytest.importorskip("vtk")
    tf = default_transfer_function((0.5, 2.0))
    alpha = tf.alpha_points.copy()
    alpha[:, 1] *= common.ALPHA_SCALE
    tf = TransferFunction(tf.rgb_points[::16], alpha, tf.name)  # every 16th colour knot
    prop = peer_vtk.vtk_volume_property(tf, 0.125)
    colour, opacity = prop.GetRGBTransferFunction(), prop.GetScalarOpacity()
    knots = np.union1d(tf.rgb_points[:, 0], tf.alpha_points[:, 0])
    xs = np.concatenate([knots, 0.5 * (knots[1:] + knots[:-1]), [0.0, 3.0]])  # and outside
    want = tf.evaluate(xs)
    got = np.array([[*colour.GetColor(x), opacity.GetValue(x)] for x in xs])
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert prop.GetScalarOpacityUnitDistance() == 0.125
    assert not prop.GetShade() and prop.GetInterpolationType() == 1  # linear


def test_vtk_camera_sees_our_pixel_centres():
    pytest.importorskip("vtk")
    from vtkmodules.vtkRenderingCore import vtkCamera

    # Up not orthogonal to the view, a non-square frame.
    camera = Camera(position=(3.0, -1.0, 2.0), look_at=(0.2, 0.4, -0.1), up=(0.3, 0.2, 1.0),
                    fovy=40.0)
    width, height = 8, 6
    bounds = [[-1.0, -0.5, -1.0], [1.0, 1.5, 0.5]]
    params = peer_vtk.vtk_camera_parameters(camera, bounds)
    cam = vtkCamera()
    peer_vtk.apply_vtk_camera(cam, params)
    _, forward, _, _ = camera.frame(width, height)
    np.testing.assert_allclose(cam.GetDirectionOfProjection(), forward, atol=1e-12)
    # Every pixel's ray, projected by VTK's camera, lands on that pixel's centre in VTK's
    # normalised device coordinates (x right, y up).
    origins, directions = camera.rays(width, height)
    matrix = cam.GetCompositeProjectionTransformMatrix(width / height, -1, 1)
    m = np.array([[matrix.GetElement(i, j) for j in range(4)] for i in range(4)])
    points = origins + 2.5 * directions
    clip = np.concatenate([points, np.ones(points.shape[:2] + (1,))], axis=-1) @ m.T
    ndc = clip[..., :2] / clip[..., 3:]
    cols, rows = np.meshgrid(np.arange(width), np.arange(height))
    np.testing.assert_allclose(ndc[..., 0], 2 * (cols + 0.5) / width - 1, atol=1e-9)
    np.testing.assert_allclose(ndc[..., 1], 1 - 2 * (rows + 0.5) / height, atol=1e-9)
    # The clipping range holds the whole box.
    near, far = cam.GetClippingRange()
    lo, hi = (np.asarray(b) for b in bounds)
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    depth = (corners - np.asarray(camera.position)) @ forward
    assert 0 < near < depth.min() and depth.max() < far


def test_vtk_renders_a_cube_where_our_projection_does(tmp_path):
    """The fixed-point ray caster of the worker, through our camera, transfer function and
    image layout, on an opaque off-centre cube: the same pixels as our projection."""
    pytest.importorskip("vtk")
    import json
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import json, os, sys
        import numpy as np
        from benchmarks.peers import vtk as peer_vtk
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = peer_vtk.VTK_WINDOW
        os.environ["LP_NUM_THREADS"] = "1"
        import vtkmodules.vtkRenderingOpenGL2, vtkmodules.vtkRenderingVolumeOpenGL2
        from vtkmodules.vtkCommonCore import vtkFloatArray
        from vtkmodules.vtkCommonDataModel import vtkImageData
        from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
        from vtkmodules.vtkRenderingCore import vtkCamera, vtkRenderer, vtkRenderWindow, vtkVolume
        from vtkmodules.vtkRenderingVolume import vtkFixedPointVolumeRayCastMapper
        from exabricks.picture.camera import default_camera
        from exabricks.picture.transfer_function import TransferFunction
        n, size = 32, 48
        volume = np.zeros((n, n, n))
        volume[4:12, 20:28, 18:26] = 1.0  # z, y, x: low z, high y, high x
        image = vtkImageData()
        image.SetDimensions(n, n, n)
        image.SetSpacing(1.0 / n, 1.0 / n, 1.0 / n)
        image.SetOrigin(0.5 / n, 0.5 / n, 0.5 / n)
        image.GetPointData().SetScalars(numpy_to_vtk(volume.ravel()))
        camera = default_camera([0, 0, 0], [1, 1, 1])
        tf = TransferFunction(np.array([[0, 1, 1, 1], [1, 1, 1, 1]], float),
                              np.array([[0, 0], [0.49, 0], [0.5, 1], [1, 1]], float))
        mapper = vtkFixedPointVolumeRayCastMapper()
        mapper.SetInputData(image)
        mapper.SetNumberOfThreads(1)
        mapper.SetAutoAdjustSampleDistances(False)
        mapper.SetSampleDistance(0.25 / n)
        actor = vtkVolume()
        actor.SetMapper(mapper)
        actor.SetProperty(peer_vtk.vtk_volume_property(tf, 1.0 / n))
        window = vtkRenderWindow()
        window.SetOffScreenRendering(True)
        window.SetAlphaBitPlanes(True)
        window.SetMultiSamples(0)
        window.SetSize(size, size)
        ren = vtkRenderer()
        ren.SetBackgroundAlpha(0.0)
        cam = vtkCamera()
        peer_vtk.apply_vtk_camera(cam, peer_vtk.vtk_camera_parameters(
            camera, [[0, 0, 0], [1, 1, 1]]))
        ren.SetActiveCamera(cam)
        ren.AddVolume(actor)
        window.AddRenderer(ren)
        window.Render()
        pixels = vtkFloatArray()
        window.GetRGBAPixelData(0, 0, size - 1, size - 1, 0, pixels, 0)
        rgba = peer_vtk.vtk_image_to_ours(vtk_to_numpy(pixels), size, size)
        np.save(sys.argv[1], rgba)
        json.dump(camera.to_dict(), open(sys.argv[2], "w"))
        """)
    # In its own process: VTK reads VTK_DEFAULT_OPENGL_WINDOW and Mesa LP_NUM_THREADS once.
    out, cam_path = tmp_path / "vtk.npy", tmp_path / "camera.json"
    proc = subprocess.run([sys.executable, "-c", script, str(out), str(cam_path)], capture_output=True,
                          text=True, timeout=120)
    if proc.returncode != 0 and "EGL" in proc.stderr:
        pytest.skip(f"no offscreen EGL rendering here: {proc.stderr.strip()[-300:]}")
    assert proc.returncode == 0, proc.stderr
    rgba = np.load(out)
    camera = Camera.from_dict(json.loads(cam_path.read_text()))
    size = rgba.shape[0]
    # Our projection of the cube [18, 26) x [20, 28) x [4, 12) / 32: where our pixel rays
    # hit the box (slab test), against where VTK's frame is opaque.
    lo, hi = np.array([18, 20, 4]) / 32, np.array([26, 28, 12]) / 32
    origins, directions = camera.rays(size, size)
    with np.errstate(divide="ignore"):
        t0, t1 = (lo - origins) / directions, (hi - origins) / directions
    hit = np.minimum(t0, t1).max(axis=-1) < np.maximum(t0, t1).min(axis=-1)
    covered = rgba[..., 3] > 0.5
    assert hit.sum() > 20
    # Only pixels along the cube's outline (trilinear edges, half-voxel margins) may differ.
    assert (hit != covered).sum() <= 0.35 * hit.sum(), ((hit != covered).sum(), hit.sum())
    assert (hit & covered).sum() >= 0.8 * hit.sum()
    assert np.abs(rgba[..., :3] - rgba[..., 3:]).max() < 0.02  # white, premultiplied


# ---------------------------------------------------------------------------
# the exabricks worker on real data, and the figures of the report


@pytest.fixture(scope="module")
def gerris_row(tmp_path_factory):
    """bench_peers' prepare and exabricks workers run in this process on the Gerris plume
    (16 x 16 frames, 2 rounds): a row as bench_dataset makes it."""
    path, field, _ = common.DATASETS["gerris"]
    tmp = tmp_path_factory.mktemp("peers-gerris")
    base = {"name": "gerris", "path": str(path), "field": field, "size": 16, "runs": 2,
            "image_prefix": str(tmp / "gerris"), "max_voxels": common.MAX_VOXELS,
            "alpha_scale": common.ALPHA_SCALE}
    prep = peer_ours.worker_prepare(base)
    ours = peer_ours.worker_exabricks({**base, **{k: prep[k] for k in (
        "camera", "transfer_function", "value_range", "unit_distance")}})
    return {"name": "gerris", "field": field, "prep": prep, "ours": ours,
            "uniform": ours.pop("uniform"), "cell_location": ours.pop("cell_location"),
            "yt": {"error": peer_yt.yt_skip_reason(prep["cells"], 1000)},
            "vtk": {"error": peer_vtk.vtk_skip_reason("gerris", path)}}


def test_worker_interleaves_regions_cell_location_and_uniform(gerris_row):
    ours, located, uniform = gerris_row["ours"], gerris_row["cell_location"], gerris_row["uniform"]
    prep = gerris_row["prep"]
    assert located["tree_nodes"] == 2 * prep["bricks"] - 1  # one brick per leaf
    for rate in common.RATE_KEYS:
        a, b, u = ours["rates"][rate], located["rates"][rate], uniform["rates"][rate]
        assert len(a["kernel_s"]) == len(b["kernel_s"]) == len(u["kernel_s"]) == 2
        # The same samples and sums: the same frame, up to the order in which a packet
        # (regions, on a CPU) adds its lanes' colours (kernels/packet.cl,
        # eb_packet_composite) where cell location adds them one at a time.
        assert b["samples"] == a["samples"] > 0 and b["max_abs_vs_regions"] <= 1e-5
        assert u["samples"] > 0
    low, high = common.RATE_KEYS
    assert ours["rates"][high]["samples"] > ours["rates"][low]["samples"]
    # The Gerris plume is 128^3 finest cells: the uniform grid is that box, and the opacity
    # unit (largest extent / 128) its finest cell.
    assert uniform["dims"] == [128, 128, 128] and uniform["voxels"] == 128 ** 3
    assert prep["unit_distance"] == prep["finest_cell_world"] == 1.0


def toy_row(name: str = "toy") -> dict:
    """A results row with round figures, as bench_dataset makes it (one round of each)."""
    camera = default_camera([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])

    def rates(regions, uniform):
        return {key: {"first_frame_s": 1.0, "frame_s": frame, "kernel_s": kernel,
                      "samples": samples}
                for key, (frame, kernel, samples) in zip(common.RATE_KEYS, regions)} \
            if uniform is None else {key: {"kernel_s": kernel, "samples": samples}
                                     for key, (kernel, samples) in zip(common.RATE_KEYS, uniform)}

    return {
        "name": name, "field": "v",
        "prep": {"cells": 1000, "bricks": 10, "regions": 40, "levels": 2, "read_s": 0.5,
                 "build_s": 0.25, "save_s": 0.1, "camera": camera.to_dict(),
                 "transfer_function": default_transfer_function((0.0, 1.0)).to_paraview_dict(),
                 "world_bounds": [[0, 0, 0], [1, 1, 1]], "value_range": [0.0, 1.0],
                 "unit_distance": 0.5, "finest_cell_world": 0.125,
                 "bricks_per_region_by_count": 2.5, "bricks_per_region_by_volume": 1.25},
        "ours": {"load_s": 0.1, "kernel_build_s": 0.2, "upload_s": 0.3, "device": "toy",
                 "peak_rss_mib": 100.0,
                 "rates": rates([([1.0, 2.0, 4.0], [0.1, 0.2, 0.3], 1000),
                                 ([3.0, 4.0, 8.0], [0.5, 0.6, 0.7], 5000)], None)},
        "cell_location": {"setup_s": 0.1, "tree_build_s": 0.001, "tree_first_build_s": 0.5,
                          "tree_nodes": 19, "tree_depth": 5,
                          "rates": {k: {**v, "max_abs_vs_regions": 0.0} for k, v in rates(
                              None, [([0.3, 0.6, 0.9], 1000), ([1.0, 1.2, 1.4], 5000)]).items()}},
        "uniform": {"dims": [8, 8, 8], "voxels": 512, "fits": True,
                    "rates": rates(None, [([0.05, 0.1, 0.2], 800), ([0.2, 0.4, 0.5], 4000)])},
        "yt": {"import_s": 1.0, "convert_s": None, "load_index_s": 1.0, "setup_s": 1.0,
               "first_frame_s": 7.0, "frame_s": [5.0, 6.0, 7.0], "peak_rss_mib": 200.0},
        "vtk": {"version": "9.9.9", "import_s": 0.1, "reader": "vtkToyReader", "threads": 2,
                "gl_renderer": "toy pipe", "finest_dims": [8, 8, 8],
                "finest_spacing": [0.125] * 3, "levels": 2, "amr": True, "peak_rss_mib": 300.0,
                "resample": {"read_s": 0.5, "dims": [8, 8, 8], "resample_s": 2.0,
                             "first_frame_s": 1.5, "first_image_s": 4.0,
                             "frame_s": [1.0, 4.0, 5.0]},
                "amr_mapper": {"first_image_s": 1.0, "frame_s": [0.5, 1.0, 3.0],
                               "resampler": {"requested_max_level": 0, "average_level": 0.25},
                               "grid_dims": [4, 4, 4], "grid_spacing": [0.25, 0.25, 0.5],
                               "render_mode": "GPU"}},
        "agreement": {},
    }


def test_report_figures_by_hand():
    low, high = common.RATE_KEYS
    rows = [toy_row(), {"name": "broken", "error": "missing"},
            {**toy_row("no-yt"), "yt": {"error": "skipped"}}]
    # yt / ours frame medians: 6 / 2 and 6 / 4; the row without yt has none.
    assert peer_report.yt_ratios(rows, low) == {"toy": pytest.approx(3.0)}
    assert peer_report.yt_ratios(rows, high) == {"toy": pytest.approx(1.5)}
    # ours / uniform samples per second: (1000 / 0.2) / (800 / 0.1), (5000 / 0.6) / (4000 / 0.4).
    ceiling = peer_report.ceiling_ratios(rows[:1])
    assert ceiling == {("toy", low): pytest.approx(0.625), ("toy", high): pytest.approx(5 / 6)}
    figures = peer_report.target_figures(rows[:1])
    rl, rh = (f"{float(k):g}" for k in common.RATE_KEYS)
    # cell location / regions kernel medians: 0.6 / 0.2 and 1.2 / 0.6.
    assert figures["cell_location"] == {f"toy rate {rl}": pytest.approx(3.0),
                                        f"toy rate {rh}": pytest.approx(2.0)}
    assert figures["ceiling"] == {f"toy rate {rl}": pytest.approx(0.625),
                                  f"toy rate {rh}": pytest.approx(5 / 6)}
    # The default camera (fovy 30) on a square frame: the corner pixel centres lie at
    # u = v = (N - 1) / N of the half-extent tan 15 deg, 1 / cos = |(1, u t, v t)|.
    # VTK / ours: frame medians 4 / 2 and (AMR mapper) 1 / 2; first images 4 and 1 against
    # ours read 0.5 + build 0.25 + program 0.2 + upload 0.3 + first frame 1.0 = 2.25.
    assert peer_report.ours_first_image_s(rows[0]) == pytest.approx(2.25)
    assert peer_report.vtk_ratios(rows) == {
        "toy": {"frame": pytest.approx(2.0), "first_image": pytest.approx(4 / 2.25),
                "amr_frame": pytest.approx(0.5), "amr_first_image": pytest.approx(1 / 2.25)},
        "no-yt": {"frame": pytest.approx(2.0), "first_image": pytest.approx(4 / 2.25),
                  "amr_frame": pytest.approx(0.5), "amr_first_image": pytest.approx(1 / 2.25)}}
    # The finest grid resampled, VTK's one failed and a dataset VTK cannot read: no ratio.
    enzo_like = toy_row("enzo-like")
    enzo_like["vtk"]["resample"] = {"read_s": 0.1, "error": "finest grid too big"}
    assert peer_report.vtk_ratios([enzo_like, {**toy_row("gerris"), "vtk": {
        "error": "no VTK reader"}}]) == {"enzo-like": {
            "amr_frame": pytest.approx(0.5), "amr_first_image": pytest.approx(1 / 2.25)}}
    assert peer_report._amr_grid(rows[0]["vtk"]["amr_mapper"], [0.125] * 3) == \
        "4x4x4 points, 2.0-4.0 finest cells apart"
    n = 16
    t = math.tan(math.radians(15.0)) * (n - 1) / n
    assert peer_report._off_axis_stretch(rows[0]["prep"]["camera"], n) == pytest.approx(
        math.sqrt(1.0 + 2.0 * t * t) - 1.0, rel=1e-9)


def _tables(lines):
    """Every markdown table of `lines` as a list of its rows' cell counts."""
    tables, current = [], []
    for line in [*lines, ""]:
        if line.startswith("|"):
            current.append(line.strip().strip("|").count("|") + 1)
        elif current:
            tables.append(current)
            current = []
    return tables


def _vtk_variants():
    """Rows whose VTK parts failed or were skipped in each way the report handles."""
    enzo_like = toy_row("enzo-like")
    enzo_like["vtk"]["resample"] = {"read_s": 0.1, "error": "finest grid too big"}
    athena_like = toy_row("athena-like")
    athena_like["vtk"]["amr_mapper"] = {"error": "not an AMR data set"}
    return [enzo_like, athena_like, {**toy_row("no-reader"), "vtk": {"error": "no VTK reader"}},
            {key: value for key, value in toy_row("no-vtk").items() if key != "vtk"}]


@pytest.mark.parametrize("which", ["toy", "gerris"])
@pytest.mark.parametrize("no_vtk", [False, True])
def test_report_tables_are_whole(which, no_vtk, request, tmp_path):
    """Every row of every table of the report has its header's number of cells, for
    measured rows, a failed one, one without yt and each way VTK is missing."""
    rows = [toy_row(), {"name": "broken", "error": "missing"}, *_vtk_variants()] \
        if which == "toy" else [request.getfixturevalue("gerris_row")]
    args = argparse.Namespace(
        datasets="x", size=16, runs=2, no_yt=False, yt_max_cells=1000, no_vtk=no_vtk,
        vtk_threads=2, alpha_scale=common.ALPHA_SCALE, max_voxels=common.MAX_VOXELS,
        images=str(tmp_path / "images"), docs=str(tmp_path / "benchmarks.md"))
    lines = peer_report.report(rows, "test machine", args)
    tables = _tables(lines)
    # exabricks vs yt, [VTK resample + fixed point, vtkAMRVolumeMapper,] cell location, ceiling
    assert len(tables) == (3 if no_vtk else 5)
    for counts in tables:
        assert len(counts) > 2 and set(counts) == {counts[0]}, counts
    text = "\n".join(lines)
    assert ("--no-vtk" in lines[0]) == no_vtk and ("How VTK was matched" in text) == (not no_vtk)
    if which == "gerris" and not no_vtk:
        assert "| gerris (T) | no VTK reader |" in text


def test_to_amr_grids_fill_holes():
    """With `fill`, the 6 missing children of the refined cell and the missing coarsest
    cell of the bounding box become leaves of the fill value; the given cells keep
    theirs, and the level-1 grid covers the box (2 x 1 x 2 cells: the one refined cell,
    the one given beside it and the two missing above them)."""
    cells = schema.Cells(
        fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 2]], np.int32),
        level=np.array([0, 0, 1, 1], np.int8), values=np.array([[1, 2, 5, 7]], np.float32))
    grids, top = yt_grids.to_amr_grids(cells, fill=-9.0)
    assert top == 1
    by_level = {g["level"]: g for g in grids}
    assert len(grids) == 2
    coarse, child = by_level[0], by_level[1]
    np.testing.assert_array_equal(coarse["dimensions"], [2, 1, 2])
    # the refined cell's mean over its 2 given and 6 filled children; 5, 7 and the filled one
    mean = (1 + 2 - 9 * 6) / 8
    np.testing.assert_array_equal(coarse["v"][0][:, 0, :], [[mean, 7.0], [5.0, -9.0]])
    np.testing.assert_array_equal(child["dimensions"], [2, 2, 2])
    expect = np.full((2, 2, 2), -9.0)
    expect[0, 0, 0], expect[1, 0, 0] = 1, 2
    np.testing.assert_array_equal(child["v"][0], expect)


@pytest.mark.slow
def test_ab_kernels_renders_two_versions_in_one_process(tmp_path):
    """benchmarks/ab_kernels.py: a revision's exabricks/ and kernels/ land in a folder
    of their own and import beside the working tree's; both versions (the second
    with a two-entry walk heap given as a build option, so that every ray falls back
    to the re-trace walk) build and render the same Gerris frames, volume timed and
    surfaces once, to the same non-empty images; each built its own programs, and
    exabricks' build options are its own again afterwards."""
    from benchmarks import ab_kernels
    from exabricks.device import opencl

    root = ab_kernels.base_package("HEAD", tmp_path)
    assert (root / "exabricks" / "__init__.py").is_file() and (root / "kernels" / "render.cl").is_file()
    options = opencl.BUILD_OPTIONS
    with ab_kernels.versions_of(root, options=("-DEB_QUEUE_SIZE=2",)) as versions:
        lines = ab_kernels.compare("gerris", versions, ["volume", "surfaces"], ["volume"], 1, 24,
                                   tmp_path)
        assert all(v.opencl._PROGRAMS for v in versions.values())
        assert versions["base"].opencl is not opencl
        assert opencl.BUILD_OPTIONS == (*options, "-DEB_QUEUE_SIZE=2")
    assert len(lines) == 2 and "base / this" in lines[0]
    for line in lines:
        assert "max abs diff image 0.00e+00, probe 0.00e+00" in line
        assert float(line.split("mean alpha ")[1].split(",")[0]) > 0
    assert opencl.BUILD_OPTIONS == options and ab_kernels.BASE_NAME not in sys.modules


# ptxas's report through -cl-nv-verbose, as NVIDIA's OpenCL driver (580.159.04) wrote
# it for the one-sample volume variant on an H200 (2026-12-04).
NVIDIA_LOG = """(): Warning: Function eb_render is a kernel, so overriding noinline attribute.
ptxas info    : 0 bytes gmem
ptxas info    : Compiling entry function 'eb_probe' for 'sm_90a'
ptxas info    : Function properties for eb_probe
ptxas         .     264 bytes stack frame, 0 bytes spill stores, 0 bytes spill loads
ptxas info    : Used 38 registers, used 0 barriers
ptxas info    : Compile time = 36.837 ms
ptxas info    : Compiling entry function 'eb_render' for 'sm_90a'
ptxas info    : Function properties for eb_render
ptxas         .     1648 bytes stack frame, 0 bytes spill stores, 0 bytes spill loads
ptxas info    : Used 126 registers, used 0 barriers
ptxas info    : Compile time = 1294.676 ms
"""


def test_kernel_resources_reads_each_kernels_lines_of_the_driver_log():
    assert kernel_resources.report_of(NVIDIA_LOG, "eb_render") == [
        "1648 bytes stack frame, 0 bytes spill stores, 0 bytes spill loads",
        "Used 126 registers, used 0 barriers", "Compile time = 1294.676 ms"]
    assert kernel_resources.report_of(NVIDIA_LOG, "eb_probe")[1] == \
        "Used 38 registers, used 0 barriers"
    assert kernel_resources.report_of("", "eb_render") == []


@pytest.mark.parametrize("device", DEVICES)
def test_kernel_resources_builds_every_variant(device, capsys):
    assert kernel_resources.main(["--device", device]) == 0
    out = capsys.readouterr().out
    rows = [l for l in out.splitlines() if l.startswith("| ")][1:]
    assert [r.split(" | ")[0][2:] for r in rows] == [v[0] for v in kernel_resources.VARIANTS]
    for row in rows:
        private, local, group, multiple = (int(x) for x in row.split(" | ")[1:5])
        assert private >= 0 and local >= 0 and group >= 1 and multiple >= 1
    # no variant builds with a compiler warning (kernel_resources prints them); a
    # warning on stderr fails the MPI runs' clean-stderr checks
    assert "warning" not in out.lower(), out
