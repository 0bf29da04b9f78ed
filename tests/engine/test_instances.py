"""Instances (`--mirror AXIS POSITION`, scene key `instances`; docs/design-rendering.md,
"Instances"): a mirrored or moved copy of the data and the meshes is exactly
the frame of the untouched data seen by the camera taken back by its map (for a
mirror, a camera whose image is the columns reversed), composited in
visibility order; copies that overlap mix their media (their extinctions add);
frames split by space are refused with one line; the flag and the scene key. Every frame test runs on every
OpenCL device present."""

from __future__ import annotations

import numpy as np
import pytest

from exabricks import schema
from exabricks.picture.camera import Camera
from exabricks.engine import instances
from exabricks.engine.renderer import Renderer
from exabricks.util.errors import ExabricksError
from exabricks.engine.partition import needs_image_mode
from exabricks.scene import field_range, scene_from_options, scene_to_dict
from exabricks.scene.model import (Clip, Instance, IsoSurface, Lighting, MeshLayer, Scene, Settings,
                                   Slice, VolumeLayer)

from helpers import AMREX, GERRIS, assert_one_error_line, built_scene, device_param, run_cli
from helpers.meshes import icosphere_file

SIZE = 64  # a power of two: the columns u and -u of a reversed frame are exact


@pytest.fixture(scope="module")
def amrex():
    bricks, regions, bvh, field, _, tf = built_scene(AMREX, "phi")
    lo, hi = (np.asarray(b, np.float64) for b in schema.world_bounds(bricks))
    return bricks, regions, bvh, field, tf, lo, hi


def over(front, back):
    return front + (1.0 - front[..., 3:4]) * back


def frame(renderer, camera, field, tf, *, meshes=(), clip=None, inst=(), spp=1, sample=None,
          depth=False, isosurfaces=(), slices=()):
    scene = Scene(camera=camera, volumes=(VolumeLayer(field, tf),), meshes=tuple(meshes),
                  clip=clip or Clip(), isosurfaces=tuple(isosurfaces), slices=tuple(slices),
                  instances=tuple(inst), lighting=Lighting(shading="headlight", specular=0.3),
                  settings=Settings(width=SIZE, height=SIZE, jitter=False, max_opacity=1.0, spp=spp,
                                    depth=depth))
    return renderer.render_scene(scene, sample=sample)


def cells_box(lo, hi):
    return Clip(box=(tuple(lo), tuple(hi)))


@device_param
# with surfaces a frame of instances builds a program variant of its own (domain and
# surfaces): the slow suite runs those
@pytest.mark.parametrize("extra", ["volume", pytest.param("mesh", marks=pytest.mark.slow),
                                   pytest.param("surfaces", marks=pytest.mark.slow)])
