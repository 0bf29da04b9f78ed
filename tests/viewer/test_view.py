"""`exabricks view`: the server's security and protocol (a real HTTP and websocket
client), and the page in a real browser (headless Chromium through Selenium):
it loads, a frame appears and refines, a drag orbits, dragging an opacity knot
changes the image, and "Save scene" writes a file whose `render --scene` is the
viewer's converged frame; what a new user meets: a wheel zoom refines to
converged once the wheel stops, a preview fills the frame's place, "Save scene"
is in sight at 1280x800, the first picture is `render`'s with the same options
(the automatic transfer function, not overridden) and "Add iso-surface" starts at
the suggested iso-value. EXABRICKS_VIEW_SCREENSHOTS=DIR keeps the screenshots
(docs/view.md's pictures)."""

from __future__ import annotations

import asyncio
import io
import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from helpers import ATHENA, GERRIS, run_cli
from helpers.browser import assert_same_pixels, converged, screenshot, shown_png, wait_for

pytestmark = pytest.mark.slow
aiohttp = pytest.importorskip("aiohttp")

VIEW = ("--field", "T", "--colormap", "inferno", "--opacity", "0,0.1,0.3,0.6", "--range", "0", "0.6",
        "--position", "129", "63", "148", "--look-at", "64", "33", "64", "--size", "320", "256",
        "--spp", "2")


class Server:
    """`exabricks view` in a subprocess; its URL, base and token."""

    def __init__(self, tmp_path, *args):
        env = {**os.environ, "EXABRICKS_CACHE": str(tmp_path / "cache"), "PYTHONFAULTHANDLER": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "exabricks.cli.main", "view", *map(str, args)],
                                     stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env)
        deadline = time.monotonic() + 120
        self.url = None
        while self.url is None and time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            if not line:
                break
            m = re.search(r"(http://\S+)", line)
            self.url = m.group(1) if m else None
        assert self.url, "the viewer printed no URL"
        self.base, self.token = self.url.split("/?token=")

    def stop(self):
        self.proc.terminate()
        try:
            return self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # show where it hangs (PYTHONFAULTHANDLER)
            import signal

            self.proc.send_signal(signal.SIGABRT)
            time.sleep(2)
            raise AssertionError(self.proc.stderr.read()[-6000:]) from None
        finally:
            self.proc.kill()


@pytest.fixture
def server(tmp_path):
    s = Server(tmp_path, GERRIS, *VIEW, "--scene-out", tmp_path / "scene.json")
    yield s
    assert s.stop() in (0, 143, -15)


def ws_messages(server, send=(), origin=None, until=lambda m: False, count=30, then=()):
    """Messages (decoded JSON, or bytes) of one websocket session that sends `send`
    and reads until `until` (or `count` messages); then, for each (messages,
    predicate) of `then`, sends those and reads until that."""
    async def run():
        jar = aiohttp.CookieJar(unsafe=True)
        async with aiohttp.ClientSession(cookie_jar=jar) as s:
            async with s.get(server.url):
                pass
            got = []
            async with s.ws_connect(server.base + "/ws", headers={"Origin": origin or server.base}) as ws:
                for messages, stop in [(send, until), *then]:
                    for m in messages:
                        await ws.send_str(m if isinstance(m, str) else json.dumps(m))
                    while len(got) < count:
                        msg = await asyncio.wait_for(ws.receive(), 60)
                        if msg.type == aiohttp.WSMsgType.TEXT:
                            got.append(json.loads(msg.data))
                        elif msg.type == aiohttp.WSMsgType.BINARY:
                            got.append(msg.data)
                        else:
                            break
                        if stop(got[-1]):
                            break
            return got
    return asyncio.run(run())


def status(url, headers=None, cookies=None):
    async def run():
        async with aiohttp.ClientSession() as s:
            async with s.get(url, headers=headers or {}, cookies=cookies or {}) as r:
                return r.status
    return asyncio.run(run())


