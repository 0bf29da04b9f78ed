"""Triangle meshes drawn with the volume (`--mesh FILE`, the scene key `meshes`;
docs/design-rendering.md, "Meshes").

A mesh file (OBJ, PLY or STL, world units) is read by trimesh and checked:
finite vertices, vertex indices in range, at least one triangle with area.
Triangles without area are dropped (marching cubes makes some where a value
equals the iso-value; they cannot be hit). The meshes of a frame are merged into one `MeshSet`: their triangles,
each tagged with its mesh, under one binned-SAH BVH (builders.bvh.build_tree,
the builder of the regions' BVH, over the triangles' boxes), which the kernels
walk for every ray (kernels/mesh.cl). A MeshSet is built once per process for
the same files (`mesh_set`), and kept in the cache of built structures
(exabricks.cache) by the files' content, checked like any input when it is
read back (`load_mesh_set`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import stat
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from .util.constants import MAX_COORDINATE, MAX_TREE_DEPTH
from .util.errors import ExabricksError
from .formats.memory import check_memory
from .util.jsonfile import kind_of
from .util import numba_compiles

numba_compiles.announce()  # its first compile on a machine says so on a terminal

log = logging.getLogger(__name__)

SUFFIXES = (".obj", ".ply", ".stl")
# Triangles of all the meshes of a frame: the ExaJet's surface is 63.2 M.
MAX_TRIANGLES = 1 << 26
# Bytes a mesh file may hold (a binary STL of MAX_TRIANGLES is 3.4 GB).
MAX_FILE_BYTES = 1 << 33
# The format of a cached MeshSet (save_mesh_set).
MESH_SET_VERSION = 3
# Edges sharper than this stay sharp in smooth shading (corner_normals), as with
# ParaView's normals filter's default feature angle.
CREASE_DEGREES = 30.0


@dataclass(frozen=True)
class Mesh:
    """vertices: float32 (V, 3) world units; faces: int32 (F, 3), every triangle with area."""

    path: str
    vertices: np.ndarray
    faces: np.ndarray
    dropped: int  # triangles without area left out


def read_mesh(path) -> Mesh:
    """The mesh in `path` (OBJ, PLY, STL), checked; ExabricksError naming the file."""
    path, size = _mesh_file(path)
    where = str(path)
    if path.suffix.lower() == ".stl":
        _check_binary_stl(path, size)
    check_memory(6 * size, where)  # the parser's text and its float64 arrays
    import io

    import trimesh

    suffix = path.suffix.lower()
    source = str(path)
    if suffix in (".obj", ".ply"):
        # The size found, not the limit: read(n) reserves n bytes up front, and 8 GiB
        # of address space is refused under a `ulimit -v` of a few GB (clusters).
        with open(path, "rb") as f:
            data = f.read(size + 1)
        if len(data) > size:
            raise ExabricksError(f"{where}: cannot read the mesh: it grew while it was read")
        source = io.BytesIO(_plain_obj(data, where) if suffix == ".obj" else _plain_ply(data, where))
    try:
        loaded = trimesh.load(source, file_type=suffix[1:], force="mesh", process=False,
                              skip_materials=True)
        vertices = np.asarray(loaded.vertices, np.float64)
        faces = np.asarray(loaded.faces)
    except ExabricksError:
        raise
    except Exception as e:  # noqa: BLE001 - a parser's error on a hostile file, whatever it is
        raise ExabricksError(f"{where}: not a readable mesh ({type(e).__name__}: {e})") from None
    return _checked(where, vertices, faces)


# Bytes beyond ASCII as '?' (bytes.translate).
_ASCII = bytes(range(128)) + b"?" * 128


def _plain_obj(data: bytes, where: str) -> bytes:
    """An OBJ's text as ASCII the parser reads: without a UTF-8 byte-order mark, other
    bytes beyond ASCII (in comments and names) as '?'; ExabricksError naming the line
    of a face with index 0 (OBJ counts from 1)."""
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    data = data.translate(_ASCII)
    for number, line in enumerate(data.splitlines(), 1):
        words = line.split()
        if words[:1] in ([b"f"], [b"l"]):
            for w in words[1:]:
                index = w.split(b"/")
                if any(i.strip() in (b"0", b"-0", b"+0") for i in index if i):
                    raise ExabricksError(f"{where}: line {number}: face index 0 in "
                                         f"{line.decode('ascii', 'replace').strip()!r} "
                                         "(OBJ indices start at 1, or -1 from the end)")
    return data


def _plain_ply(data: bytes, where: str) -> bytes:
    """A PLY's bytes with a header the parser reads: bytes beyond ASCII (comments) as
    '?', the same length; an ASCII PLY's element counts checked against its lines."""
    end = data.find(b"end_header", 0, 1 << 16)
    if not data.startswith(b"ply") or end < 0:
        return data  # the parser says what is wrong
    stop = data.find(b"\n", end)
    stop = len(data) if stop < 0 else stop + 1
    header = data[:stop].translate(_ASCII)
    lines = header.decode("ascii").splitlines()
    if any(line.split()[:2] == ["format", "ascii"] for line in lines):
        elements = [(w[1], int(w[2])) for w in (line.split() for line in lines)
                    if len(w) == 3 and w[0] == "element" and w[2].isdigit()]
        rows = [r for r in data[stop:].splitlines() if r.strip()]
        expected = sum(n for _, n in elements)
        if len(rows) < expected:
            have = len(rows)
            for name, n in elements:
                if have < n:
                    raise ExabricksError(f"{where}: the header says element {name!r} has {n:,} "
                                         f"rows, but the file holds only {have:,} rows of "
                                         "data for it")
                have -= n
    return header + data[stop:]


