"""The path integrator (kernels/path.cl, exabricks/engine/majorants.py) against closed
forms and the float64 reference, by statistics over independent frames.

A Monte Carlo frame is right when its mean is the expected value. Each test draws
K frames of independent seeds; per pixel, their mean and its standard error give
z = (mean - expected) / error, and over the pixels z must look like a standard
normal: mean z^2 within the chi-square bounds of the pixel count, no |z| beyond
Z_MAX. Frames of spp > 1 spread their samples over the pixel, so the closed forms
are averaged over the pixel too (`pixel_mean`).

On the slab of tests/helpers/slab.py (constant extinction sigma, thickness H, a
ray through it of length L = H / |d_z|):

* opacity: the sample's alpha is 1 at a real collision, so its mean is 1 - e^{-sigma L};
* single scattering under a light straight above (one bounce, no environment): the
  shadow integrator's closed form (tests/engine/test_shadows.py) times the
  Henyey-Greenstein phase at cos = d_z (scaled by 4 pi: 1 for g = 0);
* white furnace: a medium of albedo 1 in a uniform environment of radiance A and no
  other light, with unbounded scattering, is in equilibrium: every path that
  meets it carries A out, so the colour is A times the opacity, exactly, whatever
  the medium. That holds on real data too, with white surfaces in it
  (test_real_data_free_paths_have_the_opacity_and_conserve_energy,
  test_white_surfaces_in_a_white_medium_conserve_energy);
* a slice of opacity a through the middle of the slab, lit from above: the slab's
  upper half, the slice met with probability a (its colour times the light through
  the medium above it, from light_dir.w off the surface), and with probability
  1 - a the lower half, whose light crosses the slice ((1 - a) more)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from exabricks.engine import majorants
from exabricks.engine.renderer import Renderer
from exabricks.picture.transfer_function import TransferFunction
from exabricks.scene import IsoSurface, Lighting, Scene, Settings, Slice, VolumeLayer
from exabricks.scene.modes import MAX_BOUNCES
from exabricks.util.errors import ExabricksError

from helpers import GERRIS, build, device_param
from helpers.slab import (SLAB_CELLS, SLAB_ORIGIN, SLAB_RGB, SLAB_SPACING, SLAB_VALUE, slab,
                          slab_camera)

W, H = 24, 16
A0 = 0.3  # the slab's opacity per unit distance (its finest cell width)
SIGMA = -np.log(1.0 - A0) / SLAB_SPACING
THICKNESS = SLAB_SPACING * (SLAB_CELLS[2] + 1)
Z_MAX = 5.5  # no pixel's |z| beyond this (a chance of 4e-8 per pixel for a normal)


def z_scores(frames: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """Per value of (K, ...) independent frames: (mean - expected) / standard error."""
    k = frames.shape[0]
    error = frames.std(axis=0, ddof=1) / np.sqrt(k)
    return (frames.mean(axis=0) - expected) / np.maximum(error, 1e-12)


def assert_normal(z: np.ndarray) -> None:
    """z of n values looks standard normal: mean z^2 within 6 standard deviations of
    chi-square/n (sqrt(2/n)), allowing for the error of the standard errors themselves
    (the frames' own scatter), and no |z| above Z_MAX."""
    z = z.ravel()
    spread = 6.0 * np.sqrt(2.0 / z.size)
    assert abs(np.mean(z ** 2) - 1.0) < spread + 0.15, (np.mean(z ** 2), spread)
    assert np.max(np.abs(z)) < Z_MAX, np.max(np.abs(z))


def frames(renderer, scene, k: int) -> np.ndarray:
    """K frames of `scene` with seeds 0 .. K - 1: (K, H, W, 4) float64."""
    return np.stack([renderer.render_scene(scene.replace(settings=replace(scene.settings, seed=seed))).rgba
                     for seed in range(k)]).astype(np.float64)


def pixel_mean(function, camera, width=W, height=H, n=6) -> np.ndarray:
    """The mean over each pixel (an n x n grid of sub-pixel rays) of function(directions)."""
    total = 0.0
    for jy in (np.arange(n) + 0.5) / n:
        for jx in (np.arange(n) + 0.5) / n:
            _, directions = camera.rays(width, height, jitter=(jx, jy))
            total = total + function(directions)
    return total / n ** 2


def slab_path(tf_rgb=SLAB_RGB, spp=64, **lighting) -> Scene:
    tf = TransferFunction(np.array([[SLAB_VALUE, *tf_rgb]]), np.array([[SLAB_VALUE, A0]]), "constant")
    return Scene(camera=slab_camera(), volumes=(VolumeLayer("density", tf),),
                 lighting=Lighting(integrator="path", **lighting),
                 settings=Settings(width=W, height=H, spp=spp))


def slab_opacity(d):
    return 1.0 - np.exp(-SIGMA * THICKNESS / np.abs(d[..., 2]))


def phase(c, g):
    return (1.0 - g * g) / (1.0 + g * g - 2.0 * g * c) ** 1.5


@device_param
@pytest.mark.parametrize("g", [0.0, 0.6, -0.4])
def test_single_scattering_in_a_slab_lit_from_above_is_the_closed_form(device, g):
    built = slab()
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device)
    intensity = 0.8
    scene = slab_path(light=(0.0, 0.0, 1.0), light_intensity=intensity, ambient=0.0, bounces=1,
                      anisotropy=g)
    got = frames(renderer, scene, 16)

    def colour(d):
        dz = np.abs(d[..., 2])
        length = THICKNESS / dz
        lit = intensity * phase(-dz, g) * (1.0 - np.exp(-SIGMA * length * (1.0 + dz))) / (1.0 + dz)
        return lit[..., None] * np.array(SLAB_RGB)

    camera = slab_camera()
    assert_normal(z_scores(got[..., :3], pixel_mean(colour, camera)))
    assert_normal(z_scores(got[..., 3], pixel_mean(slab_opacity, camera)))


