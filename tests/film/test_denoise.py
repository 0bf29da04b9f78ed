"""The film's optional denoiser (exabricks/film/denoise.py; issue 52 item 5): Intel
Open Image Denoise over a noisy path-traced frame brings it closer to the
converged one, only when asked (never by default), with one clear error line where
it cannot run."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from exabricks.engine.renderer import Renderer
from exabricks.film import denoise
from exabricks.film.image_io import read_image
from exabricks.scene import Lighting, Scene, Settings, VolumeLayer
from exabricks.util.errors import ExabricksError

from helpers import GERRIS, device_param

pytest.importorskip(denoise.PACKAGE)


@device_param
def test_a_noisy_path_traced_frame_comes_closer_to_the_converged_one(device):
    """The plume's core path-traced at 8 spp, raw and denoised, against the same frame
    at 512 spp: the denoised frame's error is well under the raw one's, its alpha
    stays a coverage in [0, 1], and the raw frame is what the default gives."""
    from helpers.plume_core import plume_core

    core = plume_core()
    scene = Scene(camera=core.camera, volumes=(VolumeLayer("T", core.tf),),
                  lighting=Lighting(integrator="path", light=core.light),
                  background=(0.1, 0.1, 0.15, 1.0),
                  settings=Settings(width=64, height=64, spp=8, unit_distance=core.unit))
    renderer = Renderer(core.built.bricks, core.built.regions, core.built.bvh, field="T", device=device)
    raw = renderer.render_scene(scene).rgba
    assert not scene.settings.denoise
    denoised = renderer.render_scene(scene.replace(
        settings=dataclasses.replace(scene.settings, denoise=True))).rgba
    converged = renderer.render_scene(scene.replace(
        settings=dataclasses.replace(scene.settings, spp=512, seed=1))).rgba

    def rmse(a):
        return float(np.sqrt(np.mean((a - converged)[..., :3] ** 2)))

    assert rmse(denoised) < 0.5 * rmse(raw), (rmse(denoised), rmse(raw))
    assert denoised[..., 3].min() >= 0.0 and denoised[..., 3].max() <= 1.0


def test_without_the_package_one_error_line(monkeypatch):
    monkeypatch.setitem(sys.modules, denoise.PACKAGE, None)  # import fails
    with pytest.raises(ExabricksError, match=r"pip install 'exabricks\[denoise\]'"):
        denoise.check()


def test_the_command_line_denoises_whole_frames_and_records_it(cli, tmp_path):
    out = tmp_path / "d.exr"
    flags = ["--field", "T", "--size", 48, 40, "--integrator", "path", "--spp", 2]
    cli("render", GERRIS, "-o", out, *flags, "--denoise", check=0)
    assert read_image(out)[1]["scene"]["denoise"] is True  # the scene file it was drawn from
    proc = cli("render", GERRIS, "-o", tmp_path / "t.exr", *flags, "--denoise", "--tile", 16, 16)
    assert proc.returncode == 2 and "error: --denoise needs the whole frame, not --tile" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "t.exr").exists()
