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


@pytest.fixture(scope="session", autouse=True)
def builds_only_declared_programs():
    """Every render program the tests of this process built is one the feature
    table declares (exabricks.engine.variants.declared, the benchmarks' lookups
    and walks included, for the field counts built): no program outside the
    named set. Builds with a define of a test's own (Renderer._kernel's `extra`)
    are the tests' probes of the kernels, not programs of a frame."""
    yield
    from exabricks.device import opencl
    from exabricks.engine import variants

    known = {x for kind in variants.DEVICE_KINDS for v in variants.declared(kind, benchmarks=True)
             for x in v.defines if not x.startswith("EB_N_FIELDS=")}
    builds = {defines for source, defines, _ in opencl.BUILDS if source == opencl.ENTRY_SOURCE}
    ours = {d for d in builds if all(x in known or x.startswith("EB_N_FIELDS=") for x in d)}
    counts = {int(x.split("=")[1]) for d in ours for x in d if x.startswith("EB_N_FIELDS=")}
    declared = {v.defines for kind in variants.DEVICE_KINDS for n in counts
                for v in variants.declared(kind, n, benchmarks=True)}
    outside = ours - declared
    assert not outside, f"programs outside the declared set: {sorted(outside)}"
