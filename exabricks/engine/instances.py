"""Instances: the data and the meshes drawn again, mirrored or moved
(docs/design-rendering.md, "Instances"; the paper mirrors the ExaJet so).

Instance i draws a data point x at R_i x + t_i (R_i orthogonal: a mirror, a
rotation, or both), the identity being instance 0. Such a map keeps distances,
so a ray of the frame is, in an instance's own (object) space, a ray with the
same distances t along it: an instance's picture is the frame of the untouched
dataset seen by the camera taken into object space (`ObjectCamera`), with the
scene's planes and boxes taken there too (`object_scene`).

Each instance draws only inside its world box: the box of the data's cells
and the meshes' bounds, placed by its map (the basis reconstruction's half
cell beyond the data's faces is cut, so that a mirror on a face joins the
copies without overlap). Where those boxes do not overlap, every ray
crosses them one after the other, in an order that a plane between each two
boxes fixes for the whole frame (the side of the eye comes first;
`visibility_order`). The frame is then each instance's frame in that order, each
one's rays continuing from the image composited in front of it (the domain
frames of exabricks.engine.streaming, one whole dataset per domain), sample by
sample: the same image, early ray termination and depth as one scene holding
every copy. Where boxes overlap, the copies' media mix (their extinctions add):
the frame is then drawn in one pass that takes every copy covering a point at
the same samples (`render_mixture`, kernels/mixture.cl).
"""

from __future__ import annotations

import time
from dataclasses import replace
from itertools import combinations

import numpy as np

from ..picture.camera import Camera, box_corners
from ..util.errors import ExabricksError
from ..util.vectors import unit
from . import light_volume
from ..scene.model import Clip, Scene
from ..scene.modes import MAX_CLIP_PLANES

# The lattice box of an instance's frame: all of it (kernels/frame.cl eb_in_domain).
EVERYWHERE = ((-1e30,) * 3 + (0.0,), (1e30,) * 3 + (0.0,))
# Boxes closer than this (times their size) count as touching, not overlapping:
# a mirror through a face of the data.
TOUCH = 1e-9


def transforms(scene: Scene) -> list[tuple[np.ndarray, np.ndarray]]:
    """(R, t) of every instance of `scene`, the identity first."""
    return [(np.eye(3), np.zeros(3))] + [i.affine() for i in scene.instances]


class ObjectCamera:
    """`camera` seen from the object space of an instance drawn at R x + t: the same
    pixels look along the same rays, taken back by the instance's map (a mirror
    keeps the image's columns where they were, which a camera of position,
    look_at and up could not)."""

    def __init__(self, camera: Camera, r: np.ndarray, t: np.ndarray):
        self.camera, self.r, self.t = camera, r, t
        self.fovy = camera.fovy
        self.position = tuple(r.T @ (np.asarray(camera.position, np.float64) - t))

    def frame(self, width: int, height: int):
        origin, forward, du, dv = self.camera.frame(width, height)
        back = self.r.T
        return back @ (origin - self.t), back @ forward, back @ du, back @ dv

    footprint = Camera.footprint
    rays = Camera.rays


def object_scene(scene: Scene, r: np.ndarray, t: np.ndarray, box) -> Scene:
    """`scene`'s frame of the instance at (r, t), in its object space, without
    instances: the camera, the slices and the clip planes taken
    back, and the clip box too (as six planes where the map turns it off the
    axes); everything cut at the object-space `box` ((2, 3) or None)."""
    back = r.T

    def plane(point, normal):
        return (tuple(back @ (np.asarray(point, np.float64) - t)),
                tuple(back @ np.asarray(normal, np.float64)))

    planes = [plane(p, n) for p, n in scene.clip.planes]
    cut = None if box is None else np.array(box, np.float64)
    if scene.clip.box is not None:
        lo, hi = (np.asarray(b, np.float64) for b in scene.clip.box)
        if np.allclose(np.abs(r), np.round(np.abs(r)), atol=1e-12):  # axes onto axes
            corners = (np.round(back, 12) @ (np.stack([lo, hi]) - t).T).T
            user = np.stack([corners.min(0), corners.max(0)])
            cut = user if cut is None else np.stack([np.maximum(cut[0], user[0]),
                                                     np.minimum(cut[1], user[1])])
            cut[1] = np.maximum(cut[0], cut[1])  # none of it left: an empty box
        else:
            eye = np.eye(3)
            planes += [plane(lo, eye[a]) for a in range(3)] + [plane(hi, -eye[a]) for a in range(3)]
            if len(planes) > MAX_CLIP_PLANES:
                raise ExabricksError(f"a rotated instance takes the clip box as six planes: with "
                                     f"{len(scene.clip.planes)} more, over the {MAX_CLIP_PLANES} "
                                     "a frame can hold")
    slices = tuple(s.__class__(*plane(s.point, s.normal), s.field, s.colormap, s.opacity)
                   for s in scene.slices)
    clip = Clip(None if cut is None else (tuple(cut[0]), tuple(cut[1])), tuple(planes))
    lighting = scene.lighting
    if lighting.light is not None:  # a direction in world space
        lighting = replace(lighting, light=tuple(back @ np.asarray(lighting.light, np.float64)))
    return scene.replace(camera=ObjectCamera(scene.camera, r, t), slices=slices, clip=clip,
                         lighting=lighting, instances=())


