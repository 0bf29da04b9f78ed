"""The shared datasets in memory and one frame of every render mode on each
(the packets, film and streaming tests draw them)."""

from __future__ import annotations

import functools

import numpy as np
from exabricks import schema
from exabricks.picture.camera import default_camera
from exabricks.readers import read
from exabricks.scene import Clip, IsoSurface, Lighting, Scene, Settings, Slice, VolumeLayer
from exabricks.engine.renderer import Renderer
from exabricks.picture.transfer_function import TransferFunction, default_transfer_function
from helpers import AMREX, ATHENA, ENZO, GERRIS, build


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
