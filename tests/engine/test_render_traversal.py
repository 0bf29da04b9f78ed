"""The two region walks of kernels/traversal.cl give the same frames.

"ordered" (the CPUs' default: one traversal per ray with a private min-heap)
and "retrace" (the GPUs' default: the paper's §4 re-trace from the root per
region, stackless) must visit the same regions over the same intervals, so
images and sample counts agree, with sample packets (the CPUs' programs) and
one sample at a time (the GPUs'); the ordered walk's fallback to re-tracing
when its heap fills up (forced here with a 2-entry heap) must too.
tests/engine/test_render.py checks the default walk against the float64
reference integrator; tests/engine/test_walk_links.py the stackless walk's links.
"""

from __future__ import annotations


import numpy as np
import pytest

from exabricks.util.errors import ExabricksError
from exabricks.engine.renderer import TRAVERSALS, Renderer

from helpers import AMREX, ATHENA, GERRIS, DEVICES, built_scene

SIZE = 64
DATASETS = {"gerris": (GERRIS, "T"), "amrex": (AMREX, "phi"), "athena": (ATHENA, "rho")}


def scene(name: str):
    """(bricks, regions, bvh, field, camera, transfer function) of a shared dataset."""
    return built_scene(*DATASETS[name])


def use_build(renderer, define: str) -> None:
    """Make `renderer` render with its volume program built with one more define."""
    from exabricks.engine.variants import frame

    kernel = renderer._kernel(frame(kind="cpu" if renderer.packets else "gpu", traversal="ordered",
                                    n_fields=len(renderer.dataset.fields) or 1),
                              extra=(define,))
    renderer._kernel = lambda *args, **kwargs: kernel


def frame(renderer, name, **settings):
    *_, camera, tf = scene(name)
    return renderer.render(camera=camera, transfer_function=tf, width=SIZE, height=SIZE,
                           **settings)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("name", list(DATASETS))
@pytest.mark.parametrize("shading", ["headlight", "none"])
@pytest.mark.parametrize("packets", [True, False], ids=["packets", "one-sample"])
def test_ordered_and_retrace_walks_give_the_same_frame(name, device, shading, packets):
    bricks, regions, bvh, field, *_ = scene(name)
    renderer = Renderer(bricks, regions, bvh, field=field, device=device, packets=packets)
    results = {t: frame(renderer, name, traversal=t, shading=shading, depth=True)
               for t in TRAVERSALS}
    ordered, retrace = results["ordered"], results["retrace"]
    assert ordered.stats["samples"] > SIZE * SIZE  # the view is not empty
    assert ordered.stats["samples"] == retrace.stats["samples"]
    np.testing.assert_allclose(ordered.rgba, retrace.rgba, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.isinf(ordered.depth), np.isinf(retrace.depth))
    assert ordered.stats["traversal"] == "ordered" and retrace.stats["traversal"] == "retrace"


@pytest.mark.parametrize("device", DEVICES)
def test_the_default_walk_follows_the_device(device):
    """Packets (CPUs) walk with the heap, one sample at a time (GPUs) without."""
    bricks, regions, bvh, field, *_ = scene("athena")
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    assert renderer.with_packets(True).traversal == "ordered"
    assert frame(renderer.with_packets(False), "athena").stats["traversal"] == "retrace"


@pytest.mark.parametrize("device", DEVICES)
def test_heap_overflow_falls_back_to_retrace(device):
    """With a 2-entry heap almost every ray overflows; the frame must not change."""
    bricks, regions, bvh, field, *_ = scene("gerris")
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    want = frame(renderer, "gerris", traversal="ordered")
    use_build(renderer, "EB_QUEUE_SIZE=2")
    got = frame(renderer, "gerris", traversal="ordered")
    assert got.stats["samples"] == want.stats["samples"]
    np.testing.assert_allclose(got.rgba, want.rgba, rtol=0, atol=1e-6)


def test_unknown_traversal_is_one_clear_error():
    if not DEVICES:
        pytest.skip("no OpenCL device")
    bricks, regions, bvh, field, *_ = scene("athena")
    renderer = Renderer(bricks, regions, bvh, field=field, device=DEVICES[0])
    with pytest.raises(ExabricksError, match="unknown traversal 'bfs'"):
        frame(renderer, "athena", traversal="bfs")
