"""The viewer in a notebook (exabricks/viewer/notebook.py): the widget's side of the
comm without a browser (the page's messages in, frames and replies out), and the
widget in a real JupyterLab in headless Chromium: the cell shows frames, a drag
changes them, "Save scene" writes the file, and `viewer.document` and
`viewer.scene` in the kernel are that scene and draw that frame; then the same
notebook in Notebook 7. EXABRICKS_VIEW_SCREENSHOTS=DIR keeps the screenshots."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from helpers import GERRIS
from helpers.browser import assert_same_pixels

pytest.importorskip("anywidget")

OPTIONS = {"field": "T", "colormap": "inferno", "range": (0, 0.6), "size": (160, 128), "spp": 2}


def frames(widget, messages, count, timeout=60):
    """The messages the widget sends (decoded text, or PNG bytes) once it has sent
    `count` PNGs after the page's `messages`."""
    sent = []
    widget.send = lambda content, buffers=None: sent.append(buffers[0] if content.get("binary")
                                                          else json.loads(content["text"]))
    for m in messages:
        widget._received(widget, {"text": json.dumps(m)}, [])
    deadline = time.monotonic() + timeout
    while sum(isinstance(m, bytes) for m in sent) < count and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.1)
    return sent


@pytest.fixture
def viewer(tmp_path):
    import exabricks as eb

    widget = eb.view(eb.open(GERRIS, cache=False), scene_out=tmp_path / "scene.json", **OPTIONS)
    yield widget
    widget.close()


def test_the_widget_draws_in_stages_saves_and_reads_back(viewer, tmp_path):
    import exabricks as eb

    got = frames(viewer, [{"type": "hello"}], 3)
    assert got[0]["type"] == "init" and got[0]["scene"]["size"] == [160, 128]
    assert [m["stage"] for m in got if isinstance(m, dict) and m["type"] == "frame"] == \
        ["coarse", "full", "converged"]

    doc = json.loads(json.dumps(got[0]["scene"]))
    doc["camera"]["position"][0] += 20
    got = frames(viewer, [{"type": "scene", "scene": doc, "version": 7}], 3)
    headers = [m for m in got if isinstance(m, dict)]
    assert headers[-1]["stage"] == "converged" and headers[-1]["version"] == 7
    png = got[-1]

    got = frames(viewer, [{"type": "save"}], 0)
    saved = next(m for m in got if m["type"] == "saved")
    written = json.loads((tmp_path / "scene.json").read_text())
    assert saved["path"] == str(tmp_path / "scene.json") and written == saved["scene"] == viewer.document
    assert viewer.document["camera"]["position"] == doc["camera"]["position"]

    # viewer.scene, for eb.render, draws what the page shows
    eb.render(viewer.session.renderer.dataset, viewer.scene).save(tmp_path / "python.png")
    assert_same_pixels(png, tmp_path / "python.png")


def test_bad_messages_get_an_error_and_the_widget_goes_on(viewer):
    sent = []
    viewer.send = lambda content, buffers=None: sent.append(content)
    for content in ({"text": 5}, {}, [1], {"text": "{"}, {"text": '{"type": "nonsense"}'},
                    {"text": '{"type": "scene", "scene": {"size": [1e9, 1e9]}}'}):
        viewer._received(viewer, content, [])
    deadline = time.monotonic() + 30
    while len(sent) < 6 and time.monotonic() < deadline:
        time.sleep(0.02)
    errors = [json.loads(m["text"]) for m in sent]
    assert len(errors) == 6 and all(e["type"] == "error" and "\n" not in e["message"] for e in errors), errors
    got = frames(viewer, [{"type": "hello"}], 3)
    assert got[0]["type"] == "init" and sum(isinstance(m, bytes) for m in got) == 3
    viewer.close()
    viewer.send = lambda *a, **k: pytest.fail("a closed widget sends nothing")
    viewer._received(viewer, {"text": '{"type": "hello"}'}, [])
    time.sleep(0.3)


def test_a_widget_no_view_shows_frees_its_threads_and_the_device():
    """`viewer = eb.view(ds)` run again and again: each time the earlier widget's
    view goes ("bye": its output replaced) and the widget is dropped; its threads
    and the dataset's copy on the device go with it, not only on close()."""
    import gc
    import threading
    import weakref

    import exabricks as eb

    dataset = eb.open(GERRIS, cache=False)
    baseline, uploads = threading.active_count(), []
    for _ in range(4):
        viewer = eb.view(dataset, **OPTIONS)
        assert sum(isinstance(m, bytes) for m in frames(viewer, [{"type": "hello"}], 3)) == 3
        uploads.append(weakref.ref(viewer.session.renderer._renderer))
        assert threading.active_count() > baseline
        viewer._received(viewer, {"text": json.dumps({"type": "bye"})}, [])
        del viewer
    gc.collect()
    assert threading.active_count() == baseline, threading.enumerate()
    assert [u() for u in uploads] == [None] * 4


