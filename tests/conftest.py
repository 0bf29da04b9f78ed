"""Shared fixtures: the CLI runner, a generator, built files of the demo dataset.
What tests share besides fixtures is in `helpers` (tests/helpers/)."""

from __future__ import annotations

import os

import numpy as np
import pytest

# Sources' built structures go to a cache of this test process, never the user's.
if "EXABRICKS_CACHE" not in os.environ:
    import tempfile

    os.environ["EXABRICKS_CACHE"] = tempfile.mkdtemp(prefix="exabricks-test-cache-")

from helpers import GERRIS, built_scene, run_cli  # noqa: E402


@pytest.fixture
def browser():
    """A headless Chromium through Selenium (helpers.browser)."""
    from helpers.browser import chromium

    yield from chromium()


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture
def rng():
    """A fresh generator per test: no test depends on what others drew."""
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def plume_trio(tmp_path_factory):
    """bricks, regions and bvh files of the Gerris plume's T field."""
    from exabricks import schema

    d = tmp_path_factory.mktemp("trio")
    bricks, regions, bvh, *_ = built_scene(GERRIS, "T")
    paths = [d / "bricks.npz", d / "regions.npz", d / "bvh.npz"]
    regions = regions.replace(meta={"consistency": {"n_bricks": bricks.n_bricks,
                                                    "n_regions": regions.n_regions}})
    for path, obj in zip(paths, (bricks, regions, bvh)):
        schema.save(path, obj)
    return paths
