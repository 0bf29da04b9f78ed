"""The shadow integrator (kernels/light.cl, exabricks/picture/light.py) against closed
forms: a slab of constant extinction sigma seen from above, lit by a directional
light straight above or straight below it.

A ray that crosses the slab's thickness H along a path of length L = H / |d_z|
meets at depth u (along the ray) the light A + I T(u), with T the transmittance
toward the light: exp(-sigma u |d_z|) from above, exp(-sigma (H - u |d_z|)) from
below. Its colour (premultiplied) is c sigma times the integral of
exp(-sigma u) (A + I T(u)) over [0, L]:

    above: c A (1 - e^{-sigma L}) + c I (1 - e^{-sigma L (1 + |d_z|)}) / (1 + |d_z|)
    below: c A (1 - e^{-sigma L}) + c I e^{-sigma H} (1 - e^{-sigma L (1 - |d_z|)}) / (1 - |d_z|)

(sigma L in the limit |d_z| -> 1). The kernel's quadrature is the midpoint rule
of its steps; at 8 samples a finest cell its error is below 1e-4 of the colour,
and the transmittance toward the light, a product over exact step lengths, is
exact to float rounding. Every test runs on every OpenCL device present."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from exabricks.engine.renderer import Renderer
from exabricks.picture.light import KEY_ELEVATION, light_direction, light_params
from exabricks.scene import Lighting, Scene, Settings, VolumeLayer
from exabricks.util.errors import ExabricksError

from helpers import GERRIS, device_param
from helpers.slab import SLAB_CELLS, SLAB_RGB, SLAB_SPACING, constant_tf, slab, slab_camera

W, H = 24, 16
A0 = 0.3  # the slab's opacity per unit distance (its finest cell width)
AMBIENT, INTENSITY = 0.25, 0.8


def slab_scene(light, *, tf_alpha=A0, ambient=AMBIENT, intensity=INTENSITY, integrator="shadow") -> Scene:
    return Scene(camera=slab_camera(), volumes=(VolumeLayer("density", constant_tf(tf_alpha)),),
                 lighting=Lighting(integrator=integrator, light=light, ambient=ambient,
                                   light_intensity=intensity),
                 settings=Settings(width=W, height=H, sampling_rate=8.0, jitter=False, max_opacity=1.0))


def closed_form(light_above: bool, ambient=AMBIENT, intensity=INTENSITY) -> np.ndarray:
    sigma = -np.log(1.0 - A0) / SLAB_SPACING
    thickness = SLAB_SPACING * (SLAB_CELLS[2] + 1)
    _, directions = slab_camera().rays(W, H)
    dz = np.abs(directions[..., 2])
    length = thickness / dz
    lit = ambient * (1.0 - np.exp(-sigma * length))
    if light_above:
        lit = lit + intensity * (1.0 - np.exp(-sigma * length * (1.0 + dz))) / (1.0 + dz)
    else:
        k = sigma * length * (1.0 - dz)
        ratio = np.where(k > 1e-9, -np.expm1(-k) / np.maximum(k, 1e-300), 1.0)  # (1 - e^-k) / k
        lit = lit + intensity * np.exp(-sigma * thickness) * sigma * length * ratio
    return lit[..., None] * np.array(SLAB_RGB)


@device_param
@pytest.mark.parametrize("light_above", [True, False])
def test_a_slab_lit_from_above_and_from_below_is_the_closed_form(device, light_above):
    built = slab()
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device)
    light = (0.0, 0.0, 1.0 if light_above else -1.0)
    result = renderer.render_scene(slab_scene(light))
    want = closed_form(light_above)
    np.testing.assert_allclose(result.rgba[..., :3], want, rtol=1e-3, atol=0)
    # the opacity is the emission-absorption one, whatever the light
    plain = renderer.render_scene(slab_scene(light, integrator="headlight").replace(
        lighting=Lighting(shading="none")))
    np.testing.assert_array_equal(result.rgba[..., 3], plain.rgba[..., 3])


@device_param
def test_ambient_light_alone_is_the_unlit_frame(device):
    """With intensity 0 and ambient 1 the frame is the unlit one, bit for bit, drawn
    one sample at a time and by sample packets alike."""
    built = slab()
    renderer = Renderer(built.bricks, built.regions, built.bvh, device=device)
    for drawn in (renderer, renderer.with_packets(False)):
        plain = drawn.render_scene(slab_scene(None, integrator="headlight").replace(
            lighting=Lighting(shading="none")))
        ambient_only = drawn.render_scene(slab_scene((0.3, -0.2, 1.0), ambient=1.0, intensity=0.0))
        np.testing.assert_array_equal(ambient_only.rgba, plain.rgba)


def test_the_key_light_is_above_and_to_the_left_behind_the_camera():
    scene = slab_scene(None)
    d = light_direction(scene)
    _, forward, du, dv = scene.camera.frame(W, H)
    assert np.isclose(np.linalg.norm(d), 1.0)
    up, right = dv / np.linalg.norm(dv), du / np.linalg.norm(du)
    assert np.isclose(d @ up, np.sin(np.radians(KEY_ELEVATION)))  # above
    assert d @ right < 0 and d @ forward < 0  # to the left, from the camera's side
    params = light_params(scene, 0.5)
    assert params["light_rgb"] == (*(INTENSITY * np.ones(3)), AMBIENT) and params["light_dir"][3] == 0.25


@device_param
def test_shadows_refuse_what_they_cannot_do_yet(device, tmp_path):
    """Instances that overlap, and data domains where a shadow ray is traced
    (--shadow-rays traced, and the shadows of slices): one line saying so (not a
    wrong picture)."""
    import exabricks as eb

    ds = eb.open(GERRIS, cache=tmp_path / "cache")
    with pytest.raises(ExabricksError, match="--integrator shadow: .*overlap.*--mirror"):
        eb.render(ds, integrator="shadow", mirror=("x", 60.0), size=(16, 16), device=device)
    a_slice = {"point": [64, 64, 64], "normal": [0, 0, 1], "field": "T"}
    for options, what in (({"shadow_rays": "traced"}, r"shadow rays \(--integrator shadow --shadow-rays traced\)"),
                          ({"slices": [a_slice]}, r"slices' shadows \(--integrator shadow\)")):
        with pytest.raises(ExabricksError, match=what + " need the whole dataset"):
            eb.render_job(ds, tmp_path / "frame.png", integrator="shadow", memory_budget="2M",
                          size=(16, 16), device=device, **options)
    assert not (tmp_path / "frame.png").exists()


# -- real data against the float64 reference (tests/reference.py, `light`) ------------

REAL = 16  # pixels a side
REAL_TOLERANCE = 1e-4  # RMSE over the pixels and channels / the reference's maximum (measured 4.4e-6)


@pytest.mark.slow
@device_param
def test_a_shadowed_frame_of_real_data_matches_the_float64_reference(device):
    """The Gerris plume's hot core (test_render's view and colours) lit from the side:
    the kernel at 16 samples a finest cell against the reference's 16 (primary) and
    8 (toward the light) uniform steps. The opacity stops short of 1: a medium of
    opacity 1 is infinitely dense, and whether a shadow ray meets a sliver of it
    depends on where its samples fall, in the reference as in the kernel. The shadow
    is a real one: the lit frame differs from the ambient-only one by far more than
    the tolerance (7.5e-2 against 4.4e-6). Both the exact shadow rays (--shadow-rays
    traced) and the cached transmittance, the default, hold it."""
    import reference
    from helpers.plume_core import plume_core

    core = plume_core()
    built, camera, tf, unit, light = core.built, core.camera, core.tf, core.unit, core.light
    scene = Scene(camera=camera, volumes=(VolumeLayer("T", tf),),
                  lighting=Lighting(integrator="shadow", light=light, ambient=0.2, light_intensity=0.8),
                  settings=Settings(width=REAL, height=REAL, sampling_rate=16.0, jitter=False,
                                    max_opacity=1.0, unit_distance=unit))
    renderer = Renderer(built.bricks, built.regions, built.bvh, field="T", device=device)
    direction = np.asarray(light) / np.linalg.norm(light)
    want = reference.integrate(built.cells, camera, tf, REAL, REAL, "T", steps_per_finest_cell=16,
                               unit_distance=unit, light=(direction, 0.2, (0.8, 0.8, 0.8)),
                               shadow_steps_per_finest_cell=8)
    unlit = reference.integrate(built.cells, camera, tf, REAL, REAL, "T", steps_per_finest_cell=16,
                                unit_distance=unit, light=(direction, 0.2, (0.0, 0.0, 0.0)))
    shadowed = float(np.sqrt(np.mean((want - unlit) ** 2)) / want.max())
    assert shadowed > 100 * REAL_TOLERANCE, shadowed
    for rays in ("traced", "cached"):
        result = renderer.render_scene(scene.replace(lighting=replace(scene.lighting, shadow_rays=rays)))
        error = float(np.sqrt(np.mean((result.rgba - want) ** 2)) / want.max())
        assert error <= REAL_TOLERANCE, (rays, error)


@device_param
def test_a_surface_lit_from_the_camera_is_the_headlights_without_a_shadow_of_its_own(device):
    """The plume's iso-surface T = 0.1, no volume, seen from afar (so that every ray is
    nearly parallel to the view direction) and lit from the camera with the
    headlight's ambient 0.3 and diffuse 0.7: every point the camera sees, the light
    sees, so the frame is the headlight's (to the rays' spread, 1 degree). A surface
    that shadowed itself (shadow acne) would show dark dots."""
    import exabricks as eb

    ds = eb.open(GERRIS, cache=False)
    renderer = eb.Renderer(ds, device=device)
    near = renderer.scene(field="T", iso=0.1, volume=False, size=(48, 48))
    c = near.camera
    far = tuple(np.add(c.look_at, 60.0 * np.subtract(c.position, c.look_at)))
    scene = renderer.scene(near, position=far, fovy=c.fovy / 150.0)
    _, forward, _, _ = scene.camera.frame(48, 48)
    headlight = renderer.render(scene).rgba
    lit = renderer.render(scene.replace(lighting=Lighting(integrator="shadow", light=tuple(-forward),
                                                          ambient=0.3, light_intensity=0.7))).rgba
    assert (headlight[..., 3] > 0.5).sum() > 150  # the surface fills a good part of the frame
    np.testing.assert_allclose(lit, headlight, atol=2e-3, rtol=0)


@pytest.mark.slow
def test_a_scene_file_with_a_light_draws_the_same_from_the_command_line_python_and_the_viewer(tmp_path):
    """The command line, eb.render of the file, and the viewer's document of it (what
    "Save scene" writes) draw the same pixels, light and shadows included."""
    import json

    import exabricks as eb
    from exabricks.viewer.session import Session

    from helpers import run_cli

    doc = {"volumes": [{"field": "T", "transfer_function": {"colormap": "inferno", "opacity": [0, 0.3, 0.8]},
                        "range": [0, 0.6]}],
           "isosurfaces": [{"field": "T", "value": 0.45}],
           "lighting": {"integrator": "shadow", "light": {"direction": [-1, 1, 0.5], "color": [1, 0.9, 0.8],
                                                           "intensity": 0.9}, "ambient": 0.15},
           "size": [48, 40]}
    path = tmp_path / "lit.json"
    path.write_text(json.dumps(doc))
    run_cli("render", GERRIS, "--scene", path, "-o", tmp_path / "cli.exr", check=0)
    ds = eb.open(GERRIS, cache=tmp_path / "cache")
    cli = eb.Image.read(tmp_path / "cli.exr").rgba
    np.testing.assert_array_equal(eb.render(ds, path).rgba, cli)
    saved = Session(ds, scene=str(path)).doc  # the viewer's document: what "Save scene" writes
    assert saved["lighting"]["integrator"] == "shadow" and saved["lighting"]["light"]["direction"] == [-1, 1, 0.5]
    np.testing.assert_array_equal(eb.render(ds, saved).rgba, cli)