@device_param
def test_a_white_furnace_slab_gives_the_environment_times_the_opacity(device):
    """Multiple scattering, all the bounces a path may take, Russian roulette and the
    environment: with albedo 1 the colour is A (1 - e^{-sigma L})."""
    built = slab()
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device)
    ambient = 0.5
    scene = slab_path(tf_rgb=(1.0, 1.0, 1.0), light_intensity=0.0, ambient=ambient,
                      bounces=MAX_BOUNCES, anisotropy=0.3)
    got = frames(renderer, scene, 16)
    want = ambient * pixel_mean(slab_opacity, slab_camera())
    for channel in range(3):
        assert_normal(z_scores(got[..., channel], want))
    assert_normal(z_scores(got[..., 3], want / ambient))


@device_param
@pytest.mark.parametrize("a", [1.0, 0.4])
def test_a_slice_in_a_slab_lit_from_above_is_the_closed_form(device, a):
    """Surfaces under the path integrator (kernels/path_surfaces.cl): met with
    probability a, lit through the medium above them, and crossed by the light of
    what lies below; one scattering event, no environment."""
    from exabricks.picture.light import SHADOW_BIAS_CELLS

    built = slab()
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device)
    intensity, rgb = 0.8, np.array([0.9, 0.5, 0.1])
    z = SLAB_ORIGIN[2] + 2.0 * SLAB_SPACING  # the middle of the support's 5 cells
    upper = lower = 2.5 * SLAB_SPACING
    bias = SHADOW_BIAS_CELLS * SLAB_SPACING
    colormap = TransferFunction(np.array([[SLAB_VALUE, *rgb]]), np.array([[SLAB_VALUE, 1.0]]), "slice")
    scene = slab_path(light=(0.0, 0.0, 1.0), light_intensity=intensity, ambient=0.0, bounces=1)
    scene = scene.replace(slices=(Slice((0.0, 0.0, z), (0.0, 0.0, 1.0), "density", colormap, a),))
    # 32 frames: the slice's share is a coin toss (met or not) of a large value, whose
    # standard errors from 16 frames have tails too heavy for Z_MAX
    got = frames(renderer, scene, 32)

    def colour(d):
        dz = np.abs(d[..., 2])[..., None]
        l1, l2 = upper / dz, lower / dz
        above = np.array(SLAB_RGB) * intensity * -np.expm1(-SIGMA * l1 * (1.0 + dz)) / (1.0 + dz)
        met = a * rgb * intensity * np.exp(-SIGMA * (upper - bias))
        below = ((1.0 - a) ** 2 * np.array(SLAB_RGB) * intensity * np.exp(-SIGMA * upper)
                 * -np.expm1(-SIGMA * l2 * (1.0 + dz)) / (1.0 + dz))
        return above + np.exp(-SIGMA * l1) * (met + below)

    def opacity(d):
        return 1.0 - (1.0 - a) * np.exp(-SIGMA * (upper + lower) / np.abs(d[..., 2]))

    camera = slab_camera()
    assert_normal(z_scores(got[..., :3], pixel_mean(colour, camera)))
    if a < 1.0:
        assert_normal(z_scores(got[..., 3], pixel_mean(opacity, camera)))
    else:
        assert np.all(got[..., 3] == 1.0)


