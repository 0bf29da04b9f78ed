"""Triangle meshes (`--mesh`, scene key `meshes`; docs/design-rendering.md, "Meshes"):
hostile mesh files end in one error line; the kernel's watertight ray-triangle
distances against float64; rays through a closed mesh's edges and vertices
never slip through; an analytic sphere's depth against its icosphere mesh; an
opaque mesh ends the volume exactly where it is hit (the frame equals the
volume clipped there, composited over the mesh); translucent meshes composite
in order; the scene file and its flags. Every test runs on every OpenCL device
present."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
import trimesh

from exabricks.device import kernel_abi, opencl
from exabricks.engine import variants
from exabricks.engine.renderer import Renderer
from exabricks.util.errors import ExabricksError
from exabricks.mesh import build_mesh_set, read_mesh
from exabricks.scene.model import Clip, Lighting, MeshLayer, Scene, Settings, VolumeLayer
from exabricks.picture.transfer_function import TransferFunction

from helpers import AMREX, GERRIS, assert_one_error_line, built_scene, device_param, run_cli
from helpers.meshes import icosphere_file


def write_text(path, text):
    path.write_text(text)
    return path


HOSTILE = {
    "nan.obj": ("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 0 is not finite"),
    "range.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "not a readable mesh"),
    "degenerate.obj": ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "degenerate"),
    "no-faces.obj": ("v 0 0 0\nv 1 0 0\nv 2 0 0\n", "no triangles"),
    "empty.ply": ("", "not a readable mesh"),
    "truncated.ply": ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n",
                      "the header says element 'vertex' has 3 rows"),
    "mesh.json": ("{}", "OBJ, PLY or STL"),
}


def hostile_file(tmp_path, name):
    """Write hostile mesh file `name`; returns (path, what its error line says)."""
    path = tmp_path / name
    if name == "lying.stl":  # says 1000 triangles, holds one
        tri = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
        path.write_bytes(b"\0" * 80 + struct.pack("<I", 1000) + tri)
        return path, "says it holds 1,000 triangles"
    if name == "huge.stl":  # a count beyond the cap, on a file of that size (sparse)
        count = (1 << 26) + 1
        with open(path, "wb") as f:
            f.write(b"\0" * 80 + struct.pack("<I", count))
            f.truncate(84 + 50 * count)
        return path, "more than 67,108,864"
    text, needle = HOSTILE[name]
    return write_text(path, text), needle


@pytest.mark.parametrize("name", [*HOSTILE, "lying.stl", "huge.stl"])
def test_hostile_mesh_files_are_refused_with_their_name(tmp_path, name):
    path, needle = hostile_file(tmp_path, name)
    with pytest.raises(ExabricksError) as e:
        read_mesh(path)
    assert str(path) in str(e.value) and needle in str(e.value)


@pytest.mark.parametrize("name", ["lying.stl", pytest.param("nan.obj", marks=pytest.mark.slow),
                                  pytest.param("truncated.ply", marks=pytest.mark.slow)])
def test_a_hostile_mesh_file_ends_render_in_one_error_line(tmp_path, name):
    path, needle = hostile_file(tmp_path, name)
    out = tmp_path / "out.png"
    proc = run_cli("render", GERRIS, "-o", out, "--size", 16, 16, "--mesh", path)
    assert_one_error_line(proc, str(path), needle)
    assert not out.exists()


def test_a_small_mesh_renders_under_a_clusters_address_space_limit(tmp_path):
    """`ulimit -v 4000000` (4 GB, as many clusters set): a 36-byte OBJ once failed
    with "out of memory", its read reserving the 8 GiB a mesh file may hold. A
    plain render fits that limit, PoCL's reservations included."""
    import resource
    import subprocess
    import sys

    limit = 4_000_000_000

    def limited():
        hard = resource.getrlimit(resource.RLIMIT_AS)[1]
        resource.setrlimit(resource.RLIMIT_AS, (limit if hard == resource.RLIM_INFINITY
                                                else min(limit, hard), hard))

    mesh = write_text(tmp_path / "t.obj", "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 3\n")
    out = tmp_path / "out.png"
    proc = subprocess.run([sys.executable, "-m", "exabricks.cli.main", "render", GERRIS, "-o", out,
                           "--size", "16", "16", "--mesh", mesh],
                          capture_output=True, text=True, preexec_fn=limited, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_size > 0


def test_degenerate_triangles_among_others_are_dropped(tmp_path):
    path = write_text(tmp_path / "m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    mesh = read_mesh(path)
    assert len(mesh.faces) == 1 and mesh.dropped == 1
    assert build_mesh_set([mesh]).stats()["degenerate_dropped"] == 1


HIT_SOURCE = """#include "mesh.cl"
__kernel void hits(__global const float4 *tri, int n, int each, __global const float *rays,
                   __global float *t)
{
    int i = get_global_id(0);
    eb_meshes m;
    m.tri = tri;
    float3 org = vload3(2 * i, rays), dir = vload3(2 * i + 1, rays);
    eb_mesh_ray r = eb_mesh_ray_of(org, dir);
    float best = EB_INF;
    for (int k = each ? i : 0; k < (each ? i + 1 : n); ++k)
        best = fmin(best, eb_triangle_hit(&m, k, &r, 0.0f, EB_INF));
    t[i] = best;
}
"""


def device_hits(device, triangles, origins, directions, each=False) -> np.ndarray:
    """The nearest hit distance of each ray over `triangles` (T, 3, 3) by the kernel
    (`each`: ray i against triangle i only)."""
    import pyopencl as cl

    context, queue = opencl.context_for(opencl.choose_device(device))
    program = cl.Program(context, kernel_abi.header() + HIT_SOURCE).build(
        options=opencl.build_options(variants.variant().defines))
    tri = np.zeros((len(triangles), 3, 4), np.float32)
    tri[..., :3] = triangles
    rays = np.stack([origins, directions], axis=1).astype(np.float32)
    out = np.empty(len(origins), np.float32)
    buf = opencl.empty_buffer(queue, out.nbytes)
    opencl.kernel(program, "hits")(queue, (len(origins),), None, opencl.to_device(queue, tri),
                                   np.int32(len(triangles)), np.int32(each),
                                   opencl.to_device(queue, rays), buf)
    opencl.read_back(queue, buf, out)
    return out


def reference_hit(tri, org, d) -> float:
    """Möller-Trumbore in float64: the distance along d, or inf."""
    a, b, c = (np.asarray(v, np.float64) for v in tri)
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = e1 @ p
    if det == 0:
        return np.inf
    s = org - a
    u = (s @ p) / det
    q = np.cross(s, e1)
    v = (d @ q) / det
    t = (e2 @ q) / det
    return t if u >= 0 and v >= 0 and u + v <= 1 and t > 0 else np.inf


@device_param
def test_ray_triangle_distances_match_float64(device, rng):
    """Random triangles, each with a ray aimed near it: the kernel's distance is the
    float64 Möller-Trumbore one, and hit or miss agree but for rays within float
    rounding of an edge."""
    n = 2000
    tris = rng.uniform(-1, 1, (n, 3, 3))
    org = rng.uniform(-3, 3, (n, 3))
    d = tris.mean(axis=1) + rng.uniform(-0.4, 0.4, (n, 3)) - org
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = device_hits(device, tris, org, d, each=True)
    want = np.array([reference_hit(tris[i], org[i], d[i]) for i in range(n)])
    hit = np.isfinite(want)
    assert 0.3 * n < hit.sum() < 0.95 * n
    both = hit & np.isfinite(got)
    np.testing.assert_allclose(got[both], want[both], rtol=1e-5, atol=1e-6)
    assert (hit != np.isfinite(got)).sum() <= 2


@device_param
def test_rays_through_edges_and_vertices_of_a_closed_mesh_never_slip_through(device):
    """Every ray from outside toward a vertex or an edge midpoint of an icosphere,
    on the side facing it (not grazing the silhouette), hits it."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    tris = sphere.vertices[sphere.faces]
    targets = np.concatenate([sphere.vertices, sphere.vertices[sphere.edges_unique].mean(axis=1)])
    origins = np.zeros_like(targets) + [0.31, -0.17, 4.0]
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    facing = np.einsum("ij,ij->i", targets / np.linalg.norm(targets, axis=1, keepdims=True), d) < -0.1
    assert facing.sum() > 500
    t = device_hits(device, tris, origins[facing], d[facing])
    assert np.isfinite(t).all()


def scene_of(field, camera, tf, meshes=(), clip=None, size=48, **settings):
    return Scene(camera=camera, volumes=(VolumeLayer(field, tf),) if tf is not None else (),
                 meshes=tuple(meshes), clip=clip or Clip(), lighting=Lighting(shading="none"),
                 settings=Settings(width=size, height=size, jitter=False, **settings))


def test_corner_normals_are_smooth_within_the_crease_angle_and_sharp_beyond():
    """An icosphere's corner normals lie within a degree of the sphere's radius, for
    its shared vertices as for an STL's unshared ones; every corner of a cube
    (90 degree edges) keeps its face's normal; the octahedron code keeps a
    normal to 0.02 degree (16 bits a coordinate)."""
    from exabricks.mesh import corner_normals, decode_normals, encode_normals

    sphere = trimesh.creation.icosphere(subdivisions=3)
    corners = sphere.vertices[sphere.faces]
    radial = corners / np.linalg.norm(corners, axis=-1, keepdims=True)
    smooth = corner_normals(sphere.vertices, sphere.faces)
    assert np.degrees(np.arccos(np.clip((smooth * radial).sum(-1), -1, 1))).max() < 1.0
    unshared = corner_normals(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3))
    np.testing.assert_array_equal(unshared, smooth)
    box = trimesh.creation.box()
    np.testing.assert_allclose(corner_normals(box.vertices, box.faces),
                               np.repeat(box.face_normals[:, None], 3, axis=1), atol=1e-7)
    back = decode_normals(encode_normals(smooth))
    assert np.degrees(np.arccos(np.clip((back * smooth).sum(-1), -1, 1))).max() < 0.02


@device_param
def test_smooth_shading_interpolates_the_corner_normals(device, tmp_path):
    """An opaque coarse icosphere under the headlight: each pixel is the float64
    shading of the corner normals interpolated at its ray's nearest hit
    (Moller-Trumbore over every triangle), not its facet's flat normal."""
    from exabricks.mesh import decode_normals, mesh_set

    bricks, regions, bvh, field, camera, tf = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.45 * float((hi - lo).min()), 2)
    r = Renderer(bricks, regions, bvh, field=field, device=device)
    scene = scene_of(field, camera, None, [MeshLayer(str(path), color=(1.0, 1.0, 1.0))])
    got = r.render_scene(scene.replace(lighting=Lighting(shading="headlight"))).rgba
    meshes = mesh_set((str(path),))
    tri = meshes.triangles[:, :, :3].astype(np.float64)
    normals = decode_normals(meshes.normals)
    origins, dirs = camera.rays(48, 48)
    o, d = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None], e2[None])
    det = (e1[None] * p).sum(-1)
    s = o[:, None] - a[None]
    u = (s * p).sum(-1) / det
    q = np.cross(s, e1[None])
    v = (d[:, None] * q).sum(-1) / det
    t = (e2[None] * q).sum(-1) / det
    t = np.where((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0), t, np.inf)
    k = np.argmin(t, axis=1)
    hit = np.isfinite(t[np.arange(len(k)), k])
    b1, b2 = u[np.arange(len(k)), k], v[np.arange(len(k)), k]
    ns = (1 - b1 - b2)[:, None] * normals[k, 0] + b1[:, None] * normals[k, 1] + b2[:, None] * normals[k, 2]
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    flat = np.cross(e1, e2)[k]
    flat /= np.linalg.norm(flat, axis=1, keepdims=True)
    light = lambda n: 0.3 + 0.7 * np.abs((n * d).sum(1))
    want, facets = light(ns)[hit], light(flat)[hit]
    pixels = got.reshape(-1, 4)[hit]
    assert hit.sum() > 400
    np.testing.assert_allclose(pixels[:, :3], np.repeat(want[:, None], 3, axis=1), atol=2e-4)
    assert np.abs(want - facets).max() > 0.02  # the facets would show