def _mesh_file(path) -> tuple[Path, int]:
    """(path, size) of a mesh file that may be read: its suffix, a regular file, its size."""
    path = Path(path)
    where = str(path)
    if path.suffix.lower() not in SUFFIXES:
        raise ExabricksError(f"{where}: a mesh must be an OBJ, PLY or STL file "
                             f"(found the suffix {path.suffix or 'none'!r})")
    try:
        st = path.stat()
        size = st.st_size
        if not stat.S_ISREG(st.st_mode):
            raise ExabricksError(f"{where}: cannot read the mesh: {kind_of(st.st_mode)}, not a "
                                 "regular file")
    except OSError as e:
        raise ExabricksError(f"{where}: cannot read the mesh: {e.strerror or e}") from None
    if size > MAX_FILE_BYTES:
        raise ExabricksError(f"{where}: {size:,} bytes, more than a mesh may hold "
                             f"({MAX_FILE_BYTES:,})")
    return path, size


def _check_binary_stl(path: Path, size: int) -> None:
    """A binary STL's triangle count must match its size (a lying count would make
    the parser read past the file or allocate for triangles that are not there)."""
    with open(path, "rb") as f:
        head = f.read(84)
    if head[:5].lower() == b"solid" and b"\0" not in head[:80]:
        return  # ASCII STL
    if len(head) < 84:
        raise ExabricksError(f"{path}: a binary STL needs an 84-byte header, the file has {size} bytes")
    (count,) = struct.unpack("<I", head[80:84])
    if 84 + 50 * count != size:
        raise ExabricksError(f"{path}: the binary STL says it holds {count:,} triangles, which "
                             f"take {84 + 50 * count:,} bytes, but the file has {size:,}")
    if count > MAX_TRIANGLES:
        raise ExabricksError(f"{path}: {count:,} triangles, more than {MAX_TRIANGLES:,}")


