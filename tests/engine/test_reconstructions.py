"""The nearest and vertex reconstructions (docs/design-rendering.md "Reconstructions: basis, nearest, vertex"),
checked against independent float64 answers from the leaf cells."""

from __future__ import annotations

import numpy as np
import pytest

from exabricks import schema
from exabricks.readers import read
from exabricks.scene import IsoSurface, Scene, Settings
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.engine.device_data import DeviceDataset
from exabricks.builders.regions import build_regions
from exabricks.engine.renderer import Renderer

from helpers import AMREX, GERRIS, built_scene, device_param, run_cli

DATASETS = [(GERRIS, "T"), (AMREX, "phi")]

# The kernels flush denormals to zero (-cl-denorms-are-zero, exabricks/device/opencl.py).
TINY = np.finfo(np.float32).tiny


def containing_cell_values(cells: schema.Cells, points_lattice: np.ndarray) -> np.ndarray:
    """float64 reference: the value of the leaf cell whose half-open box contains each
    point (NaN in holes and outside), by a per-level dictionary of cell indices."""
    out = np.full(points_lattice.shape[0], np.nan)
    for level in np.unique(cells.level):
        mine = np.flatnonzero(cells.level == level)
        index = {tuple(q): i for q, i in zip(cells.lower_lattice[mine] >> int(level), mine)}
        q = np.floor(points_lattice / float(1 << int(level))).astype(np.int64)
        for j, key in enumerate(map(tuple, q)):
            i = index.get(key)
            if i is not None:
                out[j] = cells.values[0, i]
    return out


def random_points(bricks, n, seed=0):
    lo, hi = (np.array(x) for x in schema.world_bounds(bricks))
    # float32-representable, since points travel to the device as float32
    return (lo + (hi - lo) * np.random.default_rng(seed).random((n, 3))).astype(np.float32)


@device_param
@pytest.mark.parametrize("path, field", DATASETS, ids=["gerris", "amrex"])
def test_nearest_is_the_containing_cell_value(path, field, device):
    bricks, regions, bvh, *_ = built_scene(path, field)
    cells = read(path, fields=[field])
    points = random_points(bricks, 4000)
    got = DeviceDataset(bricks, regions, bvh, field=field, device=device).probe_fields(points,
                       reconstruction="nearest")[0]
    lattice = (points.astype(np.float64) - cells.origin_world) / cells.spacing_world
    want = containing_cell_values(cells, lattice).astype(np.float32)
    want[np.abs(want) < TINY] = 0.0
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_array_equal(got[~np.isnan(got)], want[~np.isnan(want)])


def two_level_linear(a=(0.25, -0.5, 1.0), b=3.0):
    """A 24^3 box of level-1 cells whose central 8^3 (lattice [8, 16)) is refined to
    level 0, with values of the linear field a . centre + b."""
    lower, level = [], []
    for z in range(0, 24, 2):
        for y in range(0, 24, 2):
            for x in range(0, 24, 2):
                if all(8 <= c < 16 for c in (x, y, z)):
                    for dz in (0, 1):
                        for dy in (0, 1):
                            for dx in (0, 1):
                                lower.append((x + dx, y + dy, z + dz))
                                level.append(0)
                else:
                    lower.append((x, y, z))
                    level.append(1)
    lower = np.array(lower, np.int32)
    level = np.array(level, np.int8)
    centre = lower + 0.5 * (1 << level.astype(np.int64))[:, None]
    values = (centre @ np.array(a) + b).astype(np.float32)[None]
    cells = schema.Cells(fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                         meta={}, lower_lattice=lower, level=level, values=values)
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    return cells, bricks, regions, build_bvh(regions)


@device_param
def test_vertex_reproduces_a_linear_field_inside_one_level(device):
    a, b = np.array([0.25, -0.5, 1.0]), 3.0
    cells, bricks, regions, bvh = two_level_linear(tuple(a), b)
    scene = DeviceDataset(bricks, regions, bvh, device=device)
    rng = np.random.default_rng(1)
    # Where the basis field itself is linear at every vertex of the cell around the
    # point: no vertex within a hat of both levels (fine vertices 9..15; coarse
    # vertices outside 8..16 on some axis) and none on the data's edge (0, 24).
    fine = 9.0 + 6.0 * rng.random((2000, 3))
    coarse = 2.0 + 20.0 * rng.random((8000, 3))
    coarse = coarse[np.any((coarse < 6.0) | (coarse > 18.0), axis=1)]
    for points in (fine, coarse):
        got = scene.probe_fields(points, reconstruction="vertex")[0]
        np.testing.assert_allclose(got, points @ a + b, atol=2e-5, rtol=0)


