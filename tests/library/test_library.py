"""The Python library, `import exabricks as eb` (DESIGN.md "The Python library"):
the same pixels as the commands, the render job's strategies, a Renderer that
keeps its upload, the Image, and errors as ExabricksError."""

from __future__ import annotations

import inspect
import io
import json

import numpy as np
import pytest

import exabricks as eb
from exabricks import api
from helpers import GERRIS, ROOT, run_cli

SCENE = ROOT / "docs" / "examples" / "plume-scene.json"
SMALL = {"size": (96, 80), "spp": 1}


@pytest.fixture(scope="module")
def plume(tmp_path_factory):
    return eb.open(GERRIS, cache=tmp_path_factory.mktemp("cache"))


def test_the_public_names_are_documented_and_typed():
    assert set(eb.__all__) == {"__version__", "Dataset", "ExabricksError", "Image", "Renderer", "Scene",
                               "Series", "open", "open_series", "probe", "render", "render_job",
                               "render_series", "view"}
    for name in eb.__all__[1:]:
        obj = getattr(eb, name)
        assert inspect.getdoc(obj), name
        if inspect.isfunction(obj):
            hints = inspect.signature(obj)
            assert hints.return_annotation is not inspect.Signature.empty, name
    assert api.render is eb.render


@pytest.mark.slow
def test_a_scene_file_gives_the_commands_pixels(tmp_path, plume):
    out = tmp_path / "cli.exr"
    run_cli("render", GERRIS, "--scene", SCENE, "--size", "96", "80", "--spp", "2", "-o", out,
            check=0)
    image = eb.render(plume, SCENE, size=(96, 80), spp=2)
    expected = eb.Image.read(out)
    np.testing.assert_array_equal(image.rgba, expected.rgba)
    assert image.metadata["scene"] == expected.metadata["scene"]
    # the same scene as a dict, and as the eb.Scene it resolves to
    doc = json.loads(SCENE.read_text())
    doc["lighting"]["ambient_occlusion"]["samples"] = 8
    with pytest.MonkeyPatch.context() as m:
        m.chdir(SCENE.parent)
        np.testing.assert_array_equal(eb.render(plume, doc, size=(96, 80), spp=2).rgba, expected.rgba)
    scene = eb.Renderer(plume).scene(SCENE, size=(96, 80), spp=2)
    assert isinstance(scene, eb.Scene)
    np.testing.assert_array_equal(eb.render(plume, scene).rgba, expected.rgba)


def test_options_are_the_flags(tmp_path, plume):
    out = tmp_path / "cli.exr"
    run_cli("render", GERRIS, "--field", "T", "--colormap", "inferno", "--opacity", "0,0.2,0.6",
            "--iso", "0.3", "--iso", "0.6", "--iso-opacity", "0.5", "--position", "150", "90", "170",
            "--size", "96", "80", "--spp", "1", "--depth", "-o", out, check=0)
    image = eb.render(plume, field="T", colormap="inferno", opacity="0,0.2,0.6", iso=[0.3, 0.6],
                      iso_opacity=0.5, position=(150, 90, 170), depth=True, **SMALL)
    expected = eb.Image.read(out)
    np.testing.assert_array_equal(image.rgba, expected.rgba)
    np.testing.assert_array_equal(image.depth, expected.depth)
    assert image.size == (96, 80) and image.rgba.dtype == np.float32


def test_a_renderer_keeps_its_upload(plume):
    r = eb.Renderer(plume)
    first = r.render(field="T", **SMALL)
    device = r._renderer
    moved = r.render(field="T", position=(10, 150, 200), colormap="magma", **SMALL)
    assert r._renderer is device  # a new camera and transfer function: only the frame
    assert not np.array_equal(moved.rgba, first.rgba)
    np.testing.assert_array_equal(moved.rgba, eb.render(plume, field="T", position=(10, 150, 200),
                                                        colormap="magma", **SMALL).rgba)
    r.render(field="W", **SMALL)  # another field: uploaded with the one already there
    assert r._fields == ("T", "W")
    np.testing.assert_array_equal(r.render(field="T", **SMALL).rgba, first.rgba)


@pytest.mark.slow
def test_the_render_job_strategies(tmp_path, plume):
    whole = eb.render(plume, field="T", **SMALL)
    eb.render_job(plume, tmp_path / "budget.exr", field="T", memory_budget="3M", **SMALL)
    eb.render_job(plume, tmp_path / "tiles.exr", field="T", tile=(32, 32), **SMALL)
    eb.render_job(plume, tmp_path / "progressive.exr", field="T", progressive=0.01, **SMALL)
    for name in ("budget", "tiles", "progressive"):
        np.testing.assert_allclose(eb.Image.read(tmp_path / f"{name}.exr").rgba, whole.rgba,
                                   atol=2e-6, err_msg=name)
    run_cli("camera", "orbit", plume.paths[0], "--frames", "3", "-o", tmp_path / "path.json", check=0)
    eb.render_job(plume, tmp_path / "f%02d.png", field="T", camera_path=tmp_path / "path.json",
                  frames="0:3", **SMALL)
    assert sorted(p.name for p in tmp_path.glob("f*.png")) == ["f00.png", "f01.png", "f02.png"]