def placement(scene):
    """(r, t) of the instance whose frame in object space `scene` is (object_scene),
    or None."""
    camera = scene.camera
    return (camera.r, camera.t) if isinstance(camera, ObjectCamera) else None


def light(inner, scene: Scene, scenes, box, maps) -> None:
    """Under the shadow integrator, the light's cached transmittance over every
    instance (exabricks.engine.light_volume): one volume in world space, over the
    copies of the regions that the frame's volume layers show (of `box`, where
    none does), to which each instance (its frame in object space in `scenes`)
    adds the optical depths of its own copy; the light crosses them all."""
    lighting = scene.lighting
    if lighting.integrator != "shadow":
        return
    if lighting.shadow_rays == "traced":
        raise ExabricksError("--shadow-rays traced: a shadow ray does not cross instances "
                             "(--mirror); the cached transmittance (the default) does")
    data = inner.dataset
    seen = light_volume.seen_box(data.regions, data.bricks.field_index, scene.volumes)
    if seen is None and box is None:  # nothing to cross
        return
    placed = np.concatenate(_placed(box if seen is None else seen, maps)[0])
    cache = inner.light_cache
    cache.box = (placed.min(axis=0), placed.max(axis=0))
    parts = [light_volume.part(inner.domain, m) for m in maps]
    for _ in range(2):  # a part made for another light comes again after the rest
        for one in scenes:
            inner.light(one)
        if cache.holds(parts):
            return
    raise ExabricksError("the instances disagree on the light's transmittance")


def object_box(lower, upper, mesh_bounds=None) -> np.ndarray:
    """float64 (2, 3): the box (object space) of the data's cells [lower, upper]
    and the meshes' (lower, upper), either of which may be None; None for neither."""
    boxes = [np.asarray(b, np.float64) for b in ((lower, upper), mesh_bounds) if b is not None
             and b[0] is not None]
    if not boxes:
        return None
    return np.stack([np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)])


def _placed(box, maps):
    """The corners of each instance's copy of `box`, and the scale of the whole."""
    corners = box_corners(*box)
    placed = [corners @ r.T + t for r, t in maps]
    return placed, float(np.abs(np.concatenate(placed)).max()) or 1.0


def _separation(placed, maps, i: int, j: int, size: float):
    """(low, high, unit axis, cut): a plane between copies i and j (separating
    axes of two boxes: their faces' normals and the cross products of their
    edges), `low` the copy below `cut` along the axis; None where they overlap."""
    (ri, _), (rj, _) = maps[i], maps[j]
    for axis in [*ri.T, *rj.T] + [np.cross(a, b) for a in ri.T for b in rj.T]:
        n = float(np.linalg.norm(axis))
        if n < 1e-9:
            continue
        axis = axis / n
        pi, pj = placed[i] @ axis, placed[j] @ axis
        if pi.max() <= pj.min() + TOUCH * size:
            return i, j, axis, 0.5 * (pi.max() + pj.min())
        if pj.max() <= pi.min() + TOUCH * size:
            return j, i, axis, 0.5 * (pj.max() + pi.min())
    return None


def overlapping(box, maps) -> tuple[int, int] | None:
    """The first two instances whose copies of the object-space `box` overlap, or None."""
    if box is None:
        return None
    placed, size = _placed(box, maps)
    return next(((i, j) for i, j in combinations(range(len(maps)), 2)
                 if _separation(placed, maps, i, j, size) is None), None)


def visibility_order(box, maps, eye) -> list[int]:
    """The instances (`maps`: (R, t) each) front to back from the world point `eye`,
    whose copies of the object-space `box` ((2, 3)) each lie on one side of a
    plane from each other. ExabricksError for two that overlap (`render` draws
    those as a mixture), or a cycle no single order can draw."""
    if box is None:
        return list(range(len(maps)))
    placed, size = _placed(box, maps)
    eye = np.asarray(eye, np.float64)
    before = {i: set() for i in range(len(maps))}  # before[j]: those in front of j
    for i, j in combinations(range(len(maps)), 2):
        found = _separation(placed, maps, i, j, size)
        if found is None:
            raise ExabricksError(f"instances {i} and {j} overlap (0 is the data itself)")
        low, high, axis, cut = found
        front, back = (low, high) if eye @ axis <= cut else (high, low)
        before[back].add(front)
    order, placing = [], set()

    def place(k):
        if k in order:
            return
        if k in placing:
            raise ExabricksError("the instances have no order front to back from this eye: "
                                 "move the camera or the copies")
        placing.add(k)
        for f in sorted(before[k]):
            place(f)
        order.append(k)

    for k in range(len(maps)):
        place(k)
    return order