@device_param
@pytest.mark.parametrize("path, field", DATASETS, ids=["gerris", "amrex"])
def test_vertex_is_continuous_across_level_boundaries(path, field, device):
    """Jumps of the field over 1e-3 of a finest cell, at points next to cell faces
    between levels: vertex stays within its gradient bound; nearest jumps."""
    bricks, regions, bvh, *_ = built_scene(path, field)
    cells = read(path, fields=[field])
    scene = DeviceDataset(bricks, regions, bvh, field=field, device=device)
    # Points on faces of coarse cells that touch finer cells: sample each coarse
    # cell's faces at random positions, keep those whose other side is finer.
    rng = np.random.default_rng(2)
    pick = rng.choice(cells.n_cells, min(cells.n_cells, 30000), replace=False)
    w = (1 << cells.level[pick].astype(np.int64)).astype(np.float64)[:, None]
    axis = rng.integers(0, 3, pick.size)
    face = cells.lower_lattice[pick] + rng.random((pick.size, 3)) * w
    face[np.arange(pick.size), axis] = cells.lower_lattice[pick, axis]
    step = np.zeros_like(face)
    step[np.arange(pick.size), axis] = 1e-3
    inside, outside = face + step, face - step
    level_out = containing_level(cells, outside)
    across = np.isfinite(level_out) & (level_out < cells.level[pick])
    assert across.sum() > 50
    to_world = lambda lattice: cells.origin_world + cells.spacing_world * lattice
    jumps = {}
    for recon in ("vertex", "nearest", "basis"):
        a = scene.probe_fields(to_world(inside[across]), reconstruction=recon)[0]
        b = scene.probe_fields(to_world(outside[across]), reconstruction=recon)[0]
        jumps[recon] = float(np.nanmax(np.abs(a - b)))
    span = float(np.ptp(cells.values[0]))
    # A continuous field changes by at most |gradient| * 2e-3 cells over the pair;
    # gradients here are below span per finest cell, so 1e-2 * span is generous,
    # while the cell values themselves differ by a good fraction of the span.
    assert jumps["vertex"] < 1e-2 * span, jumps
    assert jumps["basis"] < 1e-2 * span, jumps
    assert jumps["nearest"] > 10 * jumps["vertex"], jumps


def containing_level(cells, points_lattice):
    """Level of the leaf cell containing each point (NaN where none)."""
    out = np.full(points_lattice.shape[0], np.nan)
    for level in np.unique(cells.level):
        mine = np.flatnonzero(cells.level == level)
        keys = set(map(tuple, cells.lower_lattice[mine] >> int(level)))
        q = np.floor(points_lattice / float(1 << int(level))).astype(np.int64)
        hit = np.array([tuple(k) in keys for k in q])
        out[hit] = level
    return out


@device_param
@pytest.mark.parametrize("recon", ["nearest", "vertex"])
def test_every_reconstruction_renders_volumes_and_iso_surfaces(recon, device):
    bricks, regions, bvh, field, camera, tf = built_scene(GERRIS, "T")
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    basis = renderer.render(camera=camera, transfer_function=tf, width=48, height=48)
    other = renderer.render(camera=camera, transfer_function=tf, width=48, height=48,
                            reconstruction=recon)
    assert other.stats["reconstruction"] == recon
    # The same volume, reconstructed differently: close but not identical.
    alpha_b, alpha_o = basis.rgba[..., 3], other.rgba[..., 3]
    assert 0 < np.abs(alpha_b - alpha_o).max() < 0.2
    covered = {}
    for r in ("basis", recon):
        scene = Scene(camera=camera, isosurfaces=(IsoSurface(field, 0.3),),
                      settings=Settings(width=48, height=48, depth=True, reconstruction=r))
        hit = renderer.render_scene(scene)
        covered[r] = np.isfinite(hit.depth)
        assert np.all(hit.rgba[covered[r], 3] == pytest.approx(1.0))
    # The same surface, up to the reconstruction: its silhouettes nearly agree.
    assert covered["basis"].sum() > 10
    assert (covered["basis"] != covered[recon]).sum() <= 0.25 * covered["basis"].sum()