@device_param
def test_real_data_free_paths_have_the_opacity_and_conserve_energy(device):
    """The Gerris plume's hot core under a white transfer function in a uniform
    environment (radiance A, no other light), tracked through the heterogeneous
    majorant grid with null collisions:

    * the free paths are unbiased: the mean alpha of independent 1-spp frames is the
      opacity the headlight integrator integrates at 16 samples a finest cell;
    * energy is conserved through every bounce: a path of albedo 1 that meets the
      medium scatters until it leaves with A (no Russian roulette at throughput 1),
      so each frame's colour is A times its alpha, pixel for pixel. The medium is
      thin enough (opacity 0.6 per 4 cells at most) that paths leave well within
      MAX_BOUNCES events."""
    from helpers.plume_core import plume_core

    core = plume_core()
    built, camera = core.built, core.camera
    tf = TransferFunction(np.array([[0.01, 1.0, 1.0, 1.0], [0.5, 1.0, 1.0, 1.0]]),
                          np.array([[0.01, 0.0], [0.5, 0.6]]), "white ramp")
    ambient = 0.7
    settings = Settings(width=16, height=16, unit_distance=core.unit)
    scene = Scene(camera=camera, volumes=(VolumeLayer("T", tf),),
                  lighting=Lighting(integrator="path", light_intensity=0.0, ambient=ambient,
                                    bounces=MAX_BOUNCES, anisotropy=-0.2), settings=settings)
    renderer = Renderer(built.bricks, built.regions, built.bvh, field="T", device=device)
    got = frames(renderer, scene, 256)
    opacity = renderer.render_scene(scene.replace(
        lighting=Lighting(shading="none"),
        settings=replace(settings, sampling_rate=16.0, jitter=False, max_opacity=1.0))).rgba[..., 3]
    seen = opacity > 0.1  # so that no pixel misses the medium in all 256 frames (< 1e-11)
    assert seen.sum() > 60
    assert_normal(z_scores(got[..., 3], opacity)[seen])
    np.testing.assert_allclose(got[..., :3], ambient * got[..., 3:4] * np.ones(3), rtol=1e-5, atol=1e-6)
    collisions = renderer.render_scene(scene).stats["collisions"]
    assert collisions["null"] > 0 and collisions["real"] > 0


@device_param
def test_white_surfaces_in_a_white_medium_conserve_energy(device):
    """The plume's core in its white medium with two white iso-surfaces in it, one
    opaque and one of opacity 0.5, and a white slice of opacity 0.3 across it,
    under a uniform environment: paths reflect off the surfaces, pass through them
    and scatter in the medium, and every one that meets anything leaves with A, so
    each frame's colour is A times its alpha, pixel for pixel."""
    from helpers.plume_core import plume_core

    core = plume_core()
    built, camera = core.built, core.camera
    white = TransferFunction(np.array([[0.01, 1.0, 1.0, 1.0], [0.5, 1.0, 1.0, 1.0]]),
                             np.array([[0.01, 0.0], [0.5, 0.3]]), "white ramp")
    centre = tuple(np.asarray(camera.look_at, float))
    ambient = 0.7
    scene = Scene(camera=camera, volumes=(VolumeLayer("T", white),),
                  isosurfaces=(IsoSurface("T", 0.3, (1.0, 1.0, 1.0), 1.0),
                               IsoSurface("T", 0.12, (1.0, 1.0, 1.0), 0.5)),
                  slices=(Slice(centre, (1.0, 0.2, 0.1), "T", white, 0.3),),
                  lighting=Lighting(integrator="path", light_intensity=0.0, ambient=ambient,
                                    bounces=MAX_BOUNCES),
                  settings=Settings(width=16, height=16, unit_distance=core.unit))
    renderer = Renderer(built.bricks, built.regions, built.bvh, field="T", device=device)
    got = frames(renderer, scene, 8)
    assert (got[..., 3] == 1.0).sum() > 200 and (got[..., 3] == 0.0).sum() > 0
    np.testing.assert_allclose(got[..., :3], ambient * got[..., 3:4] * np.ones(3), rtol=1e-5, atol=1e-6)