def test_the_server_wants_its_token_its_host_and_its_origin(server):
    assert status(server.base + "/") == 403
    assert status(server.base + "/viewer.js") == 403
    assert status(server.base + "/?token=wrong") == 403
    assert status(server.url) == 200
    assert status(server.base + "/viewer.js?token=" + server.token) == 200
    assert status(server.base + "/ws") == 403  # no token
    assert status(server.url, headers={"Host": "evil.example"}) == 403  # DNS rebinding
    assert status(server.base + "/../../etc/passwd?token=" + server.token) == 404
    assert status(server.base + "/static/viewer.js?token=" + server.token) == 404
    with pytest.raises(aiohttp.WSServerHandshakeError) as e:
        ws_messages(server, origin="http://evil.example")
    assert e.value.status == 403


def test_frames_refine_and_bad_messages_get_an_error(server):
    got = ws_messages(server, until=lambda m: isinstance(m, dict) and m.get("stage") == "converged")
    got = [m for m in got if not (isinstance(m, dict) and m["type"] == "status")]  # kernel builds
    init, frames = got[0], [m for m in got if isinstance(m, dict) and m["type"] == "frame"]
    assert init["type"] == "init" and set(init["fields"]) == {"P", "T", "U", "V", "W"}
    assert [f["stage"] for f in frames] == ["coarse", "full", "converged"]
    assert frames[0]["width"] == 80 and frames[-1]["width"] == 320 and frames[-1]["spp"] == 2
    assert all(isinstance(m, bytes) and m[:8] == b"\x89PNG\r\n\x1a\n" for m in got[2::2])
    protocol = ["not json", "[1, 2]", {"type": 3}, {"type": "nope"}, {"type": "scene"}]
    scenes = [({"camera": "/etc/passwd"}, "inline camera object, not a file"),
              ({"volumes": [{"field": "T", "transfer_function": "/etc/passwd"}]}, "not a file"),
              ({"spp": 0}, "spp"), ({"volumes": "x" * 100}, "volumes")]
    is_error = lambda m: isinstance(m, dict) and m.get("type") == "error"  # noqa: E731
    errors = [m["message"] for m in ws_messages(server, send=protocol, count=60,
                                               until=lambda m: is_error(m) and "scene object" in m["message"])
              if is_error(m)]
    for doc, needle in scenes:  # one at a time: a newer scene drops an older one unchecked
        got = ws_messages(server, send=[{"type": "scene", "scene": doc}], count=60, until=is_error)
        errors.append(got[-1]["message"])
        assert needle in got[-1]["message"], (needle, got[-1])
    text = " | ".join(errors)
    for needle in ("not a JSON message", 'a message is an object with a "type"', "unknown message type",
                   '"scene" needs a scene object'):
        assert needle in text, (needle, text)
    # the server still draws after all that
    assert any(isinstance(m, dict) and m.get("stage") == "coarse" for m in ws_messages(server, count=4))


@pytest.mark.fuzz
def test_hostile_requests_never_crash_the_server(server):
    from hypothesis import HealthCheck, given, settings, strategies as st

    from helpers import FUZZ_EXAMPLES

    json_values = st.recursive(st.none() | st.booleans() | st.floats() | st.text(max_size=20),
                               lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=8), c, max_size=4),
                               max_leaves=20)
    messages = st.one_of(st.text(max_size=200), json_values.map(json.dumps),
                         st.fixed_dictionaries({"type": st.sampled_from(["scene", "save", "x"]),
                                                "scene": json_values}).map(json.dumps))

    @settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(messages, min_size=1, max_size=5), st.text(max_size=40))
    def attack(sent, path):
        # A newer scene drops an older one unchecked, so the replies are not one per
        # message: read until the answer to a last message that always gets one.
        end = lambda m: isinstance(m, dict) and "end-of-attack" in m.get("message", "")  # noqa: E731
        got = ws_messages(server, send=[*sent, {"type": "end-of-attack"}], count=1000, until=end)
        assert end(got[-1]), got[-3:]
        status(server.base + "/" + path.replace("?", "").replace("#", ""))

    attack()
    assert server.proc.poll() is None
    assert status(server.url) == 200
    assert any(isinstance(m, dict) and m.get("stage") == "coarse" for m in ws_messages(server, count=4))