def test_probe_cli_takes_the_reconstruction(tmp_path):
    bricks, regions, bvh, *_ = built_scene(GERRIS, "T")
    paths = [tmp_path / n for n in ("b.npz", "r.npz", "v.npz")]
    regions = regions.replace(meta={"consistency": {"n_bricks": bricks.n_bricks,
                                                    "n_regions": regions.n_regions}})
    for p, obj in zip(paths, (bricks, regions, bvh)):
        schema.save(p, obj)
    points = tmp_path / "p.npy"
    np.save(points, random_points(bricks, 50))
    out = {}
    for recon in ("basis", "nearest", "vertex"):
        run_cli("probe", *paths, "--points", points, "--reconstruction", recon,
                "-o", tmp_path / f"{recon}.npy", check=0)
        out[recon] = np.load(tmp_path / f"{recon}.npy")
    assert not np.array_equal(out["basis"], out["nearest"])
    assert run_cli("probe", *paths, "--points", points, "--reconstruction", "cubic",
                   "-o", tmp_path / "x.npy").returncode == 2


def lod_scene(camera, field, tf, lod, size=96):
    from exabricks.scene import Lighting, VolumeLayer

    return Scene(camera=camera, volumes=(VolumeLayer(field, tf),), lighting=Lighting(shading="none"),
                 settings=Settings(width=size, height=size, lod=lod))


@device_param
def test_lod_zero_leaves_the_image_unchanged(device):
    bricks, regions, bvh, field, camera, tf = built_scene(AMREX, "phi")
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    plain = renderer.render(camera=camera, transfer_function=tf, width=96, height=96,
                            shading="none")
    zero = renderer.render_scene(lod_scene(camera, field, tf, 0.0))
    np.testing.assert_array_equal(plain.rgba, zero.rgba)
    assert "samples_per_level" not in zero.stats


@device_param
@pytest.mark.parametrize("path, field", DATASETS, ids=["gerris", "amrex"])
def test_lod_samples_coarse_levels_only(path, field, device):
    """At a large pixel threshold every sample is taken at a coarse level (counted per
    level by the kernel)."""
    bricks, regions, bvh, field, camera, tf = built_scene(path, field)
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    full = renderer.render_scene(lod_scene(camera, field, tf, 0.0))
    size = 96
    # A finest cell's size in pixels at the nearest data (camera to the bounds).
    lo, hi = (np.array(x) for x in schema.world_bounds(bricks))
    nearest_t = np.linalg.norm(np.clip(camera.position, lo, hi) - np.array(camera.position))
    pixel = 2 * np.tan(np.radians(camera.fovy) / 2) / size * max(nearest_t, 1e-9)
    cell_pixels = float(bricks.spacing_world.min() * 2.0 ** int(bricks.level.min()) / pixel)
    coarse = 2 + int(bricks.level.min())  # the lowest level a threshold of 8 cells allows
    coarse_frame = renderer.render_scene(lod_scene(camera, field, tf, 8.0 * cell_pixels))
    levels = {int(k): v for k, v in coarse_frame.stats["samples_per_level"].items()}
    assert min(levels) >= coarse, levels
    assert sum(levels.values()) == coarse_frame.stats["samples"]
    assert coarse_frame.stats["samples"] < full.stats["samples"]


@device_param
def test_lod_keeps_the_opacity_of_a_constant_field(device):
    """Per-level opacity correction (Kähler & Hege): the step grows with the level
    used and the opacity of each step with it, so a constant field (whose coarse
    averages are the same constant) renders the same picture at any LOD."""
    from exabricks.picture.camera import default_camera
    from exabricks.picture.transfer_function import TransferFunction

    cells, bricks, regions, bvh = two_level_linear(a=(0.0, 0.0, 0.0), b=0.5)
    camera = default_camera(np.zeros(3), np.full(3, 24.0))
    tf = TransferFunction.from_colormap("viridis", (0.0, 1.0), opacity=(0.05, 0.05))
    renderer = Renderer(bricks, regions, bvh, device=device)
    full = renderer.render_scene(lod_scene(camera, "v", tf, 0.0, size=48))
    coarse = renderer.render_scene(lod_scene(camera, "v", tf, 50.0, size=48))
    assert min(int(k) for k in coarse.stats["samples_per_level"]) >= 1
    assert coarse.stats["samples"] < full.stats["samples"]
    # float32 opacity correction of steps twice as long: agreement to ~1e-5
    np.testing.assert_allclose(coarse.rgba, full.rgba, atol=2e-5)


