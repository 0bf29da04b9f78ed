"""The film (exabricks.film.film, issue 50 item 3): a frame's radiance becomes its
picture in one place, after every domain, sample and tile has composited, so a
setting applied there, the exposure, is exact under every way of drawing a
frame. The reference is the resident frame's radiance (`Renderer.integrate`)
developed in float64 by the definition: colour times 2**exposure, then over the
background."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from exabricks.engine.streaming import Budgeted, Resident, render_steps
from exabricks.film.film import develop
from exabricks.film.image_io import read_image
from exabricks.scene import Instance

from helpers.frames import loaded, renderer, scene_for
from helpers.streaming import budget_for, same, tiled

EXPOSURE = 1.5
BACKGROUND = (0.1, 0.2, 0.3, 1.0)


def developed(radiance: np.ndarray, exposure: float = EXPOSURE, background=BACKGROUND) -> np.ndarray:
    """`radiance` (premultiplied) developed by the definition, in float64."""
    out = radiance.astype(np.float64)
    out[..., :3] *= 2.0 ** exposure
    r, g, b, a = background
    out += (1.0 - out[..., 3:4]) * np.array([r * a, g * a, b * a, a])
    return out


def exposed(scene, exposure: float = EXPOSURE):
    return scene.replace(background=BACKGROUND,
                         settings=dataclasses.replace(scene.settings, exposure=exposure))


def close(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=2e-6 * max(1.0, float(np.abs(b).max())))


@pytest.mark.parametrize("name,mode", [("gerris", "emission"), ("amrex", "two-layers")])
def test_exposure_is_exact_for_a_resident_frame_and_its_tiles(name, mode):
    scene = exposed(scene_for(name, mode))
    radiance = renderer(name, None).integrate(scene).rgba
    assert float(radiance[..., :3].max()) > 1e-3
    reference = developed(radiance)
    close(renderer(name, None).render_scene(scene).rgba, reference)
    rgba, _, _ = tiled(Resident(renderer(name, None)), scene, (29, 13))
    close(rgba, reference)


@pytest.mark.parametrize("name,mode,n", [("gerris", "emission", 8), ("amrex", "central", 8)])
@pytest.mark.slow
def test_exposure_is_exact_under_a_memory_budget(name, mode, n):
    """Each domain continues the radiance in front of it: the exposure comes once,
    after the last (a kernel-side exposure scaled each domain's front again)."""
    built = loaded(name)[0]
    scene = exposed(scene_for(name, mode))
    reference = developed(renderer(name, None).integrate(scene).rgba)
    domains = Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, n))
    assert domains.n_domains >= n
    same(render_steps(domains, scene).rgba, reference)
    tile = (24, 16)
    domains = Budgeted(built.bricks, built.regions, scene, budget_for(name, scene, n), tile=tile)
    same(tiled(domains, scene, tile)[0], reference)


def test_exposure_is_exact_with_instances():
    name = "amrex"
    _, _, lo, _, _ = loaded(name)
    base = scene_for(name, "emission")
    for copies in ((Instance(mirror=("x", float(lo[0]))),),
                   (Instance(translate=(0.0, 0.0, 0.0)),)):  # apart, and a mixture where they overlap
        scene = exposed(base.replace(instances=copies))
        whole = renderer(name, None)
        radiance = whole.integrate(scene).rgba
        assert float(radiance[..., :3].max()) > 1e-3
        close(whole.render_scene(scene).rgba, developed(radiance))


def test_no_exposure_is_the_frame_as_before():
    scene = scene_for("gerris", "emission").replace(background=BACKGROUND)
    radiance = renderer("gerris", None).integrate(scene).rgba
    np.testing.assert_array_equal(renderer("gerris", None).render_scene(scene).rgba,
                                  develop(radiance.copy(), scene))
    close(develop(radiance.copy(), scene), developed(radiance, exposure=0.0))


@pytest.mark.slow
def test_exposure_from_the_command_line_and_the_scene_file(cli, tmp_path):
    """--exposure and a scene file's settings.exposure give the same frame: the
    unexposed frame's colour times 2**STOPS."""
    from helpers import GERRIS

    flags = ["--field", "T", "--size", 48, 40]
    cli("render", GERRIS, "-o", tmp_path / "plain.exr", *flags, check=0)
    cli("render", GERRIS, "-o", tmp_path / "lit.exr", *flags, "--exposure", -2, check=0)
    plain, meta = read_image(tmp_path / "plain.exr")
    lit, lit_meta = read_image(tmp_path / "lit.exr")
    assert float(plain[..., :3].max()) > 1e-3
    close(lit[..., :3], plain[..., :3].astype(np.float64) / 4.0)
    np.testing.assert_array_equal(lit[..., 3], plain[..., 3])
    (tmp_path / "scene.json").write_text('{"exposure": -2}')
    cli("render", GERRIS, "-o", tmp_path / "file.exr", *flags, "--scene", tmp_path / "scene.json",
        check=0)
    np.testing.assert_array_equal(read_image(tmp_path / "file.exr")[0], lit)


def test_exposure_out_of_range_is_refused(cli, tmp_path):
    """On the command line as click refuses any option out of its range (exit 2);
    in a scene file with one error line naming the file (exit 1); in Python with
    an ExabricksError."""
    from helpers import GERRIS, assert_one_error_line

    import exabricks as eb

    proc = cli("render", GERRIS, "-o", tmp_path / "x.png", "--exposure", 100)
    assert proc.returncode == 2 and "--exposure" in proc.stderr and "Traceback" not in proc.stderr
    (tmp_path / "scene.json").write_text('{"exposure": 100}')
    assert_one_error_line(cli("render", GERRIS, "-o", tmp_path / "x.png", "--scene",
                              tmp_path / "scene.json"), "scene.json", "exposure")
    assert not (tmp_path / "x.png").exists()
    scene = scene_for("gerris", "emission")
    with pytest.raises(eb.ExabricksError, match="exposure"):
        scene.replace(settings=dataclasses.replace(scene.settings, exposure=float("nan"))).check()