def test_a_mirror_is_the_frame_of_the_mirrored_camera_reversed(amrex, device, extra, tmp_path):
    """The data mirrored across its face x = 0, seen from the data's side: the frame
    of the data (cut at its cells' box) over the frame of the mirrored camera with
    its columns reversed (its slice mirrored too); with a translucent mesh, or an
    iso-surface and a slice through the copy (ambient occlusion draws its rays
    from the pixel: a reversed frame draws other ones)."""
    bricks, regions, bvh, field, tf, lo, hi = amrex
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    m = np.diag([-1.0, 1.0, 1.0])
    flip = lambda p: tuple(m @ (np.asarray(p) - lo) + lo)
    meshes, isos, slices, mirrored_slices = (), (), (), ()
    if extra == "mesh":
        path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.3 * float((hi - lo).min()), 3)
        meshes = (MeshLayer(str(path), opacity=0.6),)
    if extra == "surfaces":
        lo_v, hi_v = (float(x) for x in field_range(bricks, field))
        isos = (IsoSurface(field, lo_v + 0.6 * (hi_v - lo_v), opacity=0.5),)
        point, normal = (lo[0] - 0.3, 0.5, 0.5), (1.0, 0.3, 0.0)  # through the copy only
        slices = (Slice(point, normal, field, tf, opacity=0.7),)
        mirrored_slices = (Slice(flip(point), tuple(m @ normal), field, tf, opacity=0.7),)
    c, e = (lo + hi) / 2, float((hi - lo).max())
    cam = Camera(position=tuple(c + np.array([0.4, -2.8, 1.4]) * e),
                 look_at=tuple(c - [0.5 * e, 0.0, 0.0]), up=(0, 0, 1), fovy=40)
    mirror = Instance(mirror=("x", float(lo[0])))
    got = frame(renderer, cam, field, tf, meshes=meshes, inst=[mirror], depth=True,
                isosurfaces=isos, slices=slices)
    mirrored = Camera(position=flip(cam.position), look_at=flip(cam.look_at), up=(0, 0, 1), fovy=40)
    front = frame(renderer, cam, field, tf, meshes=meshes, clip=cells_box(lo, hi), depth=True,
                  isosurfaces=isos, slices=slices)
    back = frame(renderer, mirrored, field, tf, meshes=meshes, clip=cells_box(lo, hi), depth=True,
                 isosurfaces=isos, slices=mirrored_slices)
    want = over(front.rgba, back.rgba[:, ::-1])
    assert got.stats["instance_order"] == [0, 1]
    assert front.rgba[..., 3].max() > 0.3 and back.rgba[..., 3].max() > 0.3
    # some pixels see both copies, one behind the other
    assert ((front.rgba[..., 3] > 0.05) & (back.rgba[:, ::-1, 3] > 0.05)).any()
    np.testing.assert_allclose(got.rgba, want, atol=2e-5)
    # depth: where the copy in front shows nothing, the copy behind's
    empty = front.rgba[..., 3] == 0.0
    np.testing.assert_allclose(got.depth[empty], back.depth[:, ::-1][empty], rtol=1e-5)
    assert got.stats["samples"] == front.stats["samples"] + back.stats["samples"]


@device_param
def test_a_rigid_copy_is_the_frame_of_the_camera_moved_back(amrex, device):
    """A copy turned 40 degrees about (1, 2, 3) and moved off the data: the frame
    of the camera taken back by that map (the same pixels, no reversal), composited
    in the order that the plane between the copies gives from the eye; sample by
    sample with spp = 2; with a world clip box, which the turned copy takes as planes."""
    bricks, regions, bvh, field, tf, lo, hi = amrex
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    copy = Instance(rotate=(1.0, 2.0, 3.0, 40.0), translate=(2.2, 0.0, 0.0))
    r, t = copy.affine()
    cam = Camera(position=(4.0, -3.5, 1.8), look_at=(1.3, 0.5, 0.5), up=(0, 0, 1), fovy=45)
    world_clip = Clip(box=((-1.0, 0.1, -1.0), (4.0, 0.8, 2.0)))
    got = frame(renderer, cam, field, tf, inst=[copy], clip=world_clip, spp=2)
    back = lambda p: tuple(r.T @ (np.asarray(p) - t))
    moved = Camera(position=back(cam.position), look_at=back(cam.look_at),
                   up=tuple(r.T @ np.array([0.0, 0.0, 1.0])), fovy=45)
    order = got.stats["instance_order"]
    assert order == [1, 0]  # the eye is on the copy's side
    turned = instances.object_scene(Scene(camera=cam, clip=world_clip), r, t, None).clip
    assert turned.box is None and len(turned.planes) == 6
    samples = []
    for k in range(2):
        mine = frame(renderer, cam, field, tf, clip=Clip(box=((lo[0], 0.1, lo[2]), (hi[0], 0.8, hi[2]))),
                     spp=2, sample=k)
        theirs = frame(renderer, moved, field, tf,
                       clip=Clip(box=(tuple(lo), tuple(hi)), planes=turned.planes), spp=2, sample=k)
        assert mine.rgba[..., 3].max() > 0.1 and theirs.rgba[..., 3].max() > 0.1
        samples.append(over(theirs.rgba, mine.rgba))
    np.testing.assert_allclose(got.rgba, np.mean(samples, axis=0), atol=2e-5)


