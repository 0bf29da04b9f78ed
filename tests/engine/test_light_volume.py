"""The shadow integrator's cached transmittance toward the light (`--shadow-rays
cached`, the default: exabricks.engine.light_volume, kernels/light_volume.cl)
against the shadow rays it replaces (`--shadow-rays traced`) on real data, its
layout, and its life: made once per light, transfer function and dataset, and
read by every frame until one of them changes. The closed forms and the float64
reference of tests/engine/test_shadows.py run on the default, the cache."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from exabricks import schema
from exabricks.engine import light_volume
from exabricks.engine.renderer import Renderer
from exabricks.scene import Clip
from exabricks.util.errors import ExabricksError

from helpers import AMREX, ATHENA, ENZO, GERRIS, device_param

# RMSE of premultiplied RGBA, cached against traced (issue 62; measured 1e-4 to 1.3e-3
# at 512², docs/benchmarks-render.md "Shadow integrator")
TOLERANCE = 2e-3
DATASETS = {"gerris": (GERRIS, "T"), "amrex": (AMREX, "phi"), "athena": (ATHENA, "rho"),
            "enzo": (ENZO, "Density")}


def renderer_and_scene(name: str, size: int, device, **options):
    """An engine Renderer of a shared dataset and its default scene under the shadow
    integrator, as `exabricks render SOURCE --integrator shadow` draws it."""
    import exabricks as eb

    path, field = DATASETS[name]
    ds = eb.open(path, fields=[field], cache=False, **({"format": "yt"} if name == "enzo" else {}))
    scene = eb.Renderer(ds, device=device).scene(field=field, size=(size, size), integrator="shadow",
                                                  **options)
    return Renderer(*ds.structures(), fields=(field,), device=device), scene


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def cached_against_traced(name: str, size: int, device) -> tuple[float, float]:
    """(RMSE of the cached frame against the traced one, RMSE of the traced frame
    against the unshadowed one: how much the shadows show)."""
    renderer, scene = renderer_and_scene(name, size, device)
    cached = renderer.integrate(scene)
    assert cached.stats["shadow_rays"] == "cached" and cached.stats["light_volume"]["built"]
    lighting = scene.lighting
    traced = renderer.integrate(scene.replace(lighting=replace(lighting, shadow_rays="traced")))
    assert traced.stats["shadow_rays"] == "traced" and "light_volume" not in traced.stats
    unlit = renderer.integrate(scene.replace(lighting=replace(
        lighting, light_intensity=0.0, ambient=lighting.ambient + lighting.light_intensity)))
    return rmse(cached.rgba, traced.rgba), rmse(traced.rgba, unlit.rgba)


@device_param
def test_cached_shadows_are_the_traced_ones_on_the_plume(device):
    error, shadows = cached_against_traced("gerris", 64, device)
    assert error <= TOLERANCE and shadows > 5 * TOLERANCE, (error, shadows)


@pytest.mark.slow
@device_param
@pytest.mark.parametrize("name", ["amrex", "athena", "enzo"])
def test_cached_shadows_are_the_traced_ones_on_real_data(device, name):
    error, shadows = cached_against_traced(name, 128, device)
    assert error <= TOLERANCE and shadows > 2 * TOLERANCE, (error, shadows)


@device_param
def test_the_cache_is_made_once_per_light_transfer_function_and_clipping(device):
    """Under a light fixed in world space, the camera, the size, the samples per pixel
    and the seed reuse it; the light, the transfer function and clipping make it
    anew; a reused cache draws what a new one draws. (The default key light turns
    with the camera, and so makes it anew at every camera.)"""
    renderer, scene = renderer_and_scene("gerris", 24, device, light=(-0.5, 0.7, 0.6))

    def built(s):
        return renderer.integrate(s).stats["light_volume"]["built"]

    assert built(scene)
    c = scene.camera
    moved = scene.replace(camera=replace(c, position=tuple(np.add(c.position, (3.0, -2.0, 1.0)))))
    assert not built(moved)
    assert not built(scene.replace(settings=replace(scene.settings, width=32, height=16, spp=2, seed=7)))
    reused = renderer.integrate(moved).rgba
    assert built(scene.replace(lighting=replace(scene.lighting, light=(0.0, 1.0, 0.2))))
    renderer.light_cache.volume = None  # made anew for the same light
    np.testing.assert_array_equal(renderer.integrate(moved).rgba, reused)
    volume = scene.volumes[0]
    tf = volume.transfer_function
    fainter = replace(tf, alpha_points=tf.alpha_points * np.array([1.0, 0.5]))
    assert built(scene.replace(volumes=(replace(volume, transfer_function=fainter),)))
    assert built(scene.replace(clip=Clip(planes=(((64.0, 0.0, 0.0), (1.0, 0.0, 0.0)),))))


@pytest.mark.parametrize("light", [(0.0, 0.0, 1.0), (-0.46, 0.68, 0.57), (1.0, 1e-7, 0.0)])
def test_the_volume_covers_the_box_as_the_light_sees_it(light):
    """Every corner of the box lies inside the nodes, the light's side at depth 0; the
    node spacing is a quarter of the finest cell where that fits, else the nodes fill
    MAX_NODES."""
    lower, upper = np.array([1.0, -2.0, 0.5]), np.array([9.0, 4.0, 3.5])
    for finest, max_nodes in ((0.5, light_volume.MAX_NODES), (0.001, 50_000)):
        p = light_volume.geometry(lower, upper, light, finest, max_nodes)
        dims = np.array(p["light_dims"][:3])
        assert np.prod(dims) <= max_nodes and p["light_dims"][3] == 1
        origin, inv = np.array(p["light_origin"][:3]), np.array([p["light_u"][3], p["light_v"][3],
                                                                  p["light_origin"][3]])
        axes = np.array([p["light_u"][:3], p["light_v"][:3], -np.asarray(light) / np.linalg.norm(light)])
        np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
        corners = np.array([[(lower, upper)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
        at = (corners - origin) @ axes.T * inv
        assert np.all(at >= -1e-9) and np.all(at <= dims - 1 + 1e-9)
        assert np.isclose(at[:, 2].min(), 0.0, atol=1e-9)
        if finest == 0.5:
            np.testing.assert_allclose(1.0 / inv, finest / light_volume.NODES_PER_CELL, rtol=0.3)
        else:
            assert np.prod(dims) > 0.8 * max_nodes


# -- domains: a memory budget's, MPI data mode's (tests/engine/test_mpi.py) -------------

# RMSE of the frames / their maximum: the domains' sum of optical depths against the
# whole's, where the march of each stops on its own past T = 10^-3 (measured 2.5e-8
# to 2.6e-5 at 128²).
DOMAIN_TOLERANCE = 1e-4


@device_param
@pytest.mark.slow  # 15 s a dataset on 2 cores: each of 15-21 domains read and its part added
@pytest.mark.parametrize("name", ["gerris", "amrex", "athena", "enzo"])
def test_the_domains_of_a_budget_add_up_to_the_whole_datasets_light(device, name):
    """Under a memory budget of at least 8 domains, every domain adds its part to one
    volume over the regions that the frame shows, and the frame is the in-memory one
    with a volume of the same size (the budget's share: light_bytes)."""
    from exabricks.engine.streaming import Budgeted, render_steps
    from helpers.streaming import budget_for

    whole, scene = renderer_and_scene(name, 48, device)
    bricks, regions = whole.dataset.bricks, whole.dataset.regions
    domains = Budgeted(bricks, regions, scene, budget_for(name, scene, 8), device=device)
    assert domains.n_domains >= 8
    got = render_steps(domains, scene)
    assert got.stats["light_volume"]["bytes"] <= domains.light_bytes
    same_size = Renderer(bricks, regions, whole.dataset.bvh, fields=whole.dataset.fields, device=device,
                         light=light_volume.Cache(max_bytes=domains.light_bytes))
    reference = same_size.render_scene(scene)
    assert reference.stats["light_volume"]["nodes"] == got.stats["light_volume"]["nodes"]
    assert rmse(got.rgba, reference.rgba) <= DOMAIN_TOLERANCE * reference.rgba.max()
    reads = domains.reads
    again = render_steps(domains, scene)  # the same light: no domain adds its part again
    assert not again.stats["light_volume"]["built"] and domains.reads - reads <= domains.n_domains
    np.testing.assert_array_equal(again.rgba, got.rgba)


def mirrored_cells(cells):
    """`cells` and their mirror image across the upper x face of their box, in one set."""
    width = 1 << cells.level.astype(np.int64)
    face = int((cells.lower_lattice[:, 0] + width).max())
    lower = cells.lower_lattice.copy()
    lower[:, 0] = 2 * face - lower[:, 0] - width
    return replace(cells, lower_lattice=np.concatenate([cells.lower_lattice, lower]),
                   level=np.concatenate([cells.level, cells.level]),
                   values=np.concatenate([cells.values, cells.values], axis=1)), face


@device_param
def test_a_mirrored_copy_shadows_the_data_as_a_dataset_holding_both(device):
    """`--mirror`: each copy adds the optical depths of its own to one volume in world
    space, read in each copy's object space; lit from the copy's side, the frame is
    the frame of one dataset that holds the data and its mirror image (measured
    1.7e-5; each copy shadowing itself alone, 2.0e-3). A traced shadow ray would see
    its own copy only: refused."""
    from exabricks.readers import read
    from exabricks.scene.model import Instance

    from helpers import build

    cells = read(GERRIS, fields=["T"])
    both, face = mirrored_cells(cells)
    plane = float(cells.origin_world[0] + cells.spacing_world[0] * face)
    one, two = build(cells), build(both)
    whole, scene = renderer_and_scene("gerris", 64, device, light=(1.0, 0.05, 0.1))
    lo, hi = (np.asarray(b, np.float64) for b in schema.world_bounds(two.bricks))
    centre, size = (lo + hi) / 2, float((hi - lo).max())
    camera = replace(scene.camera, position=tuple(centre + size * np.array([0.3, -1.6, 0.7])),
                     look_at=tuple(centre))
    scene = scene.replace(camera=camera)
    data = Renderer(one.bricks, one.regions, one.bvh, fields=("T",), device=device)
    mirrored = data.integrate(scene.replace(instances=(Instance(mirror=("x", plane)),)))
    assert mirrored.stats["instances"] == 2
    doubled = Renderer(two.bricks, two.regions, two.bvh, fields=("T",), device=device)
    want = doubled.integrate(scene)
    error = rmse(mirrored.rgba, want.rgba)
    unlit = doubled.integrate(scene.replace(lighting=replace(
        scene.lighting, light_intensity=0.0, ambient=scene.lighting.ambient + scene.lighting.light_intensity)))
    assert error <= 1e-4 and rmse(want.rgba, unlit.rgba) > 100 * error, (error, rmse(want.rgba, unlit.rgba))
    with pytest.raises(ExabricksError, match="a shadow ray does not cross instances"):
        data.integrate(scene.replace(instances=(Instance(mirror=("x", plane)),), lighting=replace(
            scene.lighting, shadow_rays="traced")))
