"""The shadow integrator's cached transmittance toward the light
(`--shadow-rays cached`, the default; kernels/light_volume.cl; docs/design-rendering.md,
"Lights and shadows").

A light-space volume over the data's box as the light sees it: its nodes lie
`spacing` apart along two axes across the light and along the light itself.
Each column of nodes is one shadow ray, marched from the light's side of the
box through the regions as every shadow ray is, that records the volume
layers' transmittance at each node. Made once per light direction, transfer
function, clipping and dataset (`key`), it is kept by the Renderer and read by
every sample of every frame until one of those changes: the camera, the size,
the samples per pixel and the seed change nothing."""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass

import numpy as np

from .. import schema
from ..device import opencl
from .device_data import SEEN_VOLUME

# Nodes per finest cell width along each axis, where the box of the visible regions
# holds no more than MAX_NODES of them (float32: 64 MiB), and at most MAX_AXIS
# along any axis; and steps of a column per step of a shadow ray (its region's
# finest level's). Measured on the four datasets against the traced shadow rays
# (docs/benchmarks-render.md, "Shadow integrator").
NODES_PER_CELL = 4
MAX_NODES = 1 << 24
MAX_AXIS = 1024
COLUMN_STEPS = 2
# Columns marched per launch, about: a launch ends well within a second, so that
# a signal can stop the build between two.
COLUMNS_PER_LAUNCH = 1 << 14

# eb_params members that do not change the cache: the camera, the image and its
# samples (the rest of the parameters, the look's arrays and the visibility flags
# are its key).
_PER_VIEW = ("cam_origin", "cam_forward", "cam_du", "cam_dv", "width", "height", "spp",
             "seed", "jitter", "lod_scale", "shading", "ao_samples", "ao_distance", "light_rgb")


def axes(light_dir) -> np.ndarray:
    """Unit axes (u, v, w) of the light's space, float64 (3, 3): w away from the
    light (-light_dir), u and v across it."""
    w = -np.asarray(light_dir, np.float64)[:3]
    w = w / np.linalg.norm(w)
    helper = np.eye(3)[int(np.argmin(np.abs(w)))]
    u = np.cross(helper, w)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(w, u), w])


def geometry(lower, upper, light_dir, finest_width: float, max_nodes: int = MAX_NODES) -> dict:
    """The eb_params of the light-space volume over the world box [lower, upper]
    toward `light_dir` (unit, toward the light): light_origin, light_u, light_v,
    light_dims (kernel_abi.PARAMS)."""
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    corners = np.array([[(lower, upper)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
    uvw = axes(light_dir)
    projected = corners @ uvw.T
    low, extent = projected.min(axis=0), np.ptp(projected, axis=0)
    extent = np.maximum(extent, 1e-30 * max(1.0, float(np.abs(projected).max())))
    spacing = max(float(finest_width) / NODES_PER_CELL,
                  float(np.prod(extent) / max_nodes) ** (1.0 / 3.0), float(extent.max()) / (MAX_AXIS - 1))
    dims = np.clip(np.ceil(extent / spacing).astype(np.int64) + 1, 2, MAX_AXIS)
    while int(np.prod(dims)) > max_nodes:  # rounding up may pass the bound by a little
        spacing *= 1.01
        dims = np.clip(np.ceil(extent / spacing).astype(np.int64) + 1, 2, MAX_AXIS)
    step = extent / (dims - 1)
    origin = low @ uvw
    return {"light_origin": (*origin, 1.0 / step[2]),
            "light_u": (*uvw[0], 1.0 / step[0]), "light_v": (*uvw[1], 1.0 / step[1]),
            "light_dims": (*(int(d) for d in dims), 1)}


def visible_box(regions, region_vis):
    """The world box of the regions some volume layer shows (region_vis: the
    frame's visibility bits, DeviceDataset.visibility), or None where none does."""
    seen = (np.asarray(region_vis) & SEEN_VOLUME) != 0
    if not seen.any():
        return None
    lower = regions.lower_lattice[seen].min(axis=0).astype(np.float64)
    upper = regions.upper_lattice[seen].max(axis=0).astype(np.float64)
    return (regions.origin_world + regions.spacing_world * lower,
            regions.origin_world + regions.spacing_world * upper)


def key(params, arrays) -> str:
    """What the cache depends on: the frame's eb_params but the view's, and
    `arrays` (its look and the visibility of the nodes and regions)."""
    p = params.copy()
    for name in _PER_VIEW:
        p[name] = 0
    h = hashlib.sha1(p.tobytes())
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


@dataclass
class LightVolume:
    """A built cache: its key, device buffer and figures."""

    key: str
    buffer: object
    dims: tuple[int, int, int]
    seconds: float

    @property
    def nbytes(self) -> int:
        return 4 * math.prod(self.dims)


def build(queue, program, params, by_value: bool, fixed, cache_key: str) -> LightVolume:
    """March every column of the volume that `params` (eb_params, light_* set) lays
    out, with the program's eb_light_columns (its eb_params by value, or in a
    buffer) over the buffers `fixed` (the dataset's, the look's and the meshes',
    as eb_render takes them)."""
    nu, nv, nw = (int(x) for x in params["light_dims"].reshape(-1)[:3])
    params = params.copy()
    params["step_base"] /= COLUMN_STEPS
    params = params if by_value else opencl.to_device(queue, params)
    out = opencl.empty_buffer(queue, 4 * nu * nv * nw)
    kernel = opencl.kernel(program, "eb_light_columns")
    rows = max(1, COLUMNS_PER_LAUNCH // nu)
    tile = (8, 8)
    start = time.perf_counter()
    for j0 in range(0, nv, rows):
        n = min(rows, nv - j0)
        size = (-(-nu // tile[0]) * tile[0], -(-n // tile[1]) * tile[1])
        kernel(queue, size, tile, params, np.int32(j0), np.int32(n), *fixed, out).wait()
    return LightVolume(cache_key, out, (nu, nv, nw), time.perf_counter() - start)


class Cache:
    """A Renderer's cached transmittance: the last LightVolume built, kept for as
    long as its key holds (the copies of a Renderer over the same upload share it)."""

    def __init__(self):
        self.volume = None

    def buffer(self, dataset, program, by_value: bool, shadow_rays: str, params, arrays, fixed,
               stats: dict):
        """The device buffer that eb_render reads for the frame of `params`
        (eb_params, whose light_* members this sets; `program` draws it, taking
        them by value or not) over `dataset` (a DeviceDataset): this cache, built
        first where its key changed, or a dummy with `shadow_rays` "traced".
        `arrays`: the frame's look arrays, its nodes' and regions' visibility (the
        regions' last); `fixed`: eb_render's dataset, look and mesh buffers."""
        stats["shadow_rays"] = shadow_rays
        if shadow_rays == "traced":
            params["light_dims"] = (2, 2, 2, 0)
            return opencl.empty_buffer(dataset.queue, 4)
        box = visible_box(dataset.regions, arrays[-1]) or schema.world_bounds(dataset.bricks)
        for name, value in geometry(*box, params["light_dir"].reshape(-1)[:3],
                                    dataset.finest_width_world).items():
            params[name] = value
        cache_key = key(params, arrays)
        built = self.volume is None or self.volume.key != cache_key
        if built:
            self.volume = None  # the old buffer goes before the new one comes
            self.volume = build(dataset.queue, program, params, by_value, fixed, cache_key)
        v = self.volume
        stats["light_volume"] = {"nodes": list(v.dims), "bytes": v.nbytes, "built": built,
                                 "ms": round(1e3 * v.seconds, 3)}
        return v.buffer
