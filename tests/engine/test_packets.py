"""Sample packets (kernels/packet.cl, issue 15): a ray that reconstructs the next
eight samples of a region at once in vector registers gives the image of the
one-sample path, on every render mode and every shared dataset.

The same samples are taken (the sample counts are equal) and composited in the
same order, so the two images differ only by float rounding: the vector code
does the one-sample arithmetic in the same order, but LLVM may contract other
products into fused multiply-adds. The bound is the issue's: RMSE at most 1e-5
of the image's maximum. Both paths run on every OpenCL device (a GPU takes the
one-sample path by default, but the packet build is valid OpenCL there too).
"""

from __future__ import annotations


import numpy as np
import pytest

from exabricks.engine.renderer import PACKET_WIDTH, Renderer
from exabricks.picture.transfer_function import default_transfer_function, knot_buckets

from helpers import device_param
from helpers.frames import DATASETS, MODES, loaded, renderer, scene_for


def assert_same_frame(packet, single, width=PACKET_WIDTH):
    """Same samples (per level too, under --lod) and the same image up to rounding;
    `width`: the packets used (1 where the reconstruction or lookup has none: then
    the same arithmetic runs, the CPU profile's with the reconstruction compiled in,
    the GPU profile's with it chosen per frame)."""
    assert packet.stats["packet_width"] == width and single.stats["packet_width"] == 1
    assert packet.stats["samples"] == single.stats["samples"] > 0
    assert packet.stats.get("samples_per_level") == single.stats.get("samples_per_level")
    if width == 1:
        np.testing.assert_array_equal(packet.rgba, single.rgba)
    a, b = packet.rgba, single.rgba
    assert b[..., 3].max() > 1e-3  # the frame shows something
    rmse = float(np.sqrt(np.mean((a - b) ** 2)))
    assert rmse <= 1e-5 * float(np.abs(b).max()), rmse
    if single.depth is not None:
        assert np.array_equal(np.isfinite(packet.depth), np.isfinite(single.depth))


# The heaviest frames run in the slow suite (each mode stays on two or three datasets
# in the fast one).
SLOW = {("athena", "lod"), ("athena", "iso"), ("athena", "emission"), ("athena", "vertex"),
        ("amrex", "lod")}
CASES = [pytest.param(name, mode, marks=pytest.mark.slow) if (name, mode) in SLOW else (name, mode)
         for name in sorted(DATASETS) for mode in MODES]


@device_param
@pytest.mark.parametrize("name,mode", CASES)
def test_packets_give_the_one_sample_image(name, mode, device):
    scene = scene_for(name, mode)
    base = renderer(name, device)
    packet = base.with_packets(True).render_scene(scene)
    single = base.with_packets(False).render_scene(scene)
    assert_same_frame(packet, single, 1 if mode in ("nearest", "vertex") else PACKET_WIDTH)


@pytest.mark.slow  # two program variants of its own: in the slow suite
@device_param
@pytest.mark.parametrize("name", ["gerris", "amrex"])
def test_packets_with_the_retrace_walk_and_none_with_cell_location(name, device):
    scene = scene_for(name, "translucent")
    base = renderer(name, device).with_lookup("cell-location")
    assert_same_frame(base.with_packets(True).render_scene(scene),
                      base.with_packets(False).render_scene(scene), 1)
    base = renderer(name, device)
    assert_same_frame(base.with_packets(True).render_scene(scene, traversal="retrace"),
                      base.with_packets(False).render_scene(scene, traversal="retrace"))


@device_param
def test_cpu_devices_take_packets_by_default(device):
    from exabricks.device import opencl

    built = loaded("gerris")[0]
    r = Renderer(built.bricks, built.regions, built.bvh, field="T", device=device)
    assert r.packets == opencl.is_cpu(opencl.choose_device(device))


def device_knot_below(index: np.ndarray, xs: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The knot below each value as eb_packet_lookup finds it from the knot index, in
    float32 like the device (values inside (xs[0], xs[-1]))."""
    k, m, first = int(index[0]), int(index[1]), index[2:]
    scale = np.float32(k) / (xs[-1] - xs[0])
    x = np.minimum(np.maximum((v - xs[0]) * scale, np.float32(0)), np.float32(k - 1))
    base = first[x.astype(np.int32)]
    lo = base.copy()
    for s in range(1, m + 1):
        cand = np.minimum(base + s, len(xs) - 1)
        lo += ((base + s < len(xs)) & (xs[cand] <= v)).astype(lo.dtype)
    return lo


@pytest.mark.parametrize("kind", ["colormap", "clustered", "random", "two"])
def test_knot_index_finds_the_knot_below_every_value(kind, rng):
    """The knot index gives the binary search's answer for every float32 value, knots
    and their float neighbours included, however unevenly the knots are spaced."""
    if kind == "colormap":
        xs = default_transfer_function((-3.0, 7.5)).merged_knots()[0]
    elif kind == "clustered":
        xs = np.concatenate([np.linspace(0, 1, 50), 1 + np.cumsum(rng.random(30) * 1e-5),
                             np.linspace(2, 1e3, 7)])
    elif kind == "random":
        xs = np.cumsum(rng.random(300) ** 4 + 1e-6) - 50.0
    else:
        xs = np.array([0.25, 0.5])
    xs = np.unique(np.asarray(xs, np.float32))
    index = knot_buckets(xs)
    assert index[0] <= 4 * len(xs) and index[1] >= 0
    near = np.concatenate([xs, np.nextafter(xs, np.float32(np.inf)),
                           np.nextafter(xs, np.float32(-np.inf))])
    v = np.concatenate([near, rng.uniform(xs[0], xs[-1], 20000).astype(np.float32)])
    v = v[(v > xs[0]) & (v < xs[-1])]
    want = np.searchsorted(xs, v, side="right") - 1
    np.testing.assert_array_equal(device_knot_below(index, xs, v), want)