def test_probe_and_the_dataset(plume):
    assert plume.fields == ("P", "T", "U", "V", "W") and plume.levels == 5
    lo, hi = plume.bounds
    points = np.array(lo) + np.random.default_rng(3).random((200, 3)) * (np.array(hi) - np.array(lo))
    values = eb.probe(plume, points, "T")
    assert values.shape == (200,) and values.dtype == np.float32 and np.isfinite(values).all()
    nearest = eb.probe(plume, points, "T", reconstruction="nearest")
    assert np.abs(nearest - values).max() > 0
    triple = eb.open(plume.paths)
    np.testing.assert_array_equal(eb.probe(triple, points, "T"), values)


def test_image_save_and_notebook_display(tmp_path, plume):
    from PIL import Image as PILImage

    image = eb.render(plume, field="T", **SMALL)
    image.save(tmp_path / "a.png")
    back = eb.Image.read(tmp_path / "a.png")
    assert back.metadata["camera"] == image.metadata["camera"]
    shown = PILImage.open(io.BytesIO(image._repr_png_()))
    assert shown.size == (96, 80) and shown.mode == "RGB"
    np.testing.assert_array_equal(np.asarray(shown), image.shown())
    # over black where the frame is transparent (the default background), as it is
    png = image.to_rgba8().astype(float)
    a = png[..., 3:] / 255
    np.testing.assert_array_equal(image.shown(), np.rint(png[..., :3] * a))
    dark = eb.render(plume, field="T", background=(0.2, 0.3, 0.4), **SMALL)
    corner = dark.shown()[0, 0]
    assert np.abs(corner - np.array([0.2, 0.3, 0.4]) * 255).max() <= 0.5 + 1e-6  # float32 colours
    assert "96x80" in repr(image)


def test_errors(plume):
    with pytest.raises(eb.ExabricksError, match="spp: expected an integer from 1"):
        eb.render(plume, spp=0)
    with pytest.raises(eb.ExabricksError, match="no field 'Q'"):
        eb.render(plume, field="Q")
    with pytest.raises(eb.ExabricksError, match=r"scene: volumes\[0\]"):
        eb.render(plume, {"volumes": [{"field": "T", "transfer_function": 3}]})
    with pytest.raises(TypeError, match="use eb.render_job for memory_budget"):
        eb.render(plume, memory_budget="1G")
    with pytest.raises(TypeError, match="unknown option"):
        eb.render(plume, colour="red")
    with pytest.raises(eb.ExabricksError, match="no such file or directory"):
        eb.open("/nonexistent/plotfile")
    with pytest.raises(eb.ExabricksError, match="reconstruction"):
        eb.probe(plume, [[0, 0, 0]], reconstruction="cubic")


@pytest.mark.slow
def test_a_yt_dataset_with_a_field_yt_derives(tmp_path):
    yt = pytest.importorskip("yt")
    from helpers import ENZO

    ds = eb.open(yt.load(str(ENZO)), fields=[("gas", "density"), ("gas", "velocity_magnitude")])
    assert ds.fields == ("density", "velocity_magnitude") and ds.paths is None
    image = eb.render(ds, field="velocity_magnitude", **SMALL)
    assert image.rgba[..., 3].max() > 0.05
    # the same field through ingest --format yt: the same cells, so the same frame
    run_cli("render", ENZO, "--format", "yt", "--fields", "gas:density,gas:velocity_magnitude",
            "--field", "gas:velocity_magnitude", "--size", "96", "80", "--spp", "1", "-o",
            tmp_path / "cli.exr", check=0)
    np.testing.assert_array_equal(eb.Image.read(tmp_path / "cli.exr").rgba, image.rgba)


@pytest.mark.slow
def test_annotated_pictures_from_python_and_the_command(tmp_path, plume):
    image = eb.render(plume, field="T", colormap="inferno", **SMALL)
    image.save(tmp_path / "py.png", annotate=True, title="plume")
    run_cli("render", GERRIS, "--field", "T", "--colormap", "inferno", "--size", "96", "80", "--spp",
            "1", "--annotate", "--title", "plume", "-o", tmp_path / "cli.png", check=0)
    eb.render_job(plume, tmp_path / "job.png", field="T", colormap="inferno", annotate=True,
                  title="plume", **SMALL)
    expected = eb.Image.read(tmp_path / "cli.png").rgba
    assert expected.shape[0] > 80 and expected.shape[1] > 96 and (expected[..., 3] == 1).all()
    for name in ("py", "job"):
        np.testing.assert_array_equal(eb.Image.read(tmp_path / f"{name}.png").rgba, expected,
                                      err_msg=name)
    np.testing.assert_array_equal(image.annotated(title="plume").rgba, expected)
    with pytest.raises(eb.ExabricksError, match="an .exr stays the raw integration"):
        image.save(tmp_path / "a.exr", annotate=True)
    with pytest.raises(eb.ExabricksError, match="no scene to annotate"):
        eb.Image.read(tmp_path / "cli.png").annotated()
    proc = run_cli("render", GERRIS, "--title", "x", "-o", tmp_path / "x.png")
    assert proc.returncode == 2 and "--title goes with --annotate" in proc.stderr
    proc = run_cli("render", GERRIS, "--annotate", "--tile", "32", "32", "-o", tmp_path / "x.png")
    assert proc.returncode == 2 and "not with --tile" in proc.stderr