def _checked(where: str, vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ExabricksError(f"{where}: the mesh has no triangles")
    if len(faces) > MAX_TRIANGLES:
        raise ExabricksError(f"{where}: {len(faces):,} triangles, more than {MAX_TRIANGLES:,}")
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise ExabricksError(f"{where}: the mesh has no vertices")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        raise ExabricksError(f"{where}: vertex {int(np.flatnonzero(bad)[0])} is not finite "
                             f"({vertices[np.flatnonzero(bad)[0]].tolist()})")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ExabricksError(f"{where}: vertex indices must be integers")
    out = (faces < 0) | (faces >= len(vertices))
    if out.any():
        t = int(np.flatnonzero(out.any(axis=1))[0])
        raise ExabricksError(f"{where}: triangle {t} refers to vertex {int(faces[t][out[t]][0])}, "
                             f"but the mesh has {len(vertices):,} vertices")
    if np.abs(vertices).max() > MAX_COORDINATE:
        raise ExabricksError(f"{where}: vertex coordinates beyond {MAX_COORDINATE:g} do not fit "
                             "float32 arithmetic")
    v = vertices.astype(np.float32)
    f = faces.astype(np.int32)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = np.cross((b - a).astype(np.float64), (c - a).astype(np.float64))
    keep = (area != 0.0).any(axis=1)
    if not keep.any():
        raise ExabricksError(f"{where}: every one of its {len(f):,} triangles is degenerate "
                             "(no area)")
    return Mesh(where, v, f[keep], int((~keep).sum()))


@dataclass(frozen=True)
class MeshSet:
    """The triangles of a frame's meshes under one BVH, as the kernels read them.

    triangles: float32 (T, 3, 4), the three vertices of each triangle in BVH
    order (w of the first: the mesh index, as float); normals: uint32 (T, 3),
    the smooth-shading normal at each corner (`corner_normals`), octahedron
    coded (`encode_normals`); nodes: float32 (M, 2, 4),
    each node's lower and upper corner (world), their w the int32 bits of the
    node's (first, count): an inner node (count 0) has its children at first and
    first + 1, a leaf holds triangles first .. first + count - 1."""

    paths: tuple[str, ...]
    triangles: np.ndarray
    normals: np.ndarray
    nodes: np.ndarray
    dropped: int

    @property
    def links(self) -> np.ndarray:
        """int32 (M, 2): each node's (first, count)."""
        return np.ascontiguousarray(self.nodes[:, :, 3]).view(np.int32)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def stats(self) -> dict:
        return {"meshes": len(self.paths), "triangles": self.n_triangles,
                "degenerate_dropped": self.dropped, "bvh_nodes": len(self.nodes)}


def build_mesh_set(meshes) -> MeshSet:
    """One MeshSet of `meshes` (Mesh), mesh k's triangles tagged k."""
    total = sum(len(m.faces) for m in meshes)
    if total > MAX_TRIANGLES:
        raise ExabricksError(f"the meshes hold {total:,} triangles together, more than "
                             f"{MAX_TRIANGLES:,}")
    if len(meshes) == 1:
        vertices, faces = meshes[0].vertices, meshes[0].faces
    else:
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        vertices = np.concatenate([m.vertices for m in meshes])
        faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets)])
    owner = np.concatenate([np.full(len(m.faces), k, np.float32) for k, m in enumerate(meshes)])
    vertex_owner = np.concatenate([np.full(len(m.vertices), k) for k, m in enumerate(meshes)])
    triangles, nodes, order = mesh_bvh(vertices, faces, owner)
    normals = encode_normals(corner_normals(vertices, faces, vertex_owner))[order]
    return MeshSet(tuple(m.path for m in meshes), triangles, normals, nodes,
                   sum(m.dropped for m in meshes))