@pytest.mark.parametrize("at", [0.0, pytest.param(0.4, marks=pytest.mark.slow)])  # apart; mixed
def test_a_tile_of_an_instanced_frame_is_that_part_of_it(amrex, at):
    bricks, regions, bvh, field, tf, lo, hi = amrex
    renderer = Renderer(bricks, regions, bvh, field=field)
    cam = Camera(position=(0.5, -3.0, 1.5), look_at=(0.0, 0.5, 0.5), up=(0, 0, 1), fovy=45)
    scene = Scene(camera=cam, volumes=(VolumeLayer(field, tf),),
                  instances=(Instance(mirror=("x", at)),),
                  settings=Settings(width=SIZE, height=SIZE))
    whole = renderer.render_scene(scene).rgba
    tile = renderer.render_scene(scene, window=(8, 16, 24, 20)).rgba
    np.testing.assert_array_equal(tile, whole[16:36, 8:32])


@device_param
# each other reconstruction and level of detail is a program variant of its own
@pytest.mark.parametrize("mode", ["basis", *(pytest.param(m, marks=pytest.mark.slow)
                                            for m in ("nearest", "vertex", "lod", "surfaces"))])
def test_two_copies_in_one_place_are_the_medium_twice_as_dense(amrex, device, mode, tmp_path):
    """A copy laid on the data itself (an instance that moves nothing) overlaps it
    everywhere: the mixture's extinction is twice the data's, which is the frame
    of the data (cut at its cells) with half the unit distance, headlight shading
    and early termination included; with each reconstruction and level of detail;
    and with an iso-surface, a slice and a translucent mesh, each met twice at the
    same distance, which is once at the opacity 1 - (1 - a)^2."""
    bricks, regions, bvh, field, tf, lo, hi = amrex
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    cam = Camera(position=(2.0, -2.6, 1.9), look_at=(0.45, 0.5, 0.5), up=(0, 0, 1), fovy=40)
    settings = dict(width=SIZE, height=SIZE, jitter=False, max_opacity=1.0, depth=True,
                    reconstruction="basis" if mode == "lod" else mode if mode != "surfaces" else "basis",
                    lod=2.0 if mode == "lod" else 0.0)
    lighting = Lighting(shading="headlight", specular=0.3)

    def surfaces(a):
        if mode != "surfaces":
            return {}
        lo_v, hi_v = (float(x) for x in field_range(bricks, field))
        path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.25 * float((hi - lo).min()), 3)
        return dict(isosurfaces=(IsoSurface(field, lo_v + 0.6 * (hi_v - lo_v), opacity=a),),
                    slices=(Slice((0.5, 0.3, 0.5), (0.2, 1.0, 0.1), field, tf, opacity=a),),
                    meshes=(MeshLayer(str(path), opacity=a),))

    got = renderer.render_scene(Scene(camera=cam, volumes=(VolumeLayer(field, tf),), lighting=lighting,
                                      instances=(Instance(),), settings=Settings(**settings),
                                      **surfaces(0.3)))
    assert got.stats["instance_order"] == "mixture"
    unit = got.stats["unit_distance"]
    scene = Scene(camera=cam, volumes=(VolumeLayer(field, tf),), clip=cells_box(lo, hi),
                  lighting=lighting, settings=Settings(**settings, unit_distance=unit / 2),
                  **surfaces(1.0 - 0.7 ** 2))
    want = renderer.render_scene(scene)
    assert want.rgba[..., 3].max() > 0.5
    np.testing.assert_allclose(got.rgba, want.rgba, atol=3e-5)
    if mode != "surfaces":  # crossings refined on the field count samples too
        assert got.stats["samples"] == 2 * want.stats["samples"]
    np.testing.assert_allclose(got.depth, want.depth, rtol=1e-5)