@device_param
def test_lod_refuses_other_reconstructions(device):
    from exabricks.util.errors import ExabricksError

    bricks, regions, bvh, field, camera, tf = built_scene(GERRIS, "T")
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    scene = lod_scene(camera, field, tf, 2.0)
    scene = scene.replace(settings=Settings(width=8, height=8, lod=2.0, reconstruction="nearest"))
    with pytest.raises(ExabricksError, match="level of detail"):
        renderer.render_scene(scene)


def vertex_reference(cells: schema.Cells, points_lattice: np.ndarray, field: int = 1):
    """float64 reference of the vertex reconstruction, written from its definition
    (docs/design.md) and independent of exabricks.engine.vertex: the value at a
    point is the trilinear interpolation of its leaf cell's corner values, and a
    corner's value, seen from a cell of level l, is the trilinear value in the
    coarsest leaf cell of a coarser level whose closed box contains it (recursively,
    from that cell's own corners), else the basis field (tests/reference.py) there."""
    import functools

    import reference

    by_level = {}
    for i, (q, l) in enumerate(zip(cells.lower_lattice, cells.level)):
        by_level.setdefault(int(l), {})[tuple(int(c) >> int(l) for c in q)] = i
    levels = sorted(by_level, reverse=True)

    def trilinear(i, p):
        l = int(cells.level[i])
        w = float(1 << l)
        lo = cells.lower_lattice[i].astype(np.int64)
        f = (np.asarray(p, float) - lo) / w
        out = 0.0
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    weight = ((f[0] if dx else 1 - f[0]) * (f[1] if dy else 1 - f[1])
                              * (f[2] if dz else 1 - f[2]))
                    if weight:
                        corner = tuple(int(c) for c in lo + (1 << l) * np.array([dx, dy, dz]))
                        out += weight * corner_value(corner, l)
        return out

    @functools.lru_cache(maxsize=None)
    def corner_value(corner, l):
        for L in levels:  # coarsest first
            if L <= l:
                break
            w = 1 << L
            ranges = [[(c >> L) - d for d in ((0, 1) if c % w == 0 else (0,))] for c in corner]
            for qx in ranges[0]:
                for qy in ranges[1]:
                    for qz in ranges[2]:
                        i = by_level[L].get((qx, qy, qz))
                        if i is not None:
                            return trilinear(i, corner)
        basis = reference.reconstruct(cells, np.array([corner], float), cells.fields[field])
        return float(basis[0])

    out = np.full(points_lattice.shape[0], np.nan)
    for j, p in enumerate(points_lattice):
        for L in levels:
            i = by_level[L].get(tuple(int(np.floor(c / (1 << L))) for c in p))
            if i is not None:
                out[j] = trilinear(i, p)
                break
    return out


@device_param
def test_vertex_equals_its_float64_reference_on_a_random_hierarchy(device):
    """Three levels with holes and level jumps of two, random values."""
    from amr_strategies import make_cells, refine_octree

    rng = np.random.default_rng(7)
    lower, level = refine_octree(rng, root_level=3, root_grid=(3, 3, 2), root_fill=1.0,
                                 refine=0.5, hole=0.05, clustered=False, base_depth=0,
                                 max_cells=900, offset=(0, 0, 0))
    cells = make_cells(lower, level, rng)
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    bvh = build_bvh(regions)
    scene = DeviceDataset(bricks, regions, bvh, field="noise", device=device)
    lo, hi = (np.array(x) for x in schema.world_bounds(bricks))
    points = (lo + (hi - lo) * rng.random((600, 3))).astype(np.float32).astype(np.float64)
    got = scene.probe_fields(points, reconstruction="vertex")[0]
    want = vertex_reference(cells, points)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    assert ok.sum() > 300 and len(np.unique(cells.level)) >= 3
    # float32 basis corner values (relative 1e-6 of the noise's range) and float32
    # trilinear weights: agreement to 1e-5 of the values' scale.
    np.testing.assert_allclose(got[ok], want[ok], atol=1e-5 * np.abs(cells.values[1]).max())