def mesh_bvh(vertices, faces, owner):
    """(triangles, nodes, order) of a MeshSet: the binned-SAH BVH over the faces
    (each tagged with its mesh `owner`), the triangles in its order."""
    from .builders.bvh import build_tree, tree_bounds, tree_depths

    # a triangle in an axis plane has a flat box: the tree needs volume
    pad = np.float32(1e-6) * np.float32(max(float(np.abs(vertices).max()), 1e-30))
    lo, hi = _boxes(vertices, faces, pad)
    first, count, order, _ = build_tree(lo, hi, leaf_size=4, item="triangle")
    depth = int(tree_depths(first, count).max()) + 1
    if depth > MAX_TREE_DEPTH:
        raise ExabricksError(f"the meshes' BVH is {depth} levels deep, more than the kernels' "
                             f"{MAX_TREE_DEPTH}")
    node_lo, node_hi = tree_bounds(first, count, order, lo, hi)
    triangles = _in_order(vertices, faces, owner, order)
    nodes = np.zeros((len(first), 2, 4), np.float32)
    nodes[:, 0, :3], nodes[:, 1, :3] = node_lo, node_hi
    nodes[:, :, 3] = np.stack([first, count], axis=1).astype(np.int32).view(np.float32)
    return triangles, nodes, order