@device_param
@pytest.mark.slow  # the fast suite draws a mixture once (the coincident copies)
@pytest.mark.parametrize("extra", ["volume", "surfaces"])
def test_the_mixture_of_copies_apart_is_their_composite(amrex, device, extra, tmp_path):
    """Drawn as a mixture, copies that do not overlap (the mirror on the data's
    face) give the frame their composite in visibility order gives: every
    segment of a ray is one copy's regions; with an iso-surface, a slice and a
    translucent mesh in each copy too."""
    bricks, regions, bvh, field, tf, lo, hi = amrex
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    cam = Camera(position=(0.9, -2.6, 1.6), look_at=(0.0, 0.5, 0.5), up=(0, 0, 1), fovy=45)
    parts = {}
    if extra == "surfaces":
        lo_v, hi_v = (float(x) for x in field_range(bricks, field))
        path, _ = icosphere_file(tmp_path, (lo + hi) / 2, 0.25 * float((hi - lo).min()), 3)
        parts = dict(isosurfaces=(IsoSurface(field, lo_v + 0.6 * (hi_v - lo_v), opacity=0.5),),
                     slices=(Slice((lo[0] - 0.3, 0.5, 0.5), (1.0, 0.3, 0.0), field, tf, opacity=0.7),),
                     meshes=(MeshLayer(str(path), opacity=0.6),))
    scene = Scene(camera=cam, volumes=(VolumeLayer(field, tf),),
                  instances=(Instance(mirror=("x", float(lo[0]))),),
                  lighting=Lighting(shading="headlight"),
                  settings=Settings(width=SIZE, height=SIZE, max_opacity=1.0, spp=2), **parts)
    composite = renderer.render_scene(scene)
    assert composite.stats["instance_order"] == [0, 1]
    rgba, _, stats = instances.render_mixture(
        renderer._everywhere(), scene, renderer._object_box(scene), traversal="ordered", rows=None,
        window=None, sample=None, deadline=None)
    if extra == "volume":  # crossings refined on the field count samples too
        assert stats["samples"] == composite.stats["samples"]
    np.testing.assert_allclose(rgba, composite.rgba, atol=3e-5)


@device_param
@pytest.mark.slow  # the fast suite draws a mixture once (the coincident copies)
def test_a_mirror_through_the_data_mixes_two_media_symmetrically(amrex, device):
    """The data mirrored across the plane y = 0.4 through it: where both copies
    are, their media mix. Seen from a camera on that plane looking along it, the
    mixture is its own mirror image: the frame equals itself with its columns
    reversed. The half of the frame outside the overlap still shows one copy."""
    bricks, regions, bvh, field, tf, lo, hi = amrex
    renderer = Renderer(bricks, regions, bvh, field=field, device=device)
    c = 0.4
    cam = Camera(position=(3.2, c, 1.3), look_at=(0.5, c, 0.5), up=(0, 0, 1), fovy=40)
    mirror = Instance(mirror=("y", c))
    got = frame(renderer, cam, field, tf, inst=[mirror])
    alone = frame(renderer, cam, field, tf, clip=cells_box(lo, hi))
    assert got.stats["instance_order"] == "mixture"
    assert got.rgba[..., 3].max() > 0.3
    np.testing.assert_allclose(got.rgba, got.rgba[:, ::-1], atol=2e-5)
    assert not np.allclose(got.rgba, alone.rgba, atol=1e-2)  # the copy's medium adds


def test_visibility_order_puts_the_eye_side_first_and_refuses_cycles():
    box = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    maps = [(np.eye(3), np.zeros(3)), Instance(mirror=("z", 0.0)).affine(),
            Instance(translate=(0.0, 0.0, 3.0)).affine()]
    assert instances.visibility_order(box, maps, (0.5, 0.5, 10.0)) == [2, 0, 1]
    assert instances.visibility_order(box, maps, (0.5, 0.5, -10.0)) == [1, 0, 2]
    # three tilted rods around the z axis, each over the next: no order from above
    rod = np.array([[-1.0, -0.1, -0.1], [1.0, 0.1, 0.1]])
    ring = []
    for k in range(3):
        turn, _ = Instance(rotate=(0.0, 0.0, 1.0, 120.0 * k)).affine()
        tilt, _ = Instance(rotate=(0.0, 1.0, 0.0, 15.0)).affine()
        ring.append((turn @ tilt, turn @ np.array([0.0, -0.5, 0.0])))
    with pytest.raises(ExabricksError, match="no order front to back"):
        instances.visibility_order(rod, ring, (0.0, 0.0, 10.0))
    assert instances.visibility_order(rod, ring, (10.0, 0.0, 0.0)) is not None  # from the side


