"""Iso-surfaces as triangle meshes (`exabricks surface`, issue 37; docs/surface.md).

The reconstructed field is sampled on a uniform grid of one level's cell centres
over the data's bounds (the finest level whose grid has at most `max_points`
points, or the level asked for), by the probe kernel (the renderer's own
reconstruction), a slab of grid planes at a time; scikit-image's marching cubes
then meshes the iso-value where every corner of a grid cell has a value (points
without support are masked out). Vertices are in world units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import schema
from ..util.errors import ExabricksError
from ..formats.memory import check_memory

MAX_POINTS = 1 << 27  # grid points by default: 512 MiB of float32 samples
SLAB_POINTS = 1 << 22  # points probed at once


@dataclass(frozen=True)
class Mesh:
    """vertices: float64 (V, 3) world units; faces: int64 (F, 3) vertex indices,
    wound so that their normals point toward lower values of the field; level and
    grid: the sampling level and its (nx, ny, nz) points."""

    vertices: np.ndarray
    faces: np.ndarray
    level: int
    grid: tuple[int, int, int]


def sampling_level(bricks: schema.Bricks, max_points: int = MAX_POINTS, level: int | None = None):
    """(level, lower lattice corner, (nx, ny, nz)) of the grid of cell centres that
    samples the data: `level` if given, else the finest whose grid has at most
    `max_points` points."""
    if bricks.n_bricks == 0:
        raise ExabricksError("the dataset has no cells")
    lo, hi = (np.asarray(b, np.float64) for b in schema.world_bounds(bricks))
    lo = np.floor((lo - bricks.origin_world) / bricks.spacing_world + 0.5).astype(np.int64)
    hi = np.floor((hi - bricks.origin_world) / bricks.spacing_world + 0.5).astype(np.int64)
    finest, coarsest = int(bricks.level.min()), int(bricks.level.max())

    def dims(lv):
        return tuple(int(max(1, math.ceil((h - l) / 2 ** lv))) for l, h in zip(lo, hi))

    if level is None:
        level = finest
        while math.prod(dims(level)) > max_points and level < 30:
            level += 1
    elif not 0 <= level <= 30:
        raise ExabricksError(f"--level {level}: expected a level from 0 (the finest cells' size) to 30")
    n = dims(level)
    if math.prod(n) > max_points:
        raise ExabricksError(f"a grid of level {level} has {math.prod(n):,} points, more than "
                             f"--max-points {max_points:,}: choose a coarser --level or allow more")
    if min(n) < 2:
        raise ExabricksError(f"a grid of level {level} has {n[0]} x {n[1]} x {n[2]} points: too "
                             f"coarse to mesh (the coarsest cells are level {coarsest}); choose a "
                             "finer --level")
    return level, lo, n


def iso_mesh(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh, field: str | None,
             value: float, *, level: int | None = None, max_points: int = MAX_POINTS,
             reconstruction: str = "basis", device=None, on_slab=None, grid=None) -> Mesh:
    """The iso-surface `field` = `value` of the dataset as a Mesh (module
    docstring). `on_slab(points)` after each slab probed; `grid`: the
    `sampling_level` of these arguments, when the caller has it already.
    ExabricksError when the grid would be too large or too coarse, or the value
    is outside the sampled field's range (no surface)."""
    from skimage.measure import marching_cubes

    from ..engine.device_data import DeviceDataset

    if not math.isfinite(value):
        raise ExabricksError(f"--value {value}: expected a finite number")
    name = bricks.fields[bricks.field_index(field)]
    level, lo, (nx, ny, nz) = grid or sampling_level(bricks, max_points, level)
    h = float(2 ** level)
    # the samples, their mask, and marching cubes' working copy of both
    check_memory(10 * nx * ny * nz, f"a level-{level} grid of {nx} x {ny} x {nz} points")
    device_data = DeviceDataset(bricks, regions, bvh, field=name, device=device)
    xs = lo[0] + (np.arange(nx) + 0.5) * h
    ys = lo[1] + (np.arange(ny) + 0.5) * h
    to_world = lambda lattice: bricks.origin_world + bricks.spacing_world * lattice  # noqa: E731
    volume = np.empty((nz, ny, nx), np.float32)
    planes = max(1, SLAB_POINTS // (nx * ny))
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    for z0 in range(0, nz, planes):
        zs = lo[2] + (np.arange(z0, min(nz, z0 + planes)) + 0.5) * h
        lattice = np.stack([np.broadcast_to(gx, (len(zs), ny, nx)),
                            np.broadcast_to(gy, (len(zs), ny, nx)),
                            np.broadcast_to(zs[:, None, None], (len(zs), ny, nx))], axis=-1)
        points = to_world(lattice.reshape(-1, 3))
        volume[z0:z0 + len(zs)] = device_data.probe_fields(
            points, reconstruction=reconstruction)[0].reshape(len(zs), ny, nx)
        if on_slab is not None:
            on_slab(len(points))
    finite = np.isfinite(volume)
    if not finite.any():
        raise ExabricksError(f"{name}: no value on the level-{level} grid")
    low, high = float(volume[finite].min()), float(volume[finite].max())
    if not low < value < high:
        raise ExabricksError(f"no iso-surface of {name} at {value:g}: on the level-{level} grid the "
                             f"field ranges over [{low:g}, {high:g}]")
    volume[~finite] = np.float32(low)  # masked out below; any finite value
    verts, faces, _, _ = marching_cubes(volume, level=value, spacing=(h, h, h), mask=finite,
                                        allow_degenerate=False)
    lattice = verts[:, ::-1].astype(np.float64) + (lo + 0.5 * h)  # (z, y, x) -> (x, y, z)
    faces = np.ascontiguousarray(faces, np.int64)  # in (x, y, z): normals toward lower values
    return Mesh(to_world(lattice), faces, level, (nx, ny, nz))


def write_mesh(path, mesh: Mesh, *, inputs=()) -> None:
    """`mesh` as a .ply (binary), .obj or .stl file by the path's suffix (trimesh),
    written atomically (exabricks.util.output)."""
    import trimesh

    from ..util.output import write_output

    suffix = str(path).lower().rsplit(".", 1)[-1] if "." in str(path) else ""
    if suffix not in ("ply", "obj", "stl"):
        raise ExabricksError(f"{path}: a mesh is written as .ply, .obj or .stl")
    shape = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)

    def write(tmp):
        with open(tmp, "wb") as f:
            shape.export(f, file_type=suffix)

    write_output(path, write, inputs=inputs)