@device_param
def test_an_opaque_sphere_mesh_has_the_analytic_sphere_depth(device, tmp_path):
    """Depth of an opaque icosphere against the exact sphere: each hit lies between
    the sphere's and that of the sphere shrunk by the facets' largest gap to it
    (the sagitta); rays that miss the sphere miss the mesh."""
    bricks, regions, bvh, field, camera, tf = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    centre, radius = (lo + hi) / 2, 0.45 * float((hi - lo).min())
    path, sphere = icosphere_file(tmp_path, centre, radius)
    r = Renderer(bricks, regions, bvh, field=field, device=device)
    result = r.render_scene(scene_of(field, camera, None, [MeshLayer(str(path))], depth=True))
    origin, forward, du, dv = (np.asarray(v, np.float64) for v in camera.frame(48, 48))
    rows, cols = np.mgrid[0:48, 0:48]
    u = 2 * (cols + 0.5) / 48 - 1
    v = 1 - 2 * (rows + 0.5) / 48
    d = forward + u[..., None] * du + v[..., None] * dv
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = origin - centre
    b = d @ oc
    disc = b * b - (oc @ oc - radius * radius)
    exact = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    inside = disc > 0
    # a facet's farthest point from the sphere is its circumcentre
    a, b_, c = (sphere.vertices[sphere.faces[:, k]] for k in range(3))
    sides = [np.linalg.norm(x - y, axis=1) for x, y in ((a, b_), (b_, c), (c, a))]
    circum = (sides[0] * sides[1] * sides[2] / (4 * sphere.area_faces)).max()
    sagitta = radius - np.sqrt(radius ** 2 - circum ** 2)
    # the mesh lies between the sphere and the sphere of radius - sagitta: its hit
    # lies between the two spheres' (rays that reach the inner one)
    inner_disc = b * b - (oc @ oc - (radius - sagitta) ** 2)
    inside &= inner_disc > 0
    assert inside.sum() > 300
    inner = -b - np.sqrt(np.maximum(inner_disc, 0))
    depth = result.depth[inside].astype(np.float64)
    assert np.all(depth >= exact[inside] - 1e-5 * radius)
    assert np.all(depth <= inner[inside] + 1e-5 * radius)
    assert (depth - exact[inside]).max() > 0.3 * sagitta  # the facets show
    assert np.isinf(result.depth[disc < -(0.05 * radius) ** 2]).all()
    assert np.allclose(result.rgba[inside][:, 3], 1.0)


