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

import functools

import numpy as np
import pytest

from exabricks import schema
from exabricks.picture.camera import default_camera
from exabricks.readers import read
from exabricks.scene import Clip, IsoSurface, Lighting, Scene, Settings, Slice, VolumeLayer
from exabricks.engine.renderer import PACKET_WIDTH, Renderer
from exabricks.picture.transfer_function import TransferFunction, default_transfer_function, knot_buckets

from conftest import AMREX, ATHENA, ENZO, GERRIS, build, device_param

SIZE = 40
# Two fields each where the dataset has them (AMReX has one: its layers share it).
DATASETS = {"gerris": (GERRIS, ("T", "U")), "amrex": (AMREX, ("phi",)),
            "athena": (ATHENA, ("rho", "press")), "enzo": (ENZO, ("Density", "Temperature"))}


@functools.lru_cache(maxsize=None)
def loaded(name: str):
    path, fields = DATASETS[name]
    built = build(read(path, fields=list(fields)))
    lo, hi = (np.asarray(x) for x in schema.world_bounds(built.bricks))
    ranges = [(float(v.min()), float(v.max())) for v in built.bricks.values]
    return built, default_camera(lo, hi), lo, hi, ranges


@functools.lru_cache(maxsize=None)
def renderer(name: str, device) -> Renderer:
    built = loaded(name)[0]
    return Renderer(built.bricks, built.regions, built.bvh, fields=DATASETS[name][1],
                    device=device)


def translucent(value_range, peak=0.3) -> TransferFunction:
    """viridis with an opacity ramp 0 -> peak: nothing to skip, nothing opaque."""
    return TransferFunction.from_colormap("viridis", value_range, opacity=(0.0, peak))


def scene_for(name: str, mode: str) -> Scene:
    """One frame of `mode` on dataset `name` (every mode the renderer has)."""
    built, camera, lo, hi, ranges = loaded(name)
    fields = DATASETS[name][1]
    f0, f1 = fields[0], fields[-1]
    mid = [0.5 * (a + b) for a, b in ranges]
    centre = tuple(0.5 * (lo + hi))
    volume = (VolumeLayer(f0, default_transfer_function(ranges[0])),)
    iso = (IsoSurface(f0, mid[0] + 0.1 * (ranges[0][1] - ranges[0][0]), opacity=0.6),)
    settings = dict(width=SIZE, height=SIZE)
    lighting = {}
    parts = dict(volumes=volume)
    if mode == "emission":
        lighting = dict(shading="none")
    elif mode == "translucent":
        parts = dict(volumes=(VolumeLayer(f0, translucent(ranges[0])),))
        settings.update(max_opacity=1.0)
    elif mode == "central":
        lighting = dict(gradient="central")
    elif mode == "two-layers":
        parts = dict(volumes=(VolumeLayer(f0, translucent(ranges[0])),
                              VolumeLayer(f1, translucent(ranges[-1], 0.2))))
    elif mode == "iso":
        parts = dict(volumes=(VolumeLayer(f0, translucent(ranges[0], 0.1)),), isosurfaces=iso)
        lighting = dict(specular=0.4)
        settings.update(depth=True)
    elif mode == "clip-slice":
        parts = dict(volumes=volume, slices=(Slice(centre, (0.0, 0.0, 1.0), f1,
                                                   translucent(ranges[-1]), 0.7),),
                     clip=Clip(planes=((centre, (1.0, 0.2, 0.0)),)))
    elif mode == "ao":
        parts = dict(volumes=(VolumeLayer(f0, translucent(ranges[0], 0.05)),), isosurfaces=iso)
        lighting = dict(ao_samples=4)
    elif mode == "lod":
        settings.update(lod=3.0)
    elif mode == "spp":
        settings.update(spp=3, seed=7)
    elif mode in ("nearest", "vertex"):
        settings.update(reconstruction=mode)
    else:
        raise AssertionError(mode)
    return Scene(camera=camera, lighting=Lighting(**lighting), settings=Settings(**settings),
                 **parts)


MODES = ("emission", "translucent", "central", "two-layers", "iso", "clip-slice", "ao", "lod",
         "spp", "nearest", "vertex")


def assert_same_frame(packet, single, width=PACKET_WIDTH):
    """Same samples and the same image up to rounding; `width`: the packets used (1
    where the reconstruction or lookup has none: then the very same program runs)."""
    assert packet.stats["packet_width"] == width and single.stats["packet_width"] == 1
    assert packet.stats["samples"] == single.stats["samples"] > 0
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
