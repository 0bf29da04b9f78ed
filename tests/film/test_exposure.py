"""The automatic exposure (exabricks.film.exposure, issue 63 item 2): the film's
light meter brings the automatic picture to the display's range, --exposure
adds to it, the metadata records it, and a tiled frame, which no band can
meter alone, is metered on a preview of the whole frame."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from exabricks.engine.streaming import Resident
from exabricks.film.exposure import (DATA_ALPHA, LUMINANCE, MAX_STOPS, METER_QUANTILE,
                                     TARGET_LUMINANCE, metered_stops)
from exabricks.film.image_io import read_image
from exabricks.scene import scene_from_options

from helpers.frames import loaded, renderer
from helpers.streaming import tiled


def _luminance(rgba):
    return rgba[..., :3].astype(np.float64) @ LUMINANCE.astype(np.float64)


def test_the_meter_places_the_quantile_of_the_data_at_the_target():
    rng = np.random.default_rng(1)
    rgba = np.zeros((64, 64, 4), np.float32)
    rgba[:32, :, 3] = 0.5
    rgba[:32, :, :3] = rng.uniform(0.0, 0.3, (32, 64, 1)).astype(np.float32)
    rgba[32:, :, :3] = 0.001  # no data (alpha 0): not metered
    seen = _luminance(rgba)[rgba[..., 3] >= DATA_ALPHA]
    expected = math.log2(TARGET_LUMINANCE / np.quantile(seen, METER_QUANTILE))
    assert metered_stops(rgba) == pytest.approx(expected, rel=1e-5)
    assert metered_stops(np.zeros((8, 8, 4), np.float32)) == 0.0  # nothing to meter
    rgba[:32, :, :3] = 1e-6
    assert metered_stops(rgba) == MAX_STOPS  # within its limits


def _default_scene(**flags):
    built = loaded("gerris")[0]
    return scene_from_options(built.bricks, flags={"field": "T", "size": (96, 64), **flags})


def test_the_automatic_picture_reaches_the_display_and_exposure_adds_to_it():
    scene = _default_scene()
    assert scene.settings.auto_exposure  # the automatic transfer function's picture
    whole = renderer("gerris", None)
    radiance = whole.integrate(scene).rgba
    result = whole.render_scene(scene)
    stops = result.stats["metered_exposure"]
    assert stops == pytest.approx(metered_stops(radiance)) and stops > 0.5
    seen = _luminance(result.rgba)[radiance[..., 3] >= DATA_ALPHA]
    assert np.quantile(seen, METER_QUANTILE) == pytest.approx(TARGET_LUMINANCE, rel=1e-3)
    brighter = scene.replace(settings=dataclasses.replace(scene.settings, exposure=1.0))
    np.testing.assert_allclose(whole.render_scene(brighter).rgba[..., :3],
                               2.0 * result.rgba[..., :3], rtol=1e-6, atol=1e-7)
    # Colours and opacities chosen by hand are drawn as chosen.
    assert not _default_scene(colormap="viridis", opacity=(0.0, 0.5)).settings.auto_exposure
    assert _default_scene(auto_exposure=True, colormap="viridis",
                          opacity=(0.0, 0.5)).settings.auto_exposure


def test_a_tiled_frame_is_metered_on_a_preview_of_the_whole():
    scene = _default_scene()
    rgba, _, stats = tiled(Resident(renderer("gerris", None)), scene, (40, 24))
    whole = renderer("gerris", None).render_scene(scene)
    assert stats["metered_exposure"] == pytest.approx(whole.stats["metered_exposure"], abs=0.25)
    ratio = 2.0 ** (stats["metered_exposure"] - whole.stats["metered_exposure"])
    np.testing.assert_allclose(rgba[..., :3], ratio * whole.rgba[..., :3], rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_the_metadata_records_both(cli, tmp_path):
    from helpers import GERRIS

    out = tmp_path / "x.exr"
    cli("render", GERRIS, "--field", "T", "--size", 48, 40, "--exposure", -1, "-o", out, check=0)
    _, meta = read_image(out)
    assert meta["scene"]["exposure"] == -1 and meta["scene"]["auto_exposure"] is True
    assert meta["settings"]["metered_exposure"] > 0  # the stops the meter added
