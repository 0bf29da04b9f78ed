"""FLASH, Chombo and RAMSES outputs, written by the tests in each code's own on-disk
layout (helpers/flash_output.py, chombo_output.py, ramses_output.py), taken the ways a
user takes them: `readers.read` with the format detected, `ingest`, `eb.open`, and a
frame rendered from them against the float64 reference integrator over the leaves
the writer wrote (never what a reader made of them). yt 4.4.3 reads FLASH and
Chombo, exabricks.readers.ramses RAMSES (docs/ingest.md, "FLASH, Chombo and RAMSES").

The readers' own checks (the layouts, the leaves, the Hilbert domains) are in
test_readers_flash.py, test_readers_chombo.py and test_readers_ramses.py."""

from __future__ import annotations

import numpy as np
import pytest

import reference
from helpers import analytic_amr, chombo_output, device_param, flash_output, ramses_output, run_cli

pytest.importorskip("yt")
pytest.importorskip("h5py")

# code -> (writer, the names its reader gives the formula's fields, what meta["source"] says)
CODES = {
    "flash": (flash_output, ("dens", "pres"), {"format": "yt", "frontend": "FLASHDataset"}),
    "chombo": (chombo_output, ("density", "pressure"), {"format": "yt", "frontend": "ChomboDataset"}),
    "ramses": (ramses_output, ("Density", "Pressure"), {"format": "ramses"}),
}

SIZE = 40
RMSE_TOLERANCE = 2e-3  # as tests/engine/test_render.py, over the maximum of the reference


@pytest.fixture(scope="module", params=list(CODES))
def output(request, tmp_path_factory):
    """(code, path, leaves) of one written output."""
    writer = CODES[request.param][0]
    path, leaves = writer.write(tmp_path_factory.mktemp(request.param))
    return request.param, path, leaves


def _as_formula(cells, code):
    """`cells` with the formula's field names in place of the code's."""
    assert cells.fields == CODES[code][1]
    return cells.replace(fields=analytic_amr.FIELDS)


def test_the_written_leaves_tile_the_domain_on_three_levels_or_more(output):
    _, _, leaves = output
    analytic_amr.assert_leaves_tile(leaves)
    assert len(np.unique(leaves.width)) >= 3


def test_read_detects_the_format_and_gives_the_leaves(output):
    from exabricks.readers import read

    code, path, leaves = output
    cells = read(path)
    assert CODES[code][2].items() <= cells.meta["source"].items()
    analytic_amr.assert_cells_match(_as_formula(cells, code), leaves)
    one = read(path, fields=[CODES[code][1][1]])
    np.testing.assert_array_equal(one.values[0], cells.values[1])


def test_ingest_gives_the_leaves(output):
    from exabricks.stages.ingest import ingest

    code, path, leaves = output
    analytic_amr.assert_cells_match(_as_formula(ingest(path), code), leaves)


@device_param
def test_a_frame_of_eb_open_matches_the_reference(output, device):
    """eb.open's structures drawn at sampling rate 16, no shading, no jitter, against
    the float64 integral over the written leaves (tests/engine/test_render.py's
    measure): the whole chain from the code's file to the picture."""
    import exabricks as eb
    from exabricks.engine.renderer import Renderer
    from exabricks.picture.camera import default_camera
    from exabricks.picture.transfer_function import TransferFunction

    code, path, leaves = output
    field = CODES[code][1][0]
    bricks, regions, bvh = eb.open(path, cache=False).structures()
    want_cells = analytic_amr.expected_cells(leaves).replace(fields=CODES[code][1])
    lo, hi = reference.support_box_world(want_cells)
    camera = default_camera(lo, hi)
    values = want_cells.values[0]
    a, b = float(values.min()), float(np.percentile(values, 99))
    tf = TransferFunction(np.array([[a, 0.1, 0.2, 0.9], [b, 0.9, 0.3, 0.1]]),
                          np.array([[a, 0.0], [b, 0.6]]), "ramp")
    unit = 4.0 * float(leaves.width.min())
    want = reference.integrate(want_cells, camera, tf, SIZE, SIZE, field, steps_per_finest_cell=16,
                               unit_distance=unit, max_opacity=1.0)
    assert (want[..., 3] > 0.1).mean() > 0.1  # a real test: much of the frame is drawn
    got = Renderer(bricks, regions, bvh, field=field, device=device).render(
        camera=camera, transfer_function=tf, width=SIZE, height=SIZE, sampling_rate=16,
        jitter=False, shading="none", max_opacity=1.0, unit_distance=unit).rgba
    error = float(np.sqrt(np.mean((got - want) ** 2)) / want.max())
    assert error <= RMSE_TOLERANCE, f"{code}: RMSE / max = {error:.3g}"


@pytest.mark.slow
def test_the_commands_read_and_draw_it(output, tmp_path):
    """`exabricks ingest SOURCE` and `exabricks render SOURCE`, as a user types them."""
    from exabricks import schema

    code, path, leaves = output
    cells_file = tmp_path / "cells.npz"
    run_cli("ingest", path, "-o", cells_file, check=0)
    analytic_amr.assert_cells_match(_as_formula(schema.load(cells_file, "cells"), code), leaves)
    picture = tmp_path / "picture.png"
    proc = run_cli("render", path, "-o", picture, "--size", 96, 64, check=0)
    assert proc.stderr == "" and picture.stat().st_size > 0
    from PIL import Image

    rgb = np.asarray(Image.open(picture).convert("RGB"), np.float64)
    assert rgb.shape == (64, 96, 3) and rgb.std() > 5  # something drawn, not a blank frame