@device_param
def test_iso_crossings_are_searched_only_where_the_range_brackets_them(device, monkeypatch):
    """A path looks for iso crossings only in the regions whose value range brackets
    an iso-value (the SEEN_ISO bit). Searching every region the volume shows finds
    the same surfaces: the frames agree but for the bisection of a crossing whose
    bracket now closes at a region's exit (the same random numbers either way)."""
    from helpers.plume_core import plume_core
    from exabricks.engine import device_data

    core = plume_core()
    ramp = TransferFunction(np.array([[0.01, 0.9, 0.6, 0.3], [0.5, 1.0, 1.0, 1.0]]),
                            np.array([[0.01, 0.0], [0.5, 0.2]]), "ramp")
    scene = Scene(camera=core.camera, volumes=(VolumeLayer("T", ramp),),
                  isosurfaces=(IsoSurface("T", 0.3, (0.9, 0.9, 0.9), 1.0),),
                  lighting=Lighting(integrator="path", light_intensity=1.0, ambient=0.3, bounces=4),
                  settings=Settings(width=24, height=24, unit_distance=core.unit, spp=2))
    renderer = Renderer(core.built.bricks, core.built.regions, core.built.bvh, field="T", device=device)
    _, regions = renderer.dataset.visibility([("T", ramp)], [("T", 0.3)])
    assert 0 < np.count_nonzero(regions & device_data.SEEN_ISO) < np.count_nonzero(regions)
    skipping = renderer.render_scene(scene).rgba
    seen, every = device_data.DeviceDataset.visibility, device_data.SEEN_VOLUME | device_data.SEEN_ISO
    monkeypatch.setattr(device_data.DeviceDataset, "visibility",  # every region searched, as before
                        lambda self, layers=(), isovalues=(): tuple(np.where(v > 0, every, 0).astype(np.uint8)
                                                                    for v in seen(self, layers, isovalues)))
    searching = renderer.render_scene(scene).rgba
    assert skipping[..., 3].mean() > 0.05
    assert np.mean(np.all(skipping == searching, axis=-1)) > 0.99  # on PoCL: all of them
    assert np.abs(skipping - searching).max() < 1e-3


@device_param
def test_the_samples_of_a_frame_are_its_spp(device):
    """--spp, --progressive and --time-limit draw sample after sample: the frame of
    spp 4 is the mean of its four samples, each drawn alone (to float rounding)."""
    built = slab()
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device)
    scene = slab_path(spp=4, light=(0.3, 0.1, 1.0), bounces=4)
    whole = renderer.integrate(scene).rgba
    alone = np.mean([renderer.integrate(scene, sample=k).rgba for k in range(4)], axis=0)
    np.testing.assert_allclose(whole, alone, atol=2e-6)
    assert np.array_equal(whole, renderer.integrate(scene).rgba)  # the same for the same seed


def test_the_largest_alpha_over_a_range_is_the_brute_force_one():
    rng = np.random.default_rng(5)
    x = np.sort(rng.uniform(-3, 7, 40))
    tf = TransferFunction(np.column_stack([x, np.ones((40, 3))]),
                          np.column_stack([x, rng.uniform(0, 1, 40) ** 3]), "random")
    ranges = np.sort(rng.uniform(-5, 9, (500, 2)), axis=1).astype(np.float32)
    ranges[:20] = (np.inf, -np.inf)  # empty
    got = majorants.largest_alpha(tf, ranges)
    for (lo, hi), value in zip(ranges[20:], got[20:]):
        dense = np.concatenate([np.linspace(lo, hi, 2001), x[(x > lo) & (x < hi)]])
        want = tf.evaluate(dense)[:, 3].max()
        assert want <= value <= want + 1e-12, (lo, hi)
    assert np.all(got[:20] == 0.0)


