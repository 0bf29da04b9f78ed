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
the samples per pixel and the seed change nothing.

Data split into domains (exabricks.engine.partition: a memory budget's, or MPI
data mode's ranks) share one volume over the box of the regions that the
frame's volume layers show in any of them (`seen_box`, `Cache.box`): each domain
adds the optical depth of its own samples to every column (`Cache.buffer` with
its `part`), and the sum is the whole's. So do a frame's instances, each in its
own object space (`placement`). The driver has every part added before any
frame reads the volume (streaming.Budgeted.light_all; instances.light;
parallel.ParallelRenderer, which sums the ranks' parts with MPI)."""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import schema
from ..device import opencl
from ..util.errors import ExabricksError
from .device_data import SEEN_VOLUME, seen_bits

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
# samples; and where a domain's share of the dataset lies in its buffers (the rest
# of the parameters and the look's arrays are its key, the same in every domain).
_PER_VIEW = ("cam_origin", "cam_forward", "cam_du", "cam_dv", "width", "height", "spp",
             "seed", "jitter", "lod_scale", "shading", "ao_samples", "ao_distance", "light_rgb")
_PER_DOMAIN = ("domain", "domain_lower", "domain_upper", "use_front", "n_nodes", "n_regions",
               "n_bricks", "n_tree_nodes", "field_stride", "vertex_stride", "mip_stride")


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


def cached(scene) -> bool:
    """Whether frames of `scene` read this cache: the shadow integrator's, its
    transmittance not traced by a shadow ray from every sample."""
    return scene.lighting.integrator == "shadow" and scene.lighting.shadow_rays == "cached"


def box_of(regions, seen):
    """The world box (lower, upper) of the regions where `seen` (per region, as
    DeviceDataset.visibility gives it) has SEEN_VOLUME, or None where none has.
    In steps over the regions (schema.rows), so that mapped ones stay unread."""
    lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
    for start, (lo, hi) in schema.rows(regions.lower_lattice, regions.upper_lattice):
        here = (seen[start:start + lo.shape[0]] & SEEN_VOLUME) != 0
        if here.any():
            lower = np.minimum(lower, lo[here].min(axis=0))
            upper = np.maximum(upper, hi[here].max(axis=0))
    if not np.all(lower <= upper):
        return None
    return (regions.origin_world + regions.spacing_world * lower,
            regions.origin_world + regions.spacing_world * upper)


def seen_box(regions, field_index, volumes):
    """box_of the regions (`field_index`: a field's column of their value ranges)
    that some of `volumes` (a scene's volume layers) shows: what a driver of
    parts sets Cache.box to, from regions no DeviceDataset holds."""
    layers = [(v.field, v.transfer_function) for v in volumes]
    return box_of(regions, seen_bits(regions.value_range, field_index, layers))


def union(boxes):
    """The box around `boxes` ((lower, upper) pairs, or None), or None."""
    boxes = [b for b in boxes if b is not None]
    if not boxes:
        return None
    return (np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0))


def part(domain, placement) -> tuple:
    """What names a renderer's part of a shared Cache: its domain's box
    (kernel_abi.float4_box) and the instance's placement (r, t), each or None."""
    return (domain, None if placement is None else
            tuple(np.concatenate([np.ravel(placement[0]), np.ravel(placement[1])])))


def key(params, arrays) -> str:
    """What the cache depends on: the frame's eb_params but the view's and the
    domain's, and `arrays` (its look: which nodes and regions a volume layer shows
    follows from it)."""
    skip = set(_PER_VIEW + _PER_DOMAIN)
    h = hashlib.sha1()
    for name in params.dtype.names:  # member by member: the struct's padding is not set
        if name not in skip and not name.endswith("_at"):
            h.update(np.ascontiguousarray(params[name]).tobytes())
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


@dataclass
class LightVolume:
    """A cache: its device buffer and figures, and the parts whose optical depths
    it holds, each with the key it was made for (`parts`: Cache.buffer's part ->
    key)."""

    buffer: object
    dims: tuple[int, int, int]
    seconds: float = 0.0
    parts: dict = field(default_factory=dict)

    @property
    def nbytes(self) -> int:
        return 4 * math.prod(self.dims)


def build(queue, program, params, by_value: bool, fixed, out) -> float:
    """Add the optical depths of every column of the volume that `params`
    (eb_params, light_* set) lays out to `out`, with the program's
    eb_light_columns (its eb_params by value, or in a buffer) over the buffers
    `fixed` (the dataset's, the look's and the meshes', as eb_render takes them):
    the seconds it took."""
    nu, nv, nw = (int(x) for x in params["light_dims"].reshape(-1)[:3])
    params = params.copy()
    params["step_base"] /= COLUMN_STEPS
    params = params if by_value else opencl.to_device(queue, params)
    kernel = opencl.kernel(program, "eb_light_columns")
    rows = max(1, COLUMNS_PER_LAUNCH // nu)
    tile = (8, 8)
    start = time.perf_counter()
    for j0 in range(0, nv, rows):
        n = min(rows, nv - j0)
        size = (-(-nu // tile[0]) * tile[0], -(-n // tile[1]) * tile[1])
        kernel(queue, size, tile, params, np.int32(j0), np.int32(n), *fixed, out).wait()
    return time.perf_counter() - start


class Cache:
    """A Renderer's cached transmittance: the last LightVolume made, kept for as
    long as the keys of its parts hold. The copies of a Renderer over the same
    upload share it, and so do the Renderers of a dataset's domains and the
    instances of a frame, each adding its part (`Cache.buffer`'s `part`).
    `box`: the world box (lower, upper) that the volume covers, where a driver of
    parts sets it (the regions that a frame's volume layers show, in every
    part: seen_box); else that of the dataset of the frame; `max_bytes`: its
    size at most (a memory budget's share)."""

    def __init__(self, box=None, max_bytes: int = 4 * MAX_NODES):
        self.box, self.max_bytes = box, int(max_bytes)
        self.volume = None
        self.empty = set()  # parts that hold no data: nothing to add, whatever the key

    def buffer(self, dataset, program, by_value: bool, shadow_rays: str, params, look, region_vis,
               fixed, stats: dict, part=None, placement=None):
        """The device buffer that eb_render reads for the frame of `params`
        (eb_params, whose light_* members this sets; `program` draws it, taking
        them by value or not) over `dataset` (a DeviceDataset); or a dummy with
        `shadow_rays` "traced". The volume is made anew where `part` (its
        domain and instance: `part`) holds one made for another
        key, and the optical depths of `part` are added where it holds none.
        `placement`: (r, t) where the frame is an instance's, in its object
        space (exabricks.engine.instances: world = r @ object + t): the volume
        lies in world space, its nodes taken into object space. `look`: the
        frame's look arrays; `region_vis`: its regions' visibility
        (DeviceDataset.visibility); `fixed`: eb_render's dataset, look and mesh
        buffers."""
        stats["shadow_rays"] = shadow_rays
        if shadow_rays == "traced":
            params["light_dims"] = (2, 2, 2, 0)
            return opencl.empty_buffer(dataset.queue, 4)
        r, t = (np.eye(3), np.zeros(3)) if placement is None else placement
        box = self.box or box_of(dataset.regions, region_vis) or schema.world_bounds(dataset.bricks)
        light = r @ params["light_dir"].reshape(-1)[:3].astype(np.float64)
        for name, value in geometry(*box, light, dataset.finest_width_world, self.max_bytes // 4).items():
            if name == "light_origin":
                value = (*(r.T @ (np.asarray(value[:3]) - t)), value[3])
            elif name in ("light_u", "light_v"):
                value = (*(r.T @ np.asarray(value[:3])), value[3])
            params[name] = value
        cache_key = key(params, look)
        v = self.volume
        if v is None or v.parts.get(part, cache_key) != cache_key:
            self.volume = v = None  # the old buffer goes before the new one comes
            dims = tuple(int(d) for d in params["light_dims"].reshape(-1)[:3])
            out = opencl.empty_buffer(dataset.queue, 4 * math.prod(dims))
            opencl.fill_zero(dataset.queue, out, 4 * math.prod(dims))
            self.volume = v = LightVolume(out, dims)
        added = part not in v.parts
        if added:
            v.seconds += build(dataset.queue, program, params, by_value, fixed, v.buffer)
            v.parts[part] = cache_key
        stats["light_volume"] = {"nodes": list(v.dims), "bytes": v.nbytes, "built": added,
                                 "ms": round(1e3 * v.seconds, 3)}
        return v.buffer

    def holds(self, parts) -> bool:
        """Whether the volume holds the optical depths of every one of `parts`."""
        return set(parts) <= set(self.volume.parts if self.volume else ()) | self.empty

    def sum_over(self, comm, queue, made) -> None:
        """Sum the volume over the ranks of `comm` (MPI data mode), where each
        rank's `made` (Renderer.light's stats; None for a rank that holds no
        data) says that it holds only its own domain's part: every rank then
        holds the whole's. Collective."""
        from mpi4py import MPI

        states = comm.allgather(None if made is None else (tuple(self.volume.dims), made["built"]))
        held = [s for s in states if s is not None]
        if not any(built for _, built in held):
            return
        if len({dims for dims, _ in held}) > 1 or not all(built for _, built in held):
            raise ExabricksError("the ranks disagree on the light's transmittance")
        host = np.zeros(math.prod(held[0][0]), np.float32)
        if made is not None:
            opencl.read_back(queue, self.volume.buffer, host)
        comm.Allreduce(MPI.IN_PLACE, host, op=MPI.SUM)
        if made is not None:
            opencl.write_to(queue, self.volume.buffer, host)
