"""Scenes from scene files and flags (exabricks/scene.py, docs/scene.md): defaults,
precedence, relative paths, presets, colour fields, and one error per mistake."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from exabricks import schema
from exabricks.picture.auto_transfer import AUTOMATIC_SAMPLING_RATE, automatic_transfer_function
from exabricks.picture.camera import Camera
from exabricks.picture.framing import framed_camera, view_axes, visible_corners
from exabricks.util.errors import ExabricksError
from exabricks.scene import (
    FLAGS, MAX_AO_SAMPLES, MAX_CLIP_PLANES, MAX_ISOSURFACES, MAX_SLICES, MAX_VOLUMES, Clip,
    Lighting, Settings, choose_transfer_function, field_range, read_scene_file, scene_file_references,
    scene_from_options, scene_schema, scene_to_dict,
)
from exabricks.picture.transfer_function import TransferFunction, preset_path, widen_degenerate_range

from helpers import DEVICES, GERRIS, assert_one_error_line, run_cli

PRESET = {"Name": "two", "RGBPoints": [0, 0, 0, 0, 1, 1, 1, 1], "Points": [0, 0, 0.5, 0, 1, 0.5, 0.5, 0]}


@pytest.fixture(scope="module")
def bricks():
    """Bricks of the Gerris plume with all its fields: P T U V W."""
    from exabricks.readers import read
    from exabricks.builders.bricks import build_bricks

    return build_bricks(read(GERRIS))


@pytest.fixture(scope="module")
def trio(bricks, tmp_path_factory):
    """bricks, regions and bvh files of the plume, all fields."""
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions

    d = tmp_path_factory.mktemp("scene-trio")
    regions = build_regions(bricks)
    bvh = build_bvh(regions)
    regions = regions.replace(meta={"consistency": {"n_bricks": bricks.n_bricks,
                                                    "n_regions": regions.n_regions}})
    paths = [d / "bricks.npz", d / "regions.npz", d / "bvh.npz"]
    for path, obj in zip(paths, (bricks, regions, bvh)):
        schema.save(path, obj)
    return paths


def write(folder: Path, doc, name="scene.json") -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def build(bricks, doc=None, folder=None, camera_path=None, **flags):
    path = None if doc is None else write(folder, doc)
    return scene_from_options(bricks, scene_path=path, camera_path=camera_path, flags=flags)


def data_range(bricks, field):
    return widen_degenerate_range(field_range(bricks, field))


def colormap(bricks, field, name="viridis", value_range=None):
    return TransferFunction.from_colormap(name, value_range or data_range(bricks, field))


# ---------------------------------------------------------------------------
# defaults and the volume flags (today's behaviour of render)


def test_defaults(bricks):
    scene = scene_from_options(bricks, flags={})
    assert bricks.fields[0] == "P" and scene.fields() == ("P",)
    (layer,) = scene.volumes
    assert layer.field == "P" and layer.transfer_function == automatic_transfer_function(bricks, "P")
    # The camera frames what the automatic function shows, from the three-quarter view.
    corners = visible_corners(bricks, "P", layer.transfer_function, axes=view_axes())
    assert scene.camera == framed_camera(corners)
    # The automatic picture is exposed automatically (exabricks.film.exposure) and
    # sampled finely enough for its layers (auto_transfer.AUTOMATIC_SAMPLING_RATE).
    assert scene.settings == Settings(auto_exposure=True, sampling_rate=AUTOMATIC_SAMPLING_RATE)
    assert scene.lighting == Lighting() and scene.clip == Clip()
    assert scene.isosurfaces == () and scene.slices == () and scene.background == (0, 0, 0, 0)


def test_volume_flags(bricks):
    scene = scene_from_options(bricks, flags={"field": "T"})
    assert scene.volumes[0].field == "T"
    assert scene.volumes[0].transfer_function == automatic_transfer_function(bricks, "T")
    tf = scene_from_options(bricks, flags={"field": "U", "colormap": "magma", "range": (-1, 2),
                                           "opacity": (0, 0.5, 1)}).volumes[0].transfer_function
    assert tf == TransferFunction.from_colormap("magma", (-1, 2), opacity=(0, 0.5, 1))
    tf = scene_from_options(bricks, flags={"transfer_function": "inferno-shells"}).volumes[0].transfer_function
    assert tf.value_range == pytest.approx(data_range(bricks, "P"))
    assert scene_from_options(bricks, flags={"volume": False, "field": "T"}).volumes == ()


def test_choose_transfer_function(bricks, tmp_path):
    preset = write(tmp_path, PRESET, "p.json")
    assert choose_transfer_function(bricks, "T", str(preset)) == TransferFunction.from_paraview(preset)
    assert choose_transfer_function(bricks, "T", str(preset), value_range=(2, 4)).value_range == (2, 4)
    stretched = choose_transfer_function(bricks, "T", "default")
    assert stretched == TransferFunction.from_paraview(preset_path("default")).rescaled(data_range(bricks, "T"))
    with pytest.raises(ExabricksError, match="not both"):
        choose_transfer_function(bricks, "T", "default", "viridis")
    with pytest.raises(ExabricksError, match="--opacity goes with --colormap"):
        choose_transfer_function(bricks, "T", opacity=(0, 1))


@pytest.mark.parametrize("flags, needle", [
    ({"transfer_function": "default", "colormap": "viridis"}, "not both"),
    ({"opacity": (0, 1)}, "--opacity goes with --colormap"),
    ({"volume": False, "colormap": "viridis"}, "--no-volume"),
    ({"iso": (1,), "iso_color": (1, 0, 0), "iso_color_field": "T"}, "not both"),
    ({"iso": (1,), "iso_color": (1, 0, 0), "iso_range": (0, 1)}, "--iso-range goes with --iso-color-field"),
])
def test_contradicting_flags(bricks, flags, needle):
    with pytest.raises(ExabricksError, match=needle):
        scene_from_options(bricks, flags=flags)


def test_unknown_flag_names_are_a_programming_error(bricks):
    with pytest.raises(TypeError, match="colour"):
        scene_from_options(bricks, flags={"colour": 1})
    assert {"iso", "clip_plane", "jitter", "depth", "transfer_function", "range"} <= set(FLAGS)


# ---------------------------------------------------------------------------
# scene files, precedence and relative paths


FULL = {
    "camera": {"position": [300, 200, 300], "look_at": [64, 64, 64], "up": [0, 1, 0], "fovy": 40},
    "volumes": [{"field": "T", "transfer_function": "inferno-shells"},
                {"field": "U", "transfer_function": {"colormap": "magma", "opacity": [0, 0.5]}, "range": [-1, 1]}],
    "isosurfaces": [{"field": "T", "value": 0.01, "color": {"field": "P"}},
                    {"field": "U", "value": 0.0, "color": [1, 0, 0], "opacity": 0.5}],
    "slices": [{"point": [64, 64, 64], "normal": [0, 0, 1], "field": "V", "colormap": "gray", "range": [-1, 1],
                "opacity": 0.7}],
    "clip": {"box": [0, 0, 0, 100, 110, 120], "planes": [[64, 64, 64, 1, 0, 0]]},
    "lighting": {"shading": "none", "gradient": "central", "specular": 0.5, "shininess": 8,
                 "ambient_occlusion": {"samples": 16, "distance": 4}},
    "background": [1, 1, 1],
    "size": [64, 32], "spp": 2, "sampling_rate": 3, "max_opacity": 0.9, "seed": 7, "jitter": False,
    "unit_distance": 2, "depth": True,
}


def test_a_full_scene_file(bricks, tmp_path):
    scene = build(bricks, FULL, tmp_path)
    assert scene.camera == Camera((300, 200, 300), (64, 64, 64), (0, 1, 0), 40)
    assert scene.fields() == ("T", "U", "P", "V")
    t, u = scene.volumes
    assert t.transfer_function.value_range == pytest.approx(data_range(bricks, "T"))  # built-in: stretched
    assert u.transfer_function == TransferFunction.from_colormap("magma", (-1, 1), opacity=(0, 0.5))
    a, b = scene.isosurfaces
    assert (a.field, a.value, a.color_field, a.opacity) == ("T", 0.01, "P", 1.0)
    assert a.colormap == colormap(bricks, "P")
    assert (b.color, b.opacity, b.color_field, b.colormap) == ((1, 0, 0), 0.5, None, None)
    (s,) = scene.slices
    assert (s.point, s.normal, s.field, s.opacity) == ((64, 64, 64), (0, 0, 1), "V", 0.7)
    assert s.colormap == TransferFunction.from_colormap("gray", (-1, 1))
    assert scene.clip == Clip(((0, 0, 0), (100, 110, 120)), (((64, 64, 64), (1, 0, 0)),))
    assert scene.lighting == Lighting("none", "central", 0.5, 8.0, 16, 4.0)
    assert scene.background == (1, 1, 1, 1)  # RGB is opaque
    assert scene.settings == Settings(64, 32, 2, 3.0, 0.9, 7, False, 2.0, True)


def test_flags_override_the_file_key_by_key(bricks, tmp_path):
    scene = build(bricks, FULL, tmp_path, spp=5, shading="headlight", ao_distance=9.0, jitter=True,
                  background=(0, 0, 0, 0.5), size=(8, 8), fovy=20.0, clip_box=(1, 2, 3, 4, 5, 6))
    assert scene.settings == Settings(8, 8, 5, 3.0, 0.9, 7, True, 2.0, True)
    assert scene.lighting == Lighting("headlight", "central", 0.5, 8.0, 16, 9.0)
    assert scene.background == (0, 0, 0, 0.5)
    assert scene.camera.fovy == 20 and scene.camera.position == (300, 200, 300)
    assert scene.clip.box == ((1, 2, 3), (4, 5, 6)) and len(scene.clip.planes) == 1
    assert len(scene.volumes) == 2 and len(scene.isosurfaces) == 2  # untouched by unrelated flags


def test_volume_flags_replace_the_layers(bricks, tmp_path):
    (layer,) = build(bricks, FULL, tmp_path, colormap="gray").volumes
    assert layer.field == "T"  # the scene's first volume field
    assert layer.transfer_function == automatic_transfer_function(bricks, "T", colormap="gray")
    (layer,) = build(bricks, FULL, tmp_path, field="W").volumes
    assert layer == build(bricks, None, tmp_path, field="W").volumes[0]
    assert build(bricks, FULL, tmp_path, volume=False).volumes == ()
    assert build(bricks, {"volumes": []}, tmp_path).volumes == ()
    (layer,) = build(bricks, {"volumes": []}, tmp_path, volume=True).volumes
    assert layer.field == "P"


def test_iso_flags(bricks, tmp_path):
    scene = build(bricks, FULL, tmp_path, iso=(0.1, 0.2))  # replaces the file's, on its first volume field
    assert [(s.field, s.value, s.color, s.color_field) for s in scene.isosurfaces] == [
        ("T", 0.1, (0.9, 0.9, 0.9), None), ("T", 0.2, (0.9, 0.9, 0.9), None)]
    scene = build(bricks, None, tmp_path, iso=(0.0,), field="U", iso_color_field="V", iso_range=(0, 2),
                  iso_opacity=0.25, volume=False)
    (s,) = scene.isosurfaces
    assert (s.field, s.color_field, s.opacity, scene.volumes) == ("U", "V", 0.25, ())
    assert s.colormap == TransferFunction.from_colormap("viridis", (0, 2))
    # Without --iso, the modifiers apply to the file's iso-surfaces.
    scene = build(bricks, FULL, tmp_path, iso_color=(0, 1, 0))
    assert [(s.color, s.color_field) for s in scene.isosurfaces] == [((0, 1, 0), None)] * 2
    scene = build(bricks, FULL, tmp_path, iso_colormap="magma")
    assert scene.isosurfaces[0].colormap == colormap(bricks, "P", "magma")
    assert scene.isosurfaces[1].color == (1, 0, 0)
    with pytest.raises(ExabricksError, match="--iso-color: there is no iso-surface"):
        build(bricks, None, tmp_path, iso_color=(1, 0, 0))
    with pytest.raises(ExabricksError, match="--iso-range: there is no iso-surface coloured by a field"):
        build(bricks, None, tmp_path, iso=(1.0,), iso_range=(0, 1))
    with pytest.raises(ExabricksError, match="--iso-color-field: no field 'rho'"):
        build(bricks, None, tmp_path, iso=(1.0,), iso_color_field="rho")


def test_slice_and_clip_flags(bricks, tmp_path):
    scene = build(bricks, FULL, tmp_path, field="W", slice=((1, 2, 3, 0, 1, 0), (4, 5, 6, 1, 1, 1)))
    assert [(s.point, s.normal, s.field) for s in scene.slices] == [
        ((1, 2, 3), (0, 1, 0), "W"), ((4, 5, 6), (1, 1, 1), "W")]
    assert scene.slices[0].colormap == colormap(bricks, "W")
    (s,) = build(bricks, FULL, tmp_path, slice_colormap="magma").slices  # modifies the file's slice
    assert s.colormap == TransferFunction.from_colormap("magma", (-1, 1))
    (s,) = build(bricks, FULL, tmp_path, slice_range=(0, 5)).slices
    assert s.colormap == TransferFunction.from_colormap("gray", (0, 5))
    with pytest.raises(ExabricksError, match="--slice-colormap: there is no slice"):
        build(bricks, None, tmp_path, slice_colormap="magma")
    with pytest.raises(ExabricksError, match="--slice: expected a finite, non-zero normal"):
        build(bricks, None, tmp_path, slice=((0, 0, 0, 0, 0, 0),))
    planes = tuple((i, 0, 0, 1, i, 0) for i in range(MAX_CLIP_PLANES))
    scene = build(bricks, FULL, tmp_path, clip_plane=planes)
    assert len(scene.clip.planes) == MAX_CLIP_PLANES and scene.clip.planes[3] == ((3, 0, 0), (1, 3, 0))
    with pytest.raises(ExabricksError, match="at most 16"):
        build(bricks, None, tmp_path, clip_plane=planes + ((0, 0, 0, 1, 0, 0),))
    with pytest.raises(ExabricksError, match="--clip-box: expected a finite box"):
        build(bricks, None, tmp_path, clip_box=(0, 0, 0, -1, 1, 1))


def test_camera_precedence(bricks, tmp_path):
    cam = write(tmp_path, {"position": [0, 0, 500], "look_at": [64, 64, 64], "up": [0, 1, 0], "fovy": 50},
                "cam.json")
    inline = build(bricks, {"camera": {"position": [1, 2, 3], "look_at": [64, 64, 64], "up": [0, 1, 0]}},
                   tmp_path)
    assert inline.camera == Camera((1, 2, 3), (64, 64, 64), (0, 1, 0), 30)  # fovy defaults to 30
    assert build(bricks, FULL, tmp_path, camera_path=cam).camera == Camera.from_json(cam)
    moved = build(bricks, FULL, tmp_path, camera_path=cam, position=(9.0, 9.0, 9.0))
    assert moved.camera == Camera((9, 9, 9), (64, 64, 64), (0, 1, 0), 50)


def test_relative_paths_are_relative_to_the_scene_file(bricks, tmp_path, monkeypatch):
    folder = tmp_path / "scenes"
    write(folder, {"position": [0, 0, 500], "look_at": [64, 64, 64], "up": [0, 1, 0], "fovy": 50},
          "views/cam.json")
    write(folder, PRESET, "tf/two.json")
    path = write(folder, {"camera": "views/cam.json",
                          "volumes": [{"field": "T", "transfer_function": "tf/two.json"},
                                      {"field": "U", "transfer_function": "tf/two.json", "range": [5, 6]},
                                      {"field": "V", "transfer_function": "default"}]})
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    scene = scene_from_options(bricks, scene_path=path, flags={})
    assert scene.camera.fovy == 50
    t, u, v = (layer.transfer_function for layer in scene.volumes)
    assert t == TransferFunction.from_paraview(folder / "tf/two.json")  # a preset file as stored
    assert u.value_range == (5, 6)  # ... unless a range is given
    assert v == TransferFunction.from_paraview(preset_path("default")).rescaled(data_range(bricks, "V"))
    assert scene_file_references(path) == [folder / "views/cam.json", folder / "tf/two.json",
                                            folder / "tf/two.json"]


def test_inline_presets_and_colour_maps(bricks, tmp_path):
    doc = {"volumes": [{"field": "T", "transfer_function": PRESET},
                       {"field": "U", "transfer_function": PRESET, "range": [2, 3]}],
           "isosurfaces": [{"field": "T", "value": 0, "color": {"field": "U", "colormap": PRESET}}],
           "slices": [{"point": [0, 0, 0], "normal": [1, 0, 0], "field": "W", "colormap": "magma",
                       "range": [0, 1]}]}
    scene = build(bricks, doc, tmp_path)
    stored = TransferFunction.from_paraview_dict(PRESET)
    assert scene.volumes[0].transfer_function == stored
    assert scene.volumes[1].transfer_function == stored.rescaled((2, 3))
    assert scene.isosurfaces[0].colormap == stored
    assert scene.slices[0].colormap == TransferFunction.from_colormap("magma", (0, 1))


def test_scene_to_dict_reads_back_as_the_same_scene(bricks, tmp_path):
    scene = build(bricks, FULL, tmp_path, iso_color_field="W", clip_plane=((1, 1, 1, 0, 0, 1),))
    doc = scene_to_dict(scene)
    text = json.dumps(doc, allow_nan=False)
    assert build(bricks, text, tmp_path / "again") == scene
    default = scene_from_options(bricks, flags={})
    assert build(bricks, json.dumps(scene_to_dict(default)), tmp_path / "default") == default


def test_the_schema_is_valid_and_matches_the_limits():
    import jsonschema

    s = scene_schema()
    jsonschema.Draft202012Validator.check_schema(s)
    props = s["properties"]
    assert props["volumes"]["maxItems"] == MAX_VOLUMES
    assert props["isosurfaces"]["maxItems"] == MAX_ISOSURFACES
    assert props["slices"]["maxItems"] == MAX_SLICES
    assert s["$defs"]["clip"]["properties"]["planes"]["maxItems"] == MAX_CLIP_PLANES
    ao = s["$defs"]["lighting"]["properties"]["ambient_occlusion"]["properties"]["samples"]
    assert ao["maximum"] == MAX_AO_SAMPLES
    assert s["$defs"]["lighting"]["properties"]["shading"]["enum"] == ["headlight", "none"]
    from exabricks.util.constants import MAX_KNOTS

    preset = s["$defs"]["preset"]["properties"]
    assert preset["RGBPoints"]["maxItems"] == preset["Points"]["maxItems"] == 4 * MAX_KNOTS
    assert s["$defs"]["colormap_function"]["properties"]["opacity"]["maxItems"] == MAX_KNOTS


# ---------------------------------------------------------------------------
# a bad scene file is refused on every key, with one error naming file and key path

VOL = {"field": "T"}
ISO = {"field": "T", "value": 0.5}
SLICE = {"point": [0, 0, 0], "normal": [0, 0, 1], "field": "T"}
CAM = {"position": [300, 300, 300], "look_at": [64, 64, 64], "up": [0, 1, 0]}

BAD = [
    # (scene object or raw text, key path, another needle)
    ("[1, 2]", "", "expected a JSON object of scene keys"),
    ("{", "", "not valid JSON"),
    ('{"spp": 1, "spp": 2}', "", "duplicate key 'spp'"),
    ({"colour": [1, 0, 0]}, "colour", "unknown key"),
    ({"camera": 3}, "camera", "found 3"),
    ({"camera": ""}, "camera", "found \"\""),
    ({"camera": "missing.json"}, "camera", "no such file"),
    ({"camera": {**CAM, "zoom": 2}}, "camera.zoom", "unknown key"),
    ({"camera": {"position": [1, 2, 3], "up": [0, 1, 0]}}, "camera.look_at", "missing"),
    ({"camera": {**CAM, "position": [1, 2]}}, "camera.position", "a list of 3 numbers"),
    ({"camera": {**CAM, "up": [0, "1", 0]}}, "camera.up", "a list of 3 numbers"),
    ({"camera": {**CAM, "fovy": 180}}, "camera.fovy", "found 180"),
    ({"camera": {**CAM, "up": [1, 1, 1]}}, "camera", "parallel"),
    ({"volumes": {"field": "T"}}, "volumes", "a list of at most 8"),
    ({"volumes": [VOL] * 9}, "volumes", "a list of at most 8"),
    ({"volumes": [VOL, 3]}, "volumes[1]", "a volume layer object"),
    ({"volumes": [{"transfer_function": "default"}]}, "volumes[0].field", "missing"),
    ({"volumes": [{"field": 1}]}, "volumes[0].field", "a field name"),
    ({"volumes": [VOL, {"field": "rho"}]}, "volumes[1].field", "no field 'rho'"),
    ({"volumes": [VOL, {"field": "T", "colour": 1}]}, "volumes[1].colour", "unknown key"),
    ({"volumes": [VOL, {"field": "T", "transfer_function": 3}]}, "volumes[1].transfer_function",
     "expected a preset file, a built-in preset name or a preset object (found 3)"),
    ({"volumes": [{"field": "T", "transfer_function": "nope.json"}]}, "volumes[0].transfer_function",
     "no such file"),
    ({"volumes": [{"field": "T", "transfer_function": {"Name": "x"}}]},
     "volumes[0].transfer_function.RGBPoints", "missing"),
    ({"volumes": [{"field": "T", "transfer_function": {"RGBPoints": [0, 0, 0]}}]},
     "volumes[0].transfer_function.RGBPoints", "found [0, 0, 0]"),
    ({"volumes": [{"field": "T", "transfer_function": {"RGBPoints": [1, 0, 0, 0, 0, 1, 1, 1]}}]},
     "volumes[0].transfer_function", "increasing"),
    ({"volumes": [{"field": "T", "transfer_function": {"RGBPoints": [0, 0, 0, 0], "Points": [0, 2, 0.5, 0]}}]},
     "volumes[0].transfer_function", "alpha outside [0, 1]"),
    ({"volumes": [{"field": "T", "transfer_function": {"colormap": "nope"}}]},
     "volumes[0].transfer_function", "unknown colormap 'nope'"),
    ({"volumes": [{"field": "T", "transfer_function": {"colormap": "viridis", "opacity": [2]}}]},
     "volumes[0].transfer_function.opacity[0]", "in [0, 1]"),
    ({"volumes": [{"field": "T", "transfer_function": {"colormap": "viridis", "alpha": [1]}}]},
     "volumes[0].transfer_function.alpha", "unknown key"),
    ({"volumes": [{"field": "T", "range": [1]}]}, "volumes[0].range", "[low, high]"),
    ({"volumes": [{"field": "T", "range": [2, 1]}]}, "volumes[0].range", "low < high"),
    ({"isosurfaces": "T"}, "isosurfaces", "a list of at most 32"),
    ({"isosurfaces": [ISO] * 33}, "isosurfaces", "a list of at most 32"),
    ({"isosurfaces": [{"field": "T"}]}, "isosurfaces[0].value", "missing"),
    ({"isosurfaces": [{**ISO, "value": "1"}]}, "isosurfaces[0].value", "a number"),
    ({"isosurfaces": [{**ISO, "field": "rho"}]}, "isosurfaces[0].field", "no field 'rho'"),
    ({"isosurfaces": [{**ISO, "color": "red"}]}, "isosurfaces[0].color", "an RGB list"),
    ({"isosurfaces": [{**ISO, "color": [1, 0]}]}, "isosurfaces[0].color", "an RGB list"),
    ({"isosurfaces": [{**ISO, "color": [1, 0, 2]}]}, "isosurfaces[0].color[2]", "in [0, 1]"),
    ({"isosurfaces": [{**ISO, "color": {"colormap": "viridis"}}]}, "isosurfaces[0].color.field", "missing"),
    ({"isosurfaces": [{**ISO, "color": {"field": "rho"}}]}, "isosurfaces[0].color.field", "no field 'rho'"),
    ({"isosurfaces": [{**ISO, "color": {"field": "U", "colormap": "nope"}}]}, "isosurfaces[0].color.colormap",
     "unknown colormap"),
    ({"isosurfaces": [{**ISO, "color": {"field": "U", "range": [1, 1]}}]}, "isosurfaces[0].color.range",
     "low < high"),
    ({"isosurfaces": [{**ISO, "opacity": 1.5}]}, "isosurfaces[0].opacity", "in [0, 1]"),
    ({"isosurfaces": [{**ISO, "colour": 1}]}, "isosurfaces[0].colour", "unknown key"),
    ({"slices": [SLICE] * 9}, "slices", "a list of at most 8"),
    ({"slices": [{"point": [0, 0, 0], "field": "T"}]}, "slices[0].normal", "missing"),
    ({"slices": [{**SLICE, "point": [0, 0]}]}, "slices[0].point", "a list of 3 numbers"),
    ({"slices": [{**SLICE, "normal": [0, 0, 0]}]}, "slices[0].normal", "non-zero"),
    ({"slices": [{**SLICE, "field": "rho"}]}, "slices[0].field", "no field 'rho'"),
    ({"slices": [{**SLICE, "colormap": 5}]}, "slices[0].colormap", "a matplotlib colormap name"),
    ({"slices": [{**SLICE, "colormap": "nope"}]}, "slices[0].colormap", "unknown colormap"),
    ({"slices": [{**SLICE, "range": [0, "1"]}]}, "slices[0].range", "[low, high]"),
    ({"slices": [{**SLICE, "opacity": -1}]}, "slices[0].opacity", "in [0, 1]"),
    ({"slices": [{**SLICE, "width": 1}]}, "slices[0].width", "unknown key"),
    ({"clip": [0, 0, 0, 1, 1, 1]}, "clip", "a clip object"),
    ({"clip": {"sphere": 1}}, "clip.sphere", "unknown key"),
    ({"clip": {"box": [0, 0, 0, 1, 1]}}, "clip.box", "six numbers"),
    ({"clip": {"box": [0, 0, 0, 1, -1, 1]}}, "clip.box", "x0 <= x1"),
    ({"clip": {"planes": [[0, 0, 0, 1, 0, 0], [1, 2, 3]]}}, "clip.planes[1]", "six numbers"),
    ({"clip": {"planes": [[0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 0, 0]]}}, "clip.planes[1]", "non-zero"),
    ({"clip": {"planes": [[0, 0, 0, 1, 0, 0]] * 17}}, "clip.planes", "at most 16"),
    ({"lighting": "headlight"}, "lighting", "a lighting object"),
    ({"lighting": {"shading": "phong"}}, "lighting.shading", '"headlight" or "none"'),
    ({"lighting": {"gradient": "sobel"}}, "lighting.gradient", '"analytic" or "central"'),
    ({"lighting": {"specular": -1}}, "lighting.specular", "a number >= 0"),
    ({"lighting": {"shininess": 0}}, "lighting.shininess", "a positive number"),
    ({"lighting": {"ambient_occlusion": 4}}, "lighting.ambient_occlusion", "an ambient-occlusion object"),
    ({"lighting": {"ambient_occlusion": {"samples": 257}}}, "lighting.ambient_occlusion.samples",
     "from 0 to 256"),
    ({"lighting": {"ambient_occlusion": {"samples": 1.5}}}, "lighting.ambient_occlusion.samples",
     "an integer"),
    ({"lighting": {"ambient_occlusion": {"distance": 0}}}, "lighting.ambient_occlusion.distance",
     "a positive number"),
    ({"lighting": {"ambient_occlusion": {"rays": 4}}}, "lighting.ambient_occlusion.rays", "unknown key"),
    ({"lighting": {"diffuse": 0.2}}, "lighting.diffuse", "unknown key"),
    ({"lighting": {"integrator": "paths"}}, "lighting.integrator", "headlight"),
    ({"lighting": {"path": {"bounces": 0}}}, "lighting.path.bounces", "from 1 to 256"),
    ({"lighting": {"path": {"anisotropy": 1}}}, "lighting.path.anisotropy", "[-0.99, 0.99]"),
    ({"lighting": {"path": 8}}, "lighting.path", "a path-tracing object"),
    ({"lighting": {"ambient": -1}}, "lighting.ambient", ">= 0"),
    ({"lighting": {"light": [1, 0, 0]}}, "lighting.light", "a directional light object"),
    ({"lighting": {"light": {"direction": [1, 0]}}}, "lighting.light.direction", "a direction"),
    ({"lighting": {"light": {"direction": [0, 0, 0]}}}, "lighting.light.direction", "is zero"),
    ({"lighting": {"light": {"color": [2, 0, 0]}}}, "lighting.light.color", "[0, 1]"),
    ({"lighting": {"light": {"shine": 1}}}, "lighting.light.shine", "unknown key"),
    ({"background": [1, 1]}, "background", "an RGB or RGBA list"),
    ({"background": [1, 1, 1, 2]}, "background[3]", "in [0, 1]"),
    ({"size": [64]}, "size", "[width, height]"),
    ({"size": [64, 0]}, "size", "from 1 to 32768"),
    ({"spp": 0}, "spp", "from 1 to 4096"),
    ({"spp": 2.5}, "spp", "an integer"),
    ("{\"spp\": 1e400}", "spp", "found Infinity"),
    ({"sampling_rate": -1}, "sampling_rate", "a positive number"),
    ("{\"sampling_rate\": NaN}", "sampling_rate", "found NaN"),
    ({"max_opacity": 0}, "max_opacity", "(0, 1]"),
    ({"seed": -1}, "seed", "from 0 to 4294967295"),
    ({"seed": 2 ** 32}, "seed", "from 0 to 4294967295"),
    ({"jitter": "no"}, "jitter", "true or false"),
    ({"unit_distance": 0}, "unit_distance", "a positive number"),
    ({"depth": 1}, "depth", "true or false"),
]


@pytest.mark.parametrize("doc, key_path, needle", BAD,
                         ids=[f"{k or 'root'}-{i}" for i, (_, k, _) in enumerate(BAD)])
def test_a_bad_scene_file_is_one_error_naming_file_and_key(bricks, tmp_path, doc, key_path, needle):
    path = write(tmp_path, doc)
    with pytest.raises(ExabricksError) as info:
        scene_from_options(bricks, scene_path=path, flags={})
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {key_path}: " if key_path else f"{path}: "), message
    assert needle in message, message


def test_mistakes_are_reported_in_file_order(bricks, tmp_path):
    path = write(tmp_path, '{"spp": 0, "volumes": [{"field": "T", "range": "x"}], "seed": -1}')
    with pytest.raises(ExabricksError, match=r": spp: "):
        read_scene_file(path)


HUGE = "a" * 10_000_000  # a 10 MB key or value: a message quotes at most 80 characters of it


@pytest.mark.parametrize("text, needle", [
    ('{"%s": 1}' % HUGE, "unknown key"),
    ('{"volumes": [{"%s x": 1}]}' % HUGE, "unknown key"),
    ('{"b%s": 1, "b%s": 2}' % (HUGE[:100_000], HUGE[:100_000]), "duplicate key"),
    ('{"volumes": [{"field": "%s"}]}' % HUGE, "no field"),
    ('{"camera": "%s"}' % HUGE, "expected a camera file"),
    ('{"volumes": [{"field": "T", "transfer_function": "%s"}]}' % HUGE, "expected a preset file"),
], ids=["key", "nested-key", "duplicate-key", "field", "camera", "preset"])
def test_a_huge_key_or_value_is_quoted_shortened(bricks, tmp_path, text, needle):
    path = tmp_path / "scene.json"
    path.write_text(text)
    with pytest.raises(ExabricksError) as info:
        scene_from_options(bricks, scene_path=path, flags={})
    message = str(info.value)
    assert needle in message and "..." in message, message[:300]
    assert len(message) < 200 + len(", ".join(scene_schema()["properties"])), message[:300]


def test_cli_quotes_a_huge_key_shortened(tmp_path):
    path = tmp_path / "scene.json"
    path.write_text('{"%s": 1}' % HUGE)
    proc = run_cli("render", GERRIS, "--scene", path, "--size", "8", "8", "-o", tmp_path / "x.png")
    assert_one_error_line(proc, str(path), "unknown key")
    assert len(proc.stderr) < 1000


# ---------------------------------------------------------------------------
# through the command line (errors come before any rendering)


@pytest.mark.slow
def test_cli_names_the_scene_file_and_key(trio, tmp_path):
    scene = write(tmp_path, {"volumes": [VOL, {"field": "T", "transfer_function": 3}]})
    out = tmp_path / "x.png"
    assert_one_error_line(run_cli("render", *trio, "-o", out, "--scene", scene), str(scene),
                          "volumes[1].transfer_function: expected a preset file, a built-in preset name "
                          "or a preset object (found 3)")
    scene = write(tmp_path, {"camera": "nowhere/cam.json"})
    assert_one_error_line(run_cli("render", *trio, "-o", out, "--scene", scene), str(scene), "camera:",
                          "no such file")
    scene = write(tmp_path, {"isosurfaces": [{"field": "rho", "value": 1}]})
    assert_one_error_line(run_cli("render", *trio, "-o", out, "--scene", scene), str(scene),
                          "isosurfaces[0].field", "'rho'")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_cli_refuses_an_output_that_is_a_file_the_scene_names(trio, tmp_path):
    write(tmp_path, PRESET, "tf.png")  # an odd name, but a preset the scene reads
    scene = write(tmp_path, {"volumes": [{"field": "T", "transfer_function": "tf.png"}]})
    proc = run_cli("render", *trio, "-o", tmp_path / "tf.png", "--scene", scene)
    assert_one_error_line(proc, "would overwrite the input")
    assert json.loads((tmp_path / "tf.png").read_text()) == PRESET


@pytest.mark.slow
def test_cli_usage_errors_and_depth_with_png(trio, tmp_path):
    out = tmp_path / "x.png"
    proc = run_cli("render", *trio, "-o", out, "--iso", "1", "--iso-color", "1,0,0", "--iso-color-field", "T")
    assert proc.returncode == 2 and "not both" in proc.stderr
    proc = run_cli("render", *trio, "-o", out, "--clip-plane", "0", "0", "0", "nan", "0", "1")
    assert proc.returncode == 2 and "finite" in proc.stderr
    scene = write(tmp_path, {"depth": True})
    assert_one_error_line(run_cli("render", *trio, "-o", out, "--scene", scene), "depth", ".exr")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def _render_scene_exists() -> bool:
    from exabricks.engine import renderer

    return hasattr(renderer, "render_scene")


@pytest.mark.skipif(not DEVICES or not _render_scene_exists(), reason="needs render_scene and an OpenCL device")
def test_cli_writes_the_scene_into_the_image_metadata(trio, tmp_path):
    from exabricks.film.image_io import read_image

    scene = write(tmp_path, {"volumes": [{"field": "T"}], "size": [24, 16], "jitter": False})
    out = tmp_path / "x.exr"
    run_cli("render", *trio, "-o", out, "--scene", scene, "--spp", "2", check=0)
    rgba, meta = read_image(out)
    assert rgba.shape == (16, 24, 4)
    assert meta["scene"]["spp"] == 2 and meta["scene"]["size"] == [24, 16]
    assert meta["scene"]["volumes"][0]["field"] == "T" and meta["scene"]["jitter"] is False
    assert meta["transfer_function"] == meta["scene"]["volumes"][0]["transfer_function"]
    assert meta["camera"] == meta["scene"]["camera"]


def test_a_scene_object_is_held_to_the_limits_of_its_options():
    """eb.Scene.replace(...) builds a scene without the command line's parsing: its
    check takes each setting's limits from the option that declares it (issue 50,
    item 4), so a negative shininess or a NaN specular weight is refused."""
    import dataclasses

    from exabricks.picture.camera import Camera
    from exabricks.scene import Scene
    from exabricks.scene.options import SCENE_OPTIONS

    scene = Scene(Camera((0, 0, 5), (0, 0, 0), (0, 1, 0)))
    scene.check()
    for part, change, name in (("lighting", {"shininess": -5.0}, "shininess"),
                               ("lighting", {"specular": float("nan")}, "specular"),
                               ("lighting", {"shading": "bogus"}, "shading"),
                               ("lighting", {"ao_samples": 10_000}, "ao_samples"),
                               ("settings", {"lod": -1.0}, "lod"),
                               ("settings", {"spp": 0}, "spp"),
                               ("settings", {"max_opacity": 2.0}, "max_opacity")):
        bad = scene.replace(**{part: dataclasses.replace(getattr(scene, part), **change)})
        with pytest.raises(ExabricksError, match=f"^{name}: "):
            bad.check()
    assert {o.name for o in SCENE_OPTIONS if o.target} >= {"shininess", "specular", "spp", "lod"}