def render_mixture(inner, scene: Scene, box, *, traversal, rows, window, sample, deadline):
    """`render`'s frame with every instance drawn at once as one mixture of media
    (kernels/mixture.cl), each copy cut at its box: what copies that overlap
    need (their extinctions add where they do)."""
    mixed = inner._mixture(box, copy_rows(scene, box))
    result = mixed.integrate(scene.replace(instances=()), traversal=traversal, rows=rows,
                             window=window, sample=sample, deadline=deadline)
    stats = dict(result.stats, instances=len(scene.instances) + 1, instance_order="mixture")
    return result.rgba, result.depth, stats


def copy_rows(scene: Scene, box) -> np.ndarray:
    """float32 (copies, rows, 4): what kernels/mixture.cl reads of each copy, in
    float4 rows: its map from world to object space (3 rows: M | m); a head (has
    a clip box, clip planes, the row of its slices, 0); the clip box's corners;
    its clip planes (point, unit normal), padded to the most any copy has; its
    slices' points (w: opacity), then their unit normals. The clipping and the
    slices are the copy's object scene's (`object_scene`: the cut at `box` included)."""
    maps = transforms(scene)
    clips = [object_scene(scene, r, t, box) for r, t in maps]
    most = max(len(o.clip.planes) for o in clips)
    n_slices = len(scene.slices)
    out = np.zeros((len(maps), 6 + 2 * most + 2 * n_slices, 4), np.float32)
    for k, ((r, t), obj) in enumerate(zip(maps, clips)):
        out[k, :3] = np.column_stack([r.T, -r.T @ t])
        clip = obj.clip
        out[k, 3] = (clip.box is not None, len(clip.planes), 6 + 2 * most, 0)
        if clip.box is not None:
            out[k, 4, :3], out[k, 5, :3] = clip.box
        for i, (point, normal) in enumerate(clip.planes):
            out[k, 6 + 2 * i, :3], out[k, 7 + 2 * i, :3] = point, unit(normal)
        at = 6 + 2 * most
        for i, plane in enumerate(obj.slices):
            out[k, at + i] = (*plane.point, plane.opacity)
            out[k, at + n_slices + i, :3] = unit(plane.normal)
    return out


def render(inner, scene: Scene, box, *, traversal, rows, window, sample, deadline):
    """The frame of `scene` with its instances: (premultiplied radiance before
    the film, depth or None, stats). `inner` renders one frame of the
    untouched dataset continuing an image in front (a Renderer over EVERYWHERE);
    `box` is object_box's; the other arguments are Renderer.integrate's, whose
    deadline applies to the first instance's first sample alone (those after it
    draw the rows it drew)."""
    maps = transforms(scene)
    if overlapping(box, maps):
        return render_mixture(inner, scene, box, traversal=traversal, rows=rows, window=window,
                              sample=sample, deadline=deadline)
    order = visibility_order(box, maps, scene.camera.position)
    scenes = [object_scene(scene, r, t, box) for r, t in maps]
    light(inner, scene, scenes, box, maps)
    spp = int(scene.settings.spp)
    samples = range(spp) if sample is None and spp > 1 else (sample,)
    total = depth = stats = drawn = None
    count, spans = 0, rows
    start = time.perf_counter()
    for k in samples:
        over = None
        for i in order:
            result = inner.integrate(scenes[i], traversal=traversal, rows=spans, window=window,
                                     sample=k, front=over, deadline=deadline)
            over, stats = result.rgba, result.stats
            count += stats["samples"]
            if result.depth is not None:
                depth = result.depth if depth is None else np.minimum(depth, result.depth)
            if deadline is not None:  # the rows above it, for every later frame
                deadline, drawn = None, stats["rows"]
                spans = [(a, min(a + n, drawn) - a) for a, n in (rows or [(0, len(over))])
                         if a < drawn] or [(0, 0)]
        total = over if total is None else total + over
    if len(samples) > 1:
        total /= np.float32(len(samples))
    seconds = time.perf_counter() - start
    stats = dict(stats, rows=stats["rows"] if drawn is None else drawn, samples=count,
                 instances=len(maps), instance_order=order, spp=spp,
                 ms=1e3 * seconds, ms_per_sample=1e3 * seconds / (spp if sample is None else 1),
                 samples_per_second=count / seconds if seconds > 0 else 0.0)
    return total, depth, stats