def bricks_bounds(bricks):
    from exabricks import schema

    return schema.world_bounds(bricks)


def plane_mesh(tmp_path, point, normal, size):
    """Two triangles: a square of side `size` centred on `point`, normal `normal`."""
    n = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    a = np.cross(n, [1, 0, 0] if abs(n[0]) < 0.9 else [0, 1, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    corners = [point + size * (s * a + t * b) for s, t in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    mesh = trimesh.Trimesh(vertices=corners, faces=[[0, 1, 2], [0, 2, 3]], process=False)
    path = tmp_path / "plane.obj"
    mesh.export(path)
    return path


@device_param
@pytest.mark.parametrize("packets", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_an_opaque_mesh_ends_the_volume_where_it_is_hit(device, tmp_path, packets):
    """The frame with an opaque plane mesh through the data equals the volume
    clipped at that plane (the half toward the camera) composited over the mesh's
    colour: the volume in front is integrated exactly up to the hit."""
    bricks, regions, bvh, field, camera, tf = built_scene(AMREX, "phi")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    centre = (lo + hi) / 2
    normal = np.asarray(camera.position, np.float64) - centre  # facing the camera
    path = plane_mesh(tmp_path, centre, normal, 10 * float((hi - lo).max()))
    faint = TransferFunction(tf.rgb_points, tf.alpha_points * [[1, 0.3]])
    r = Renderer(bricks, regions, bvh, field=field, device=device)
    if r.packets != packets:
        r = r.with_packets(packets)
    colour = (0.2, 0.5, 0.9)
    # no early termination: the volume alone would stop some rays before the mesh
    got = r.render_scene(scene_of(field, camera, faint, [MeshLayer(str(path), color=colour)],
                                  max_opacity=1.0))
    front = r.render_scene(scene_of(field, camera, faint, max_opacity=1.0,
                                    clip=Clip(planes=((tuple(centre), tuple(normal)),))))
    want = front.rgba.copy()
    want[..., :3] += (1 - front.rgba[..., 3:4]) * np.asarray(colour, np.float32)
    want[..., 3] = 1.0
    assert 0.05 < front.rgba[..., 3].mean() < 0.95
    np.testing.assert_allclose(got.rgba, want, rtol=0, atol=2e-6)


@device_param
def test_translucent_meshes_composite_in_distance_order(device, tmp_path):
    """Two translucent planes in front of nothing: C = a1 c1 + (1 - a1) a2 c2 with
    the nearer first, whichever order the scene lists them in."""
    bricks, regions, bvh, field, camera, tf = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    centre = (lo + hi) / 2
    towards = np.asarray(camera.position, np.float64) - centre
    towards /= np.linalg.norm(towards)
    big = 10 * float((hi - lo).max())
    near = plane_mesh(tmp_path / "near", centre + 0.1 * towards, towards, big) \
        if (tmp_path / "near").mkdir() is None else None
    far = plane_mesh(tmp_path / "far", centre - 0.1 * towards, towards, big) \
        if (tmp_path / "far").mkdir() is None else None
    r = Renderer(bricks, regions, bvh, field=field, device=device)
    layers = [MeshLayer(str(far), color=(0, 0, 1), opacity=0.5),
              MeshLayer(str(near), color=(1, 0, 0), opacity=0.25)]
    got = r.render_scene(scene_of(field, camera, None, layers, size=16)).rgba
    want = np.array([0.25, 0, 0.75 * 0.5, 0.25 + 0.75 * 0.5], np.float32)
    np.testing.assert_allclose(got.reshape(-1, 4), np.broadcast_to(want, (256, 4)), atol=1e-6)


@pytest.mark.slow
def test_the_scene_file_and_its_flags(tmp_path):
    """meshes in a scene file (paths relative to it, a colour field), --mesh-color and
    --mesh-opacity on top; the image's metadata holds the scene read back."""
    bricks, *_ = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.2 * float((hi - lo).min()), 3)
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({"meshes": [{"path": "sphere.ply", "opacity": 0.5,
                                             "color": {"field": "T", "colormap": "viridis"}}]}))
    out = tmp_path / "a.png"
    run_cli("render", GERRIS, "-o", out, "--size", 32, 32, "--scene", scene, check=0)
    from exabricks.film.image import Image

    meta = Image.read(out).metadata
    assert meta["scene"]["meshes"][0]["path"] == str(path) and meta["settings"]["meshes"]["triangles"] > 0
    run_cli("render", GERRIS, "-o", out, "--size", 32, 32, "--scene", scene, "--mesh-color",
            "1,0,0", "--mesh-opacity", 1, check=0)
    mesh = Image.read(out).metadata["scene"]["meshes"][0]
    assert mesh["color"] == [1.0, 0.0, 0.0] and mesh["opacity"] == 1.0
    scene.write_text(json.dumps({"meshes": [{"path": "nothing.ply"}]}))
    assert_one_error_line(run_cli("render", GERRIS, "-o", out, "--scene", scene),
                          "meshes[0].path", "nothing.ply")


def test_meshes_beyond_the_triangle_cap_are_refused(monkeypatch):
    import exabricks.mesh as mesh_module

    sphere = trimesh.creation.icosphere(subdivisions=1)
    mesh = mesh_module._checked("s", np.asarray(sphere.vertices), np.asarray(sphere.faces))
    monkeypatch.setattr(mesh_module, "MAX_TRIANGLES", 100)
    with pytest.raises(ExabricksError, match="more than 100"):
        build_mesh_set([mesh, mesh])


@pytest.mark.slow
def test_a_budget_of_several_domains_refuses_meshes(tmp_path):
    """A frame split by space cannot hold a mesh (it reaches beyond the data): one
    error line; a budget that holds the data in one domain draws the same frame."""
    bricks, *_ = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.3 * float((hi - lo).min()), 3)
    args = ["render", GERRIS, "--size", 48, 48, "--mesh", path, "--mesh-opacity", 0.5]
    out = tmp_path / "x.png"
    assert_one_error_line(run_cli(*args, "-o", out, "--memory-budget", "3M"),
                          "meshes need the whole dataset at once", "domains")
    assert not out.exists()
    run_cli(*args, "-o", tmp_path / "a.png", check=0)
    run_cli(*args, "-o", tmp_path / "b.png", "--memory-budget", "300M", check=0)
    from exabricks.film.image import Image

    np.testing.assert_array_equal(Image.read(tmp_path / "a.png").rgba,
                                  Image.read(tmp_path / "b.png").rgba)


def test_the_viewer_draws_only_the_meshes_it_was_started_with(tmp_path):
    """A scene from the page may name no file but the viewer's own meshes: another
    mesh file is refused with one line (the page could otherwise read any file)."""
    import exabricks as eb
    from exabricks.viewer.session import Session

    bricks, *_ = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.2 * float((hi - lo).min()), 2)
    session = Session(eb.open(GERRIS), options={"mesh": [str(path)], "size": (32, 32)})
    doc = json.loads(json.dumps(session.doc))
    assert doc["meshes"][0]["path"] == str(path)
    doc["meshes"][0]["opacity"] = 0.5
    assert session.check(doc).meshes[0].opacity == 0.5
    other = tmp_path / "other.obj"
    write_text(other, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    doc["meshes"][0]["path"] = str(other)
    with pytest.raises(ExabricksError, match=r"meshes\[0\].path: the viewer draws only"):
        session.check(doc)


@device_param
def test_a_mesh_coloured_by_a_field_shows_the_field_at_the_hit(device, tmp_path):
    """--mesh-color-field: an opaque plane through the Gerris data, unshaded, shows at
    each pixel the colour map of T probed where its ray meets the plane (and the
    fixed colour where T has no data)."""
    import exabricks as eb
    from exabricks.scene import scene_from_options

    bricks, regions, bvh, field, camera, tf = built_scene(GERRIS, "T")
    lo, hi = (np.asarray(b, np.float64) for b in bricks_bounds(bricks))
    centre = (lo + hi) / 2
    normal = np.asarray(camera.position, np.float64) - centre
    path = plane_mesh(tmp_path, centre, normal, 10 * float((hi - lo).max()))
    scene = scene_from_options(bricks, flags={
        "mesh": [str(path)], "mesh_color_field": "T", "volume": False, "shading": "none",
        "size": (40, 40), "jitter": False, "position": camera.position,
        "look_at": camera.look_at, "up": camera.up, "fovy": camera.fovy})
    mesh = scene.meshes[0]
    assert mesh.color_field == "T" and mesh.color == (0.9, 0.9, 0.9)
    got = Renderer(bricks, regions, bvh, field=field, device=device).render_scene(scene).rgba
    origin, forward, du, dv = (np.asarray(v, np.float64) for v in camera.frame(40, 40))
    rows, cols = np.mgrid[0:40, 0:40]
    d = (forward + (2 * (cols + 0.5) / 40 - 1)[..., None] * du
         + (1 - 2 * (rows + 0.5) / 40)[..., None] * dv)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    t = ((centre - origin) @ normal) / (d @ normal)
    hits = origin + t[..., None] * d
    value = eb.probe(GERRIS, hits.reshape(-1, 3), "T", device=device).reshape(40, 40)
    has = np.isfinite(value)
    assert 0.2 < has.mean() < 1.0
    want = np.where(has[..., None], mesh.colormap.evaluate(np.where(has, value, 0))[..., :3], 0.9)
    # float32 hit points against float64 ones, through T's gradient and the colour map
    np.testing.assert_allclose(got[..., :3], want, rtol=0, atol=5e-5)
    assert np.allclose(got[..., 3], 1.0)


def test_the_bvh_is_cached_by_content_and_checked_when_read_back(tmp_path, monkeypatch, caplog):
    """A second process (here: the in-process memo cleared) reads the meshes' BVH
    from the cache: the same arrays, nothing built. A damaged or crafted entry
    (truncated, compressed, a child out of range, a mesh not asked for) is
    refused by its checks, with a warning, and built again; a changed file misses."""
    import zipfile

    from exabricks import cache, mesh

    monkeypatch.setenv("EXABRICKS_CACHE", str(tmp_path / "cache"))
    path, _ = icosphere_file(tmp_path, (0.0, 0.0, 0.0), 1.0, 3)
    mesh._mesh_set.cache_clear()
    built = mesh.mesh_set((str(path),))
    entry = cache.Cache(tmp_path / "cache").paths(cache.mesh_key([path]), cache.MESH_FILES)[0]

    def again():
        mesh._mesh_set.cache_clear()
        return mesh.mesh_set((str(path),))

    def same(a, b):
        np.testing.assert_array_equal(a.triangles, b.triangles)
        np.testing.assert_array_equal(a.nodes, b.nodes)
        np.testing.assert_array_equal(a.normals, b.normals)
        assert a.dropped == b.dropped

    with monkeypatch.context() as m:
        m.setattr(mesh, "build_mesh_set", lambda meshes: pytest.fail("built again"))
        same(again(), built)
    good = entry.read_bytes()

    def crafted(**change):
        arrays = {"version": np.int64(mesh.MESH_SET_VERSION), "triangles": built.triangles,
                  "normals": built.normals, "nodes": built.nodes, "dropped": np.int64(0), **change}
        with open(entry, "wb") as f:
            np.savez(f, **arrays)

    nodes = built.nodes.copy()
    nodes[0, 1, 3] = np.int32(0).view(np.float32)  # the root an inner node ...
    nodes[0, 0, 3] = np.int32(len(nodes)).view(np.float32)  # ... with children beyond the tree
    stranger = built.triangles.copy()
    stranger[5, 0, 3] = 3.0  # a mesh not asked for
    damage = [lambda: entry.write_bytes(good[: len(good) // 2]),
              lambda: crafted(nodes=nodes), lambda: crafted(triangles=stranger),
              lambda: crafted(version=np.int64(7))]

    def compressed():
        with zipfile.ZipFile(entry, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("triangles.npy", b"\0" * 1000)

    for spoil, needle in zip(damage + [compressed], ["not a readable mesh set", "children",
                                                     "meshes other than", "version 7", "stored"]):
        spoil()
        caplog.clear()
        same(again(), built)
        assert any(needle in r.getMessage() and "damaged" in r.getMessage()
                   for r in caplog.records), (needle, [r.getMessage() for r in caplog.records])
        assert entry.read_bytes() == good  # built again and put back
    old = cache.mesh_key([path])
    icosphere_file(tmp_path, (0.5, 0.0, 0.0), 1.0, 3)  # the same path, new content
    assert cache.mesh_key([path]) != old
    assert not np.array_equal(again().triangles, built.triangles)