def test_save_scene_renders_the_viewers_frame(server, tmp_path):
    got = ws_messages(server, count=40, until=after_converged(),
                      then=[([{"type": "save"}], lambda m: isinstance(m, dict) and m.get("type") == "saved")])
    assert got[-1]["type"] == "saved" and got[-1]["path"] == str(tmp_path / "scene.json")
    doc = json.loads((tmp_path / "scene.json").read_text())
    assert doc == got[-1]["scene"]
    converged = frame_after(got, "converged")
    assert_renders(doc, tmp_path, converged)


def after_converged():
    """A predicate true at the PNG that follows a "converged" frame message."""
    seen = []

    def stop(m):
        if isinstance(m, dict):
            seen.append(m.get("stage"))
            return False
        return bool(seen) and seen[-1] == "converged"
    return stop


def frame_after(got, stage):
    i = next(i for i, m in enumerate(got) if isinstance(m, dict) and m.get("stage") == stage)
    return got[i + 1]


def assert_renders(scene_file_or_doc, tmp_path, png: bytes, *options):
    """`render --scene` of the document to a .png is `png` (the viewer's frame), pixel
    for pixel."""
    path = tmp_path / "check.json"
    if isinstance(scene_file_or_doc, dict):
        path.write_text(json.dumps(scene_file_or_doc))
    else:
        shutil.copy(scene_file_or_doc, path)
    run_cli("render", GERRIS, "--scene", path, *options, "-o", tmp_path / "check.png", check=0)
    assert_same_pixels(png, tmp_path / "check.png")



# -- the page in a real browser --------------------------------------------------