@device_param
@pytest.mark.parametrize("reconstruction", ["basis", "nearest"])
def test_the_majorants_bound_the_medium_everywhere(device, reconstruction):
    """At 200,000 random points of the Gerris plume, the extinction of the reconstructed
    field (probe's values, the kernel's reconstruction) is at most its macrocell's
    majorant, for a transfer function with sharp peaks (the hardest to bound)."""
    from exabricks.readers import read

    built = build(read(GERRIS))
    renderer = Renderer(built.bricks, built.regions, built.bvh, field="T", device=device)
    tf = TransferFunction(np.array([[0.0, 1, 1, 1], [1.0, 1, 1, 1]]),
                          np.array([[0.0, 0.0], [0.01, 0.6], [0.02, 0.05], [0.2, 0.05], [0.21, 0.9],
                                    [0.22, 0.0], [1.0, 0.3]]), "peaks")
    scene = Scene(camera=slab_camera(), volumes=(VolumeLayer("T", tf),),
                  settings=Settings(reconstruction=reconstruction))
    unit = renderer.dataset.finest_width_world
    grid, mu = majorants.frame_majorants(scene, renderer.dataset, unit, {})
    rng = np.random.default_rng(1)
    upper = grid.lower + np.asarray(grid.dims) * grid.width
    lattice = rng.uniform(grid.lower, upper, (200_000, 3))
    world = built.bricks.origin_world + built.bricks.spacing_world * lattice
    values = renderer.dataset.probe_fields(world, reconstruction=reconstruction)[0]
    sigma = majorants.extinction(np.nan_to_num(tf.evaluate(values)[:, 3]), 1.0 / unit)
    cell = np.floor((lattice - grid.lower) / grid.width).astype(int)
    index = cell[:, 0] + grid.dims[0] * (cell[:, 1] + grid.dims[1] * cell[:, 2])
    assert np.all(sigma <= mu[index]), np.max(sigma - mu[index])
    assert np.count_nonzero(sigma > 0) > 1000


@device_param
def test_the_path_integrator_refuses_what_it_does_not_draw(device, tmp_path):
    import exabricks as eb

    ds = eb.open(GERRIS, cache=tmp_path / "cache")
    for options in ({"lod": 2.0}, {"reconstruction": "vertex"}):
        with pytest.raises(ExabricksError, match="--integrator path draws the basis or nearest"):
            eb.render(ds, integrator="path", size=(16, 16), device=device, **options)
    with pytest.raises(ExabricksError, match="--integrator path: .*--ao"):
        eb.render(ds, integrator="path", iso=(0.3,), ao_samples=4, size=(16, 16), device=device)
    with pytest.raises(ExabricksError, match="--integrator path: .*--mirror"):
        eb.render(ds, integrator="path", mirror=("x", 0.0), size=(16, 16), device=device)


# -- real data against the float64 reference (tests/reference.py, `light`) ------------

@pytest.mark.slow
@device_param
def test_single_scattering_on_real_data_is_the_float64_reference_and_converges(device):
    """The Gerris plume's hot core lit from the side (test_shadows.py's scene), one
    scattering event and no environment: the expected frame is the shadow
    integrator's float64 reference with ambient 0 (16 samples a finest cell along
    the camera ray, 8 toward the light, so its quadrature error is far below the
    Monte Carlo error here). 256 independent 1-spp frames (pixel centres, as the
    reference):

    * within their Monte Carlo error: per pixel z-scores of the colour look normal;
    * unbiased, converging as 1/sqrt(N): the mean squared error of the mean of N
      frames, over disjoint groups of N, falls as 1/N (slope of log RMSE against
      log N within 0.07 of -1/2, N = 1 .. 32)."""
    import reference
    from helpers.plume_core import plume_core

    core = plume_core()
    built, camera, tf, unit, light = core.built, core.camera, core.tf, core.unit, core.light
    size = 16
    scene = Scene(camera=camera, volumes=(VolumeLayer("T", tf),),
                  lighting=Lighting(integrator="path", light=light, ambient=0.0, light_intensity=0.8,
                                    bounces=1),
                  settings=Settings(width=size, height=size, unit_distance=unit))
    renderer = Renderer(built.bricks, built.regions, built.bvh, field="T", device=device)
    got = frames(renderer, scene, 256)
    direction = np.asarray(light) / np.linalg.norm(light)
    want = reference.integrate(built.cells, camera, tf, size, size, "T", steps_per_finest_cell=16,
                               unit_distance=unit, light=(direction, 0.0, (0.8, 0.8, 0.8)),
                               shadow_steps_per_finest_cell=8)
    seen = want[..., 3] > 0.1  # so that no pixel misses the medium in all 256 frames (< 1e-11)
    assert seen.sum() > 60
    assert_normal(z_scores(got[..., :3], want[..., :3])[seen])
    assert_normal(z_scores(got[..., 3], want[..., 3])[seen])
    ns = np.array([1, 2, 4, 8, 16, 32])
    rmse = [np.sqrt(np.mean([np.mean((group.mean(axis=0) - want)[seen] ** 2)
                             for group in got.reshape(256 // n, n, *got.shape[1:])])) for n in ns]
    slope = np.polyfit(np.log(ns), np.log(rmse), 1)[0]
    assert abs(slope + 0.5) < 0.07, (slope, rmse)