def corner_normals(vertices, faces, vertex_owner=None, crease_degrees: float = CREASE_DEGREES):
    """float32 (F, 3, 3): the smooth-shading normal at each corner of each face
    (docs/design-rendering.md, "Meshes"): the unit sum, weighted by their angle at the
    corner's point, of the unit normals of the faces that meet at that point
    and turn from this face by at most `crease_degrees` (a sharper edge stays
    sharp: a cube is flat). Vertices at the same float32 position count as one
    point (an STL's unshared triangles are smooth too), unless `vertex_owner`
    (each vertex's mesh) differs: meshes do not smooth into each other."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    owner = (np.zeros(len(vertices), np.uint64) if vertex_owner is None
             else np.asarray(vertex_owner).astype(np.uint64))
    bits = (vertices.astype(np.float32) + np.float32(0.0)).view(np.uint32).astype(np.uint64)
    order, first = _group((bits[:, 0] << np.uint64(32)) | bits[:, 1],
                          (bits[:, 2] << np.uint64(32)) | owner)
    point = np.empty(len(vertices), np.int64)
    point[order] = np.cumsum(first) - 1
    corner_point = point[faces].reshape(-1)
    start, by_point = _corners_by_point(corner_point, int(point.max()) + 1 if len(point) else 0)
    return _corner_normals(vertices, faces, by_point, start, np.cos(np.radians(crease_degrees)))


@numba.njit(cache=True)
def _corners_by_point(corner_point, n_points):
    """(start, by_point): the corners (3 f + j) grouped by point, point k's at
    by_point[start[k]:start[k + 1]] (a counting sort)."""
    start = np.zeros(n_points + 1, np.int64)
    for p in corner_point:
        start[p + 1] += 1
    for k in range(n_points):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    by_point = np.empty(corner_point.shape[0], np.int64)
    for c in range(corner_point.shape[0]):
        p = corner_point[c]
        by_point[fill[p]] = c
        fill[p] += 1
    return start, by_point


def _group(high, low):
    """(order, first): an order of the keys (high, low) that puts equal keys
    together, and where each group starts in it. Sorted by a hash (a fifth of a
    lexicographic sort's time), falling back to that sort if two keys share one."""
    mixed = (high * np.uint64(0x9E3779B97F4A7C15)) ^ low
    mixed ^= mixed >> np.uint64(29)
    order = np.argsort(mixed, kind="stable")
    h, lo = high[order], low[order]
    same = (h[1:] == h[:-1]) & (lo[1:] == lo[:-1])
    if np.any((mixed[order][1:] == mixed[order][:-1]) & ~same):  # a collision
        order = np.lexsort((low, high))
        h, lo = high[order], low[order]
        same = (h[1:] == h[:-1]) & (lo[1:] == lo[:-1])
    return order, np.concatenate([[True], ~same])


@numba.njit(cache=True, parallel=True)
def _corner_normals(vertices, faces, by_point, start, cos_crease):
    """corner_normals' sums, with scalars only (no temporaries in the loops)."""
    f = faces.shape[0]
    unit = np.zeros((f, 3))
    angle = np.zeros((f, 3))
    for i in numba.prange(f):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        ux, uy, uz = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], \
            vertices[b, 2] - vertices[a, 2]
        vx, vy, vz = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], \
            vertices[c, 2] - vertices[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 0.0:
            unit[i, 0], unit[i, 1], unit[i, 2] = nx / length, ny / length, nz / length
        for j in range(3):
            p, q, r = faces[i, j], faces[i, (j + 1) % 3], faces[i, (j + 2) % 3]
            ex, ey, ez = vertices[q, 0] - vertices[p, 0], vertices[q, 1] - vertices[p, 1], \
                vertices[q, 2] - vertices[p, 2]
            gx, gy, gz = vertices[r, 0] - vertices[p, 0], vertices[r, 1] - vertices[p, 1], \
                vertices[r, 2] - vertices[p, 2]
            d = np.sqrt((ex * ex + ey * ey + ez * ez) * (gx * gx + gy * gy + gz * gz))
            if d > 0.0:
                angle[i, j] = np.arccos(min(1.0, max(-1.0, (ex * gx + ey * gy + ez * gz) / d)))
    out = np.zeros((f, 3, 3), np.float32)
    for k in numba.prange(start.shape[0] - 1):  # by point: its faces stay in cache
        for mc in range(start[k], start[k + 1]):
            i, j = by_point[mc] // 3, by_point[mc] % 3
            sx = sy = sz = 0.0
            for m in range(start[k], start[k + 1]):
                o = by_point[m] // 3
                if unit[o, 0] * unit[i, 0] + unit[o, 1] * unit[i, 1] + unit[o, 2] * unit[i, 2] \
                        >= cos_crease:
                    w = angle[o, by_point[m] % 3]
                    sx += w * unit[o, 0]
                    sy += w * unit[o, 1]
                    sz += w * unit[o, 2]
            length = np.sqrt(sx * sx + sy * sy + sz * sz)
            if length > 0.0:
                out[i, j, 0], out[i, j, 1], out[i, j, 2] = sx / length, sy / length, sz / length
            else:
                out[i, j, 0], out[i, j, 1], out[i, j, 2] = unit[i, 0], unit[i, 1], unit[i, 2]
    return out


def encode_normals(normals) -> np.ndarray:
    """uint32 (...): unit normals (..., 3) in octahedron coding (Cigolle et al.
    2014), 16 bits per coordinate (x in the low half); kernels/mesh.cl decodes."""
    n = np.ascontiguousarray(normals, np.float32)
    return _encode(n.reshape(-1, 3)).reshape(n.shape[:-1])


@numba.njit(cache=True, parallel=True)
def _encode(n):
    out = np.empty(n.shape[0], np.uint32)
    for i in numba.prange(n.shape[0]):
        x, y, z = np.float64(n[i, 0]), np.float64(n[i, 1]), np.float64(n[i, 2])
        s = abs(x) + abs(y) + abs(z)
        if s > 0.0:
            x, y, z = x / s, y / s, z / s
        if z < 0.0:
            x, y = (1.0 - abs(y)) * (1.0 if x >= 0.0 else -1.0), (1.0 - abs(x)) * (1.0 if y >= 0.0 else -1.0)
        u = np.uint32(np.round((min(1.0, max(-1.0, x)) * 0.5 + 0.5) * 65535.0))
        v = np.uint32(np.round((min(1.0, max(-1.0, y)) * 0.5 + 0.5) * 65535.0))
        out[i] = u | (v << np.uint32(16))
    return out


def decode_normals(codes) -> np.ndarray:
    """float64 (..., 3) unit normals of encode_normals' codes (the kernel's rule)."""
    codes = np.asarray(codes, np.uint32)
    u = (codes & 0xFFFF) / 65535.0 * 2.0 - 1.0
    v = (codes >> 16) / 65535.0 * 2.0 - 1.0
    z = 1.0 - np.abs(u) - np.abs(v)
    t = np.maximum(-z, 0.0)
    x = u - np.where(u >= 0.0, t, -t)
    y = v - np.where(v >= 0.0, t, -t)
    n = np.stack([x, y, z], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


@numba.njit(cache=True, parallel=True)
def _boxes(vertices, faces, pad):
    """Each triangle's box, float32 (T, 3) lower and upper, at least `pad` thick."""
    n = faces.shape[0]
    lo = np.empty((n, 3), np.float32)
    hi = np.empty((n, 3), np.float32)
    for i in numba.prange(n):
        for a in range(3):
            x0 = vertices[faces[i, 0], a]
            x1 = vertices[faces[i, 1], a]
            x2 = vertices[faces[i, 2], a]
            low = min(x0, min(x1, x2))
            lo[i, a] = low
            hi[i, a] = max(max(x0, max(x1, x2)), low + pad)
    return lo, hi


@numba.njit(cache=True, parallel=True)
def _in_order(vertices, faces, owner, order):
    """MeshSet.triangles: triangle order[k] at k, its mesh in the first vertex's w."""
    n = order.shape[0]
    out = np.zeros((n, 3, 4), np.float32)
    for k in numba.prange(n):
        t = order[k]
        for j in range(3):
            for a in range(3):
                out[k, j, a] = vertices[faces[t, j], a]
        out[k, 0, 3] = owner[t]
    return out


def mesh_set(paths) -> MeshSet:
    """The MeshSet of the mesh files `paths`, built once per process for files whose
    size and modification time have not changed."""
    keys = []
    for p in paths:
        try:
            st = os.stat(p)
            keys.append((str(p), str(Path(p).resolve()), st.st_size, st.st_mtime_ns))
        except OSError as e:
            raise ExabricksError(f"{p}: cannot read the mesh: {e.strerror or e}") from None
    return _mesh_set(tuple(keys))


@functools.lru_cache(maxsize=4)
def _mesh_set(keys) -> MeshSet:
    from . import cache

    from .formats.provenance import sha256_file

    paths = [_mesh_file(k[0])[0] for k in keys]
    store = cache.Cache(cache.default_root())
    digests = [sha256_file(p) for p in paths]
    k = cache.mesh_key(paths, digests)
    # The meshes' content as one hash: what the entry records beside its key.
    source_sha256 = hashlib.sha256("\n".join(digests).encode()).hexdigest()
    found = store.paths(k, cache.MESH_FILES)
    if found is not None:
        try:
            meshes = load_mesh_set(found[0], paths, k, source_sha256)
            log.debug("%s: the meshes' BVH from the cache", found[0])
            return meshes
        except ExabricksError as e:
            log.warning("a damaged cache entry of meshes (%s): building it again", e)
            store.drop(k)
    meshes = build_mesh_set([read_mesh(p) for p in paths])
    about = {"path": ", ".join(str(p.resolve()) for p in paths),
             "options": {"kind": "meshes", "triangles": meshes.n_triangles}}
    try:
        store.put(k, lambda d: save_mesh_set(meshes, d / cache.MESH_FILES[0],
                                             cache.record(k, source_sha256)),
                  about, cache.MESH_FILES)
    except (ExabricksError, OSError) as e:  # the frame goes on without the cache
        log.warning("the meshes' BVH is not cached: %s", e)
    return meshes


def save_mesh_set(meshes: MeshSet, path: Path, record: dict | None = None) -> None:
    """`meshes` as an uncompressed .npz (MESH_SET_VERSION); `record`: the cache
    entry's key and content hash (exabricks.cache.record), as JSON text."""
    extra = {} if record is None else {"cache": np.str_(json.dumps(record, sort_keys=True))}
    with open(path, "wb") as f:
        np.savez(f, version=np.int64(MESH_SET_VERSION), triangles=meshes.triangles,
                 normals=meshes.normals, nodes=meshes.nodes, dropped=np.int64(meshes.dropped),
                 **extra)


def load_mesh_set(path: Path, paths, k: str | None = None,
                  source_sha256: str | None = None) -> MeshSet:
    """The MeshSet of the mesh files `paths` that save_mesh_set wrote to `path`,
    checked as any input a kernel walks (ExabricksError naming `path`): stored,
    not compressed, arrays no larger than the file; finite triangles of known
    meshes; a tree over them (formats.checks.check_tree) with finite boxes; and,
    given the entry key `k`, that it records `k` and `source_sha256`
    (exabricks.cache.check: an entry swapped with another's is refused)."""
    from types import SimpleNamespace

    from . import cache
    from .formats.checks import check_tree

    where = str(path)
    try:
        size = os.path.getsize(path)
        with zipfile.ZipFile(path) as z:
            members = z.infolist()
        if (any(m.compress_type != zipfile.ZIP_STORED for m in members)
                or sum(m.file_size for m in members) > size):
            raise ExabricksError(f"{where}: not a stored .npz of meshes")
        with np.load(path, allow_pickle=False) as npz:
            names = ("version", "triangles", "normals", "nodes", "dropped")
            if not set(names) <= set(npz.files) <= {*names, "cache"}:
                raise ExabricksError(f"{where}: holds {sorted(npz.files)}, not a mesh set")
            version, triangles, normals, nodes, dropped = (npz[n] for n in names)
            recorded = npz["cache"] if "cache" in npz.files else None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise ExabricksError(f"{where}: not a readable mesh set ({e})") from None
    if version.shape != () or int(version) != MESH_SET_VERSION:
        raise ExabricksError(f"{where}: mesh set version {version}, expected {MESH_SET_VERSION}")
    t = triangles.shape[0] if triangles.ndim == 3 else 0
    if (triangles.dtype != np.float32 or triangles.shape != (t, 3, 4) or not 1 <= t <= MAX_TRIANGLES
            or nodes.dtype != np.float32 or nodes.ndim != 3 or nodes.shape[1:] != (2, 4)
            or not 1 <= nodes.shape[0] <= 2 * t or dropped.shape != () or int(dropped) < 0
            or normals.dtype != np.uint32 or normals.shape != (t, 3)):
        raise ExabricksError(f"{where}: arrays of shapes {triangles.shape}, {nodes.shape} are not "
                             "a mesh set")
    xyz = triangles[:, :, :3]
    owner = triangles[:, 0, 3]
    if not (np.all(np.abs(xyz) <= MAX_COORDINATE) and np.all(owner == np.round(owner))
            and owner.min() >= 0 and owner.max() < len(paths)):
        raise ExabricksError(f"{where}: triangles with coordinates that are not finite or meshes "
                             f"other than the {len(paths)} asked for")
    box = nodes[:, :, :3]
    if not (np.all(np.abs(box) <= np.float32(np.finfo(np.float32).max))
            and np.all(box[:, 0] <= box[:, 1])):
        raise ExabricksError(f"{where}: mesh BVH boxes that are not finite or are inverted")
    meshes = MeshSet(tuple(str(p) for p in paths), triangles, normals, nodes, int(dropped))
    check_tree(meshes.links[:, 0], meshes.links[:, 1], t, where, "mesh BVH", "triangle")
    if k is not None:
        try:
            meta = {"cache": json.loads(str(recorded))} if recorded is not None \
                and recorded.shape == () and recorded.dtype.kind == "U" else {}
        except ValueError:
            meta = {}
        cache.check([SimpleNamespace(meta=meta)], [where], k, source_sha256)
    return meshes