def test_the_flag_and_the_scene_key(tmp_path):
    bricks, *_ = built_scene(GERRIS, "T")
    scene = scene_from_options(bricks, flags={"mirror": [("y", "0"), ("z", "-1.5")]})
    assert scene.instances == (Instance(mirror=("y", 0.0)), Instance(mirror=("z", -1.5)))
    doc = scene_to_dict(scene.replace(instances=(
        Instance(mirror=("x", 2.0), rotate=(0.0, 0.0, 1.0, 90.0), translate=(1.0, 2.0, 3.0)),)))
    path = tmp_path / "scene.json"
    import json

    path.write_text(json.dumps(doc))
    again = scene_from_options(bricks, scene_path=path)
    assert again.instances == (Instance(mirror=("x", 2.0), rotate=(0.0, 0.0, 1.0, 90.0),
                                        translate=(1.0, 2.0, 3.0)),)
    with pytest.raises(ExabricksError, match="mirror: expected an axis"):
        scene_from_options(bricks, flags={"mirror": [("w", "0")]})
    with pytest.raises(ExabricksError, match="mirror: expected an axis"):
        scene_from_options(bricks, flags={"mirror": [("x", "nan")]})
    with pytest.raises(ExabricksError, match=r"mirror: 1e\+300 is beyond the float32 range"):
        scene_from_options(bricks, flags={"mirror": [("x", "1e300")]})  # before the camera
    path.write_text(json.dumps({"instances": [{"translate": [0, 1e31, 0]}]}))
    with pytest.raises(ExabricksError, match=r"instances\[0\]: a translation .* within 1e"):
        scene_from_options(bricks, scene_path=path)
    path.write_text(json.dumps({"instances": [{"rotate": [0, 0, 0, 30]}]}))
    with pytest.raises(ExabricksError, match=r"instances\[0\].*non-zero axis"):
        scene_from_options(bricks, scene_path=path)
    path.write_text(json.dumps({"instances": [{"mirror": ["q", 0]}]}))
    with pytest.raises(ExabricksError, match=r"instances\[0\]"):
        scene_from_options(bricks, scene_path=path)
    assert needs_image_mode(scene) == "instances"
    # the Python API's keyword: one plane, or a list of them
    from exabricks.scene import SCENE_OPTIONS

    option = next(o for o in SCENE_OPTIONS if o.name == "mirror")
    assert option.coerce(("y", 0)) == (("y", 0.0),)
    assert option.coerce([("y", 0), ("x", "2")]) == (("y", 0.0), ("x", 2.0))


@pytest.mark.slow
def test_render_mirror_and_a_budget_of_several_domains(tmp_path):
    """`render --mirror` writes the instances into the image's scene; a budget that
    splits the data by space refuses them with one line and writes nothing."""
    from exabricks.film.image import Image

    out = tmp_path / "m.png"
    args = ["render", GERRIS, "--size", 48, 48, "--mirror", "x", 0]
    run_cli(*args, "-o", out, check=0)
    assert Image.read(out).metadata["scene"]["instances"] == [
        {"translate": [0.0, 0.0, 0.0], "mirror": ["x", 0.0]}]
    bad = tmp_path / "b.png"
    assert_one_error_line(run_cli(*args, "-o", bad, "--memory-budget", "3M"),
                          "instances need the whole dataset at once", "domains")
    assert not bad.exists()
