"""The first picture (issue 48, docs/scene.md "Defaults"): `render SOURCE -o x.png`
with no option but the field, on every real dataset, shows the structure:
opaque, neither empty nor a block, with contrast, framed, without speckle.
The measures are benchmarks.first_picture's; the figures they hold to are the
ones docs/scene.md records, with room for the jitter of one sample per pixel."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from benchmarks.first_picture import picture_metrics
from helpers import AMREX, ATHENA, ENZO, GERRIS, run_cli

SOURCES = {"amrex": (AMREX, ()), "athena": (ATHENA, ("--field", "rho")),
           "gerris": (GERRIS, ("--field", "T")), "enzo": (ENZO, ("--field", "Density"))}


@pytest.mark.slow  # four renders of real data from their sources: in the slow suite (CI runs it)
@pytest.mark.parametrize("name", sorted(SOURCES))
def test_the_default_picture_shows_the_structure(name, tmp_path):
    source, field = SOURCES[name]
    png = tmp_path / "x.png"
    run_cli("render", source, *field, "--no-cache", "-o", png, check=0)
    m = picture_metrics(np.asarray(Image.open(png).convert("RGBA")))
    assert m["opaque"] == 1.0, m
    assert 0.05 <= m["coverage"] <= 0.75, m  # neither an empty frame nor a block
    assert m["contrast"] >= 0.25, m
    assert m["framing"] >= 0.6, m  # the visible part fills most of the frame
    assert m["isolated_dark"] <= 0.5, m  # no speckle (per thousand covered pixels)


def test_the_metrics_tell_a_block_and_an_empty_frame_from_a_picture():
    """The measures themselves: an opaque uniform cube fails contrast, an empty
    frame coverage, salt-and-pepper the isolated-dark count."""
    block = np.zeros((64, 64, 4), np.uint8)
    block[..., 3] = 255
    block[4:60, 4:60, :3] = (90, 20, 120)
    m = picture_metrics(block)
    assert m["contrast"] < 0.05 and m["coverage"] > 0.75
    assert picture_metrics(np.zeros((64, 64, 4), np.uint8))["coverage"] == 0.0
    y, x = np.mgrid[:64, :64]
    disc = np.zeros((64, 64, 4), np.uint8)
    disc[..., 3] = 255
    disc[..., 1] = np.clip(255 - 8 * np.hypot(x - 32, y - 32), 0, 255).astype(np.uint8)
    clean = picture_metrics(disc)["isolated_dark"]
    disc[::7, ::5, 1] //= 4
    assert clean == 0.0 and picture_metrics(disc)["isolated_dark"] > 10