def test_the_page_in_a_browser(server, browser, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    started = time.monotonic()
    browser.get(server.url)
    first = wait_for(browser, "const f = window.exabricks.frame; return f ? f : null")
    assert first["stage"] in ("coarse", "full", "converged")
    frame = converged(browser)
    assert frame["width"] == 320 and frame["spp"] == 2 and time.monotonic() - started < 60
    status_text = browser.find_element(By.ID, "status").text
    assert "converged 320×256, 2 spp" in status_text and "samples/s" in status_text
    screenshot(browser, "view-plume.png")
    before = shown_png(browser)

    # a drag orbits the camera
    position = browser.execute_script("return window.exabricks.doc.camera.position.slice()")
    view = browser.find_element(By.ID, "view")
    ActionChains(browser).move_to_element(view).click_and_hold().move_by_offset(80, 0) \
        .move_by_offset(40, 10).release().perform()
    frame = converged(browser, frame["version"])
    moved = browser.execute_script("return window.exabricks.doc.camera.position")
    assert np.linalg.norm(np.subtract(moved, position)) > 10
    look_at = browser.execute_script("return window.exabricks.doc.camera.look_at")
    assert np.allclose(np.linalg.norm(np.subtract(moved, look_at)),
                       np.linalg.norm(np.subtract(position, look_at)), rtol=1e-6)  # an orbit
    orbited = shown_png(browser)
    assert orbited != before

    # dragging an opacity knot (the last, at the top right) down changes the image
    knots = browser.execute_script("return window.exabricks.doc.volumes[0].transfer_function.opacity.slice()")
    canvas = browser.find_element(By.ID, "opacity")
    w, h = canvas.size["width"], canvas.size["height"]
    y_last = 5 + (1 - knots[-1]) * (h - 10)
    ActionChains(browser).move_to_element_with_offset(canvas, w / 2 - 5, y_last - h / 2).click_and_hold() \
        .move_by_offset(0, 40).release().perform()
    frame = converged(browser, frame["version"])
    dragged = browser.execute_script("return window.exabricks.doc.volumes[0].transfer_function.opacity")
    assert dragged[:-1] == knots[:-1] and dragged[-1] < knots[-1] - 0.2
    assert shown_png(browser) != orbited
    screenshot(browser, "view-knot.png")

    # an iso-surface, then "Save scene": render --scene of it draws the viewer's frame
    browser.find_element(By.ID, "iso-add").click()
    frame = converged(browser, frame["version"])
    browser.find_element(By.ID, "save").click()
    wait_for(browser, "return document.getElementById('saved').textContent")
    assert str(tmp_path / "scene.json") in browser.find_element(By.ID, "saved").text
    assert_renders(tmp_path / "scene.json", tmp_path, shown_png(browser))
    screenshot(browser, "view-iso.png")
    logs = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    assert not logs, logs


def test_shadows_keep_the_first_key_light_as_the_camera_orbits(server, browser, tmp_path):
    """Choosing the shadow integrator lights the frame by the camera's key light,
    which the page then takes as the scene's own (docs/view.md, "Lights"): its
    direction fills the light fields and stays while a drag orbits the camera, so
    that the light's cached transmittance is reused; the saved scene renders the
    viewer's frame."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    browser.get(server.url)
    frame = converged(browser)
    Select(browser.find_element(By.ID, "integrator")).select_by_value("shadow")
    frame = converged(browser, frame["version"])
    toward = browser.execute_script("return window.exabricks.doc.lighting.light.direction")
    assert np.isclose(np.linalg.norm(toward), 1.0, atol=1e-9)
    shown = [float(browser.find_element(By.ID, f"light-{a}").get_attribute("value")) for a in "xyz"]
    np.testing.assert_allclose(shown, toward, atol=1e-9)
    ActionChains(browser).move_to_element(browser.find_element(By.ID, "view")).click_and_hold() \
        .move_by_offset(60, 0).release().perform()
    frame = converged(browser, frame["version"])
    assert browser.execute_script("return window.exabricks.doc.lighting.light.direction") == toward
    browser.find_element(By.ID, "save").click()
    wait_for(browser, "return document.getElementById('saved').textContent")
    saved = json.loads((tmp_path / "scene.json").read_text())
    assert saved["lighting"]["integrator"] == "shadow" and saved["lighting"]["light"]["direction"] == toward
    assert_renders(tmp_path / "scene.json", tmp_path, shown_png(browser))


PAGE_BACKGROUND = (0x16, 0x18, 0x1D)  # viewer.css: body's background


def in_sight(driver, element_id):
    """Whether the element lies wholly within the viewport, on top there (not covered)."""
    return driver.execute_script(
        "const e = document.getElementById(arguments[0]), r = e.getBoundingClientRect();"
        "return r.width > 0 && r.height > 0 && r.left >= 0 && r.top >= 0 && r.right <= innerWidth && "
        "r.bottom <= innerHeight && document.elementFromPoint((r.left + r.right) / 2, (r.top + r.bottom) / 2) === e",
        element_id)


def test_a_new_user_zooms_drags_and_saves(server, browser):
    """A wheel zoom refines to a converged frame once the wheel stops; a preview
    during a drag fills the place of the whole frame; "Save scene" is in sight at
    1280x800 and every control can be scrolled to."""
    from PIL import Image as PILImage
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
    from selenium.webdriver.common.by import By

    browser.get(server.url)
    frame = converged(browser)
    whole = browser.execute_script("return document.getElementById('frame').getBoundingClientRect().toJSON()")
    assert (whole["width"], whole["height"]) == (320, 256)

    # "Save scene" in sight without scrolling; the last control reachable by scrolling the panel
    assert browser.execute_script("return [innerWidth, outerHeight]") == [1280, 800]
    assert in_sight(browser, "save"), browser.find_element(By.ID, "save").rect
    browser.execute_script("document.getElementById('spp').scrollIntoView({block: 'nearest'})")
    assert in_sight(browser, "spp") and in_sight(browser, "save")

    # a wheel zoom and then nothing: the frame refines to the whole size at the scene's samples
    camera = browser.execute_script("return window.exabricks.doc.camera")
    distance = np.linalg.norm(np.subtract(camera["position"], camera["look_at"]))
    view = browser.find_element(By.ID, "view")
    ActionChains(browser).scroll_from_origin(ScrollOrigin.from_element(view), 0, 200).perform()
    frame = converged(browser, frame["version"], timeout=30)
    camera = browser.execute_script("return window.exabricks.doc.camera")
    assert np.linalg.norm(np.subtract(camera["position"], camera["look_at"])) > distance * 1.05
    assert (frame["width"], frame["height"], frame["spp"]) == (320, 256, 2)
    assert browser.find_element(By.ID, "status").get_attribute("data-stage") == "converged"

    # mid-drag (the button held, no more motion): a quarter-size preview, drawn over the whole frame's place
    ActionChains(browser).move_to_element(view).click_and_hold().move_by_offset(30, 0) \
        .move_by_offset(10, 5).perform()
    preview = wait_for(browser, "const f = window.exabricks.frame, img = document.getElementById('frame');"
                                "return f && f.stage === 'coarse' && f.version === window.exabricks.version && "
                                "img.complete && img.naturalWidth === f.width ? f : null")
    assert (preview["width"], preview["height"]) == (80, 64)
    box = browser.execute_script("return document.getElementById('frame').getBoundingClientRect().toJSON()")
    assert (box["width"], box["height"]) == (320, 256) and box == whole
    shot = np.asarray(PILImage.open(io.BytesIO(browser.get_screenshot_as_png())).convert("RGB")).astype(int)
    x0, y0 = round(box["left"]), round(box["top"])
    drawn = shot[y0:y0 + 256, x0:x0 + 320]
    page = np.all(np.abs(drawn - PAGE_BACKGROUND) <= 2, axis=-1)
    assert page.mean() < 0.01, f"{page.mean():.1%} of the frame's place shows the page, not the preview"
    screenshot(browser, "view-drag-preview.png")
    ActionChains(browser).release().perform()
    frame = converged(browser, preview["version"] - 1)
    assert frame["width"] == 320
    logs = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    assert not logs, logs


def test_the_first_picture_is_renders_and_an_iso_surface_shows(tmp_path, browser):
    """With no transfer function given, the page's first converged frame is what
    `render` draws with the same options (the automatic transfer function, the
    framing camera, an opaque background), pixel for pixel: the page shows the
    automatic function's knots without replacing it. "Add iso-surface" starts at
    suggested_iso_value of the field (the blast's shell)."""
    from selenium.webdriver.common.by import By

    import exabricks as eb
    from exabricks.picture.auto_transfer import suggested_iso_value

    s = Server(tmp_path, ATHENA, "--field", "rho")
    try:
        browser.get(s.url)
        frame = converged(browser)
        doc = browser.execute_script("return window.exabricks.doc")
        assert doc["volumes"] == [{"field": "rho", "transfer_function": {"colormap": "viridis"}}]
        layer = browser.execute_script("return window.exabricks.layer")
        assert layer["field"] == "rho" and len(layer["opacity"]) > 2 and 0 < max(layer["opacity"]) < 0.5
        assert in_sight(browser, "save")
        screenshot(browser, "view-blast.png")
        viewer = shown_png(browser)

        browser.find_element(By.ID, "iso-add").click()
        iso = browser.execute_script("return window.exabricks.doc.isosurfaces")
        assert len(iso) == 1 and iso[0]["field"] == "rho"
        assert iso[0]["value"] == suggested_iso_value(eb.open(ATHENA).bricks, "rho")
        converged(browser, frame["version"])
        screenshot(browser, "view-blast-iso.png")
        logs = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
        assert not logs, logs
    finally:
        s.stop()
    run_cli("render", ATHENA, "--field", "rho", "-o", tmp_path / "render.png", check=0)
    assert_same_pixels(viewer, tmp_path / "render.png")


def test_a_view_within_a_memory_budget(tmp_path):
    """`view --memory-budget` draws domain by domain; its saved scene renders the same
    frame with `render --scene --memory-budget`."""
    s = Server(tmp_path, GERRIS, *VIEW, "--memory-budget", "8M", "--scene-out", tmp_path / "scene.json")
    try:
        got = ws_messages(s, count=40, until=after_converged(),
                          then=[([{"type": "save"}], lambda m: isinstance(m, dict) and m.get("type") == "saved")])
    finally:
        s.stop()
    assert_renders(tmp_path / "scene.json", tmp_path, frame_after(got, "converged"), "--memory-budget", "8M")


def test_a_server_that_cannot_listen_says_so():
    from helpers import assert_one_error_line

    assert_one_error_line(run_cli("view", GERRIS, "--host", "203.0.113.1"), "--host 203.0.113.1",
                          "cannot listen there")
