"""The notebooks of docs/examples run as written through a real Jupyter kernel
(nbclient + ipykernel), from a folder that is not their own, show their pictures,
and show no warning noise: walkthrough.ipynb, and viewer-and-series.ipynb (the
viewer in the cell, a series with one colour range, its movie). (docs/python.md's
examples: tests/docs/test_docs_examples.py; the viewer's widget in a real
JupyterLab: tests/viewer/test_notebook.py.)"""

from __future__ import annotations

import base64
import io
import os

import numpy as np
import pytest

from helpers import ROOT

EXAMPLES = ROOT / "docs" / "examples"
NOTEBOOKS = ("viewer-and-series.ipynb", "walkthrough.ipynb")  # each run and checked below
PLUME = ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells"


def test_every_notebook_of_the_examples_is_run_here():
    assert sorted(p.name for p in EXAMPLES.glob("*.ipynb")) == sorted(NOTEBOOKS)


def run_notebook(name, tmp_path):
    """The notebook `name` of docs/examples, run in a folder of its own: (its cells with
    their outputs, its pictures, the folder). No cell writes to stderr or fails."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    from PIL import Image as PILImage

    nb = nbformat.read(EXAMPLES / name, as_version=4)
    folder = tmp_path / "anywhere"  # not the notebook's folder: it finds its data itself
    folder.mkdir()
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(folder)}})
    os.environ.setdefault("EXABRICKS_CACHE", str(tmp_path / "cache"))  # the kernel inherits it
    client.execute()
    pictures, noise = [], []
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            if out.get("name") == "stderr":
                noise.append(out["text"])
            if out.get("output_type") == "error":
                noise.append(out["ename"])
            if "image/png" in out.get("data", {}):
                pictures.append(PILImage.open(io.BytesIO(base64.b64decode(out["data"]["image/png"]))))
    assert not noise, noise
    return nb.cells, pictures, folder


@pytest.mark.slow
def test_the_walkthrough_notebook_runs_and_shows_its_pictures(tmp_path):
    import exabricks as eb

    cells, pictures, _ = run_notebook("walkthrough.ipynb", tmp_path)
    sizes = [p.size for p in pictures]
    assert len(pictures) == 5, sizes
    assert sizes[:3] == [(384, 384), (384, 384), (640, 160)]
    assert all(w > 384 and h > 384 for w, h in sizes[3:])  # the annotated pictures: side panels
    # the first picture is the library's frame, pixel for pixel
    expected = eb.render(eb.open(PLUME), field="T", colormap="inferno", position=(120, 106, 140),
                         look_at=(64, 40, 64), size=(384, 384))
    np.testing.assert_array_equal(np.asarray(pictures[0]), expected.shown())
    for p in pictures:  # every picture shows something
        assert np.asarray(p.convert("L")).std() > 5
    # the error cell printed the command's message
    printed = [o["text"] for c in cells for o in c.get("outputs", []) if o.get("name") == "stdout"]
    assert any("no field 'Q'" in t for t in printed), printed



@pytest.mark.slow
def test_the_viewer_and_series_notebook_runs_and_shows_its_pictures(tmp_path):
    pytest.importorskip("anywidget")
    import exabricks as eb

    cells, pictures, folder = run_notebook("viewer-and-series.ipynb", tmp_path)
    data = [o.get("data", {}) for c in cells for o in c.get("outputs", [])]
    # the viewer's cell shows the widget, and eb.render of viewer.scene is its first picture
    assert any("model_id" in d.get("application/vnd.jupyter.widget-view+json", {}) for d in data), data
    expected = eb.render(eb.open(PLUME), field="T", colormap="inferno", range=(0, 0.6), size=(640, 400), spp=4)
    assert len(pictures) == 2 and pictures[0].size == (640, 400)
    np.testing.assert_array_equal(np.asarray(pictures[0]), expected.shown())
    # eight steps with one colour range; their frames side by side; the movie, embedded
    assert any(d.get("text/plain", "").startswith("(8, (") for d in data), data
    assert pictures[1].size == (8 * 160, 120) and np.asarray(pictures[1].convert("L")).std() > 5
    assert any("data:video/mp4;base64," in d.get("text/html", "") for d in data)
    assert len(sorted((folder / "frames").glob("*.png"))) == 8 and (folder / "phi.mp4").stat().st_size > 1000
