"""Budgets, comparisons and tiles of frames under a memory budget
(exabricks.engine.streaming), for the tests of streamed frames."""

from __future__ import annotations

import numpy as np
from exabricks.engine.domains import domain_plan, domain_bytes
from exabricks.engine.budget_bytes import LIGHT_SHARE, SLACK, fixed_bytes, light_bytes
from exabricks.engine.streaming import render_tiled
from helpers.frames import loaded


def whole_bytes(name, scene) -> int:
    built = loaded(name)[0]
    plan = domain_plan(built.bricks, built.regions, [-np.inf] * 3, [np.inf] * 3, 0.0, True,
                       ("b", "r"))
    return domain_bytes(built.bricks, built.regions, plan, scene.fields())


def budget_for(name, scene, domains: int) -> int:
    """A budget whose domains each hold at most 1/`domains` of the whole: at least
    that many domains."""
    n_bricks = loaded(name)[0].bricks.n_bricks
    bare = fixed_bytes(scene, n_bricks) + SLACK * whole_bytes(name, scene) / domains
    # and the cached transmittance's share of the budget (light_bytes), if any
    return int(bare + light_bytes(scene, bare / (1.0 - LIGHT_SHARE))) + 1


def same(a, b):
    peak = float(np.abs(b).max())
    assert peak > 1e-3
    rmse = float(np.sqrt(np.mean((a.astype(np.float64) - b) ** 2)))
    assert rmse <= 1e-5 * peak, (rmse, peak)


def tiled(domains, scene, tile):
    """render_tiled into one array: (rgba, depth or None, stats)."""
    s = scene.settings
    rgba = np.full((s.height, s.width, 4), np.nan, np.float32)
    depth = np.full((s.height, s.width), np.nan, np.float32) if s.depth else None

    def put(row0, band, band_depth):
        rgba[row0:row0 + len(band)] = band
        if depth is not None:
            depth[row0:row0 + len(band)] = band_depth

    stats = render_tiled(domains, scene, tile, put)
    return rgba, depth, stats