def test_without_anywidget_one_error_line(monkeypatch):
    import sys

    import exabricks as eb
    from exabricks.viewer import notebook

    monkeypatch.setitem(sys.modules, "anywidget", None)
    notebook._widget_class.cache_clear()
    try:
        with pytest.raises(eb.ExabricksError, match=r"pip install 'exabricks\[notebook\]'"):
            eb.view(GERRIS)
    finally:
        notebook._widget_class.cache_clear()


# -- in a real JupyterLab --------------------------------------------------------

CELL = """from pathlib import Path

import exabricks as eb

plume = Path(eb.__file__).parent / "data" / "gerris-plume" / "plume7-1.cells"
viewer = eb.view(plume, field="T", colormap="inferno", range=(0, 0.6), size=(320, 256), spp=2,
                 scene_out="scene.json")
viewer"""
VIEW = "window.exabricksViews && window.exabricksViews[0]"


@pytest.mark.slow
def test_the_viewer_in_jupyterlab(tmp_path, browser):
    pytest.importorskip("jupyterlab")
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    from helpers.browser import converged, screenshot, shown_png, wait_for
    from helpers.jupyter import Lab

    lab = Lab(tmp_path, [CELL], env={"EXABRICKS_CACHE": str(tmp_path / "cache")})
    try:
        browser.get(lab.url())
        lab.run_all(browser)
        frame = converged(browser, state=VIEW, timeout=180)
        assert frame["width"] == 320 and frame["spp"] == 2
        status = browser.find_element(By.CSS_SELECTOR, ".exabricks-inline #status").text
        assert "converged 320×256, 2 spp" in status, status
        before = shown_png(browser, VIEW)

        # a drag in the cell orbits the camera and draws a new frame
        view = browser.find_element(By.CSS_SELECTOR, ".exabricks-inline #view")
        browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", view)
        position = browser.execute_script(f"return {VIEW}.doc.camera.position.slice()")
        ActionChains(browser).move_to_element(view).click_and_hold().move_by_offset(80, 0) \
            .move_by_offset(40, 10).release().perform()
        frame = converged(browser, frame["version"], state=VIEW)
        assert np.linalg.norm(np.subtract(browser.execute_script(f"return {VIEW}.doc.camera.position"),
                                          position)) > 10
        shown = shown_png(browser, VIEW)
        assert shown != before
        browser.set_window_size(1280, 1100)  # the cell and the whole widget, for docs/view.md
        browser.execute_script("window.jupyterapp.shell.collapseLeft(); "
                               "document.querySelector('.jp-Cell').scrollIntoView()")
        screenshot(browser, "view-jupyterlab.png")

        # "Save scene" writes scene_out; the kernel's viewer.document is that scene, and
        # eb.render of viewer.scene draws the frame the cell shows
        save = browser.find_element(By.CSS_SELECTOR, ".exabricks-inline #save")
        browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", save)
        save.click()
        wait_for(browser, "const e = document.querySelector('.exabricks-inline #saved'); "
                          "return e && e.textContent")
        saved = json.loads((tmp_path / "scene.json").read_text())
        document = lab.evaluate("import json; viewer.scene; print(json.dumps(viewer.document))")
        assert document == saved
        lab.evaluate("eb.render(plume, viewer.scene).save('python.png'); print(1)")
        assert_same_pixels(shown, tmp_path / "python.png")
        logs = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
        assert not logs, logs

        # the same notebook in Notebook 7 (the same kernel): frames, and a drag changes them
        browser.get(lab.url("notebooks"))
        lab.run_all(browser)
        frame = converged(browser, state=VIEW, timeout=180)
        view = browser.find_element(By.CSS_SELECTOR, ".exabricks-inline #view")
        browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", view)
        before = shown_png(browser, VIEW)
        ActionChains(browser).move_to_element(view).click_and_hold().move_by_offset(-60, 20).release().perform()
        converged(browser, frame["version"], state=VIEW)
        assert shown_png(browser, VIEW) != before
        screenshot(browser, "view-notebook7.png")
    finally:
        lab.stop()
