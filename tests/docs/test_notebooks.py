"""docs/examples/walkthrough.ipynb runs as written through a real Jupyter kernel
(nbclient + ipykernel), from a folder that is not its own, shows its pictures, and
shows no warning noise. (docs/python.md's examples: tests/docs/test_docs_examples.py.)"""

from __future__ import annotations

import base64
import io
import os

import numpy as np
import pytest

from helpers import ROOT

NOTEBOOK = ROOT / "docs" / "examples" / "walkthrough.ipynb"


@pytest.mark.slow
def test_the_walkthrough_notebook_runs_and_shows_its_pictures(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    from PIL import Image as PILImage

    import exabricks as eb

    nb = nbformat.read(NOTEBOOK, as_version=4)
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
    sizes = [p.size for p in pictures]
    assert len(pictures) == 5, sizes
    assert sizes[:3] == [(384, 384), (384, 384), (640, 160)]
    assert all(w > 384 and h > 384 for w, h in sizes[3:])  # the annotated pictures: side panels
    # the first picture is the library's frame, pixel for pixel
    plume = ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells"
    expected = eb.render(eb.open(plume), field="T", colormap="inferno", position=(120, 106, 140),
                         look_at=(64, 40, 64), size=(384, 384))
    np.testing.assert_array_equal(np.asarray(pictures[0]), expected.shown())
    for p in pictures:  # every picture shows something
        assert np.asarray(p.convert("L")).std() > 5
    # the error cell printed the command's message
    printed = [o["text"] for c in nb.cells for o in c.get("outputs", []) if o.get("name") == "stdout"]
    assert any("no field 'Q'" in t for t in printed), printed

