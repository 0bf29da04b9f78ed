"""`exabricks view` against hostile inputs (issue 49, the viewer's part): a frame
in progress is cancelled by a newer change within a second, and one change may
ask only so much; a FIFO or a device as --scene-out is refused and a save never
holds the server's loop; a built-in preset name never makes the server read a
file; a non-ASCII cookie gets 403, not 500."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import threading
import time

import numpy as np
import pytest

from conftest import GERRIS

aiohttp = pytest.importorskip("aiohttp")


class StubSession:
    """What the server needs of a Session, without a device: frames are never drawn."""

    doc = {"volumes": []}

    def info(self):
        return {"type": "init", "scene": self.doc}

    def check(self, doc):
        return doc

    def layer(self, scene):
        return None

    def stages(self, scene, moving=False):
        return []


def serving(viewer, body):
    """Run `await body(base_url)` with `viewer` listening; the server stops after."""
    async def run():
        url = await viewer.start()
        try:
            return await body(url.split("/?token=")[0])
        finally:
            await asyncio.wait_for(viewer.stop(), 5)
    return asyncio.run(run())


async def raw_get(base: str, headers: bytes) -> bytes:
    """The status line of a GET / with `headers` (raw bytes: a client library would
    refuse to send what a hostile one does)."""
    host, port = base.removeprefix("http://").rsplit(":", 1)
    reader, writer = await asyncio.open_connection(host, int(port))
    writer.write(b"GET / HTTP/1.1\r\nHost: " + f"{host}:{port}".encode() + b"\r\n" + headers +
                 b"Connection: close\r\n\r\n")
    await writer.drain()
    line = await asyncio.wait_for(reader.readline(), 10)
    writer.close()
    return line


def test_a_non_ascii_cookie_gets_403_and_no_traceback(caplog):
    from exabricks.viewer.server import COOKIE, Viewer

    viewer = Viewer(StubSession())

    async def body(base):
        return [await raw_get(base, cookie) for cookie in (
            "Cookie: exabricks_view_token=é\r\n".encode(),
            b"Cookie: exabricks_view_token=\xff\xc3\x28\r\n",
            b"Cookie: \xff\xfe=\xc3\x28\r\n",
            f"Cookie: a=\u00e9; {COOKIE}={viewer.token}\r\n".encode(),
            f"Cookie: {COOKIE}={viewer.token}\r\n".encode())]

    with caplog.at_level(logging.DEBUG, logger="aiohttp"):
        lines = serving(viewer, body)
    assert [line.split()[1] for line in lines[:3]] == [b"403", b"403", b"403"], lines
    assert lines[3].split()[1] in (b"200", b"403") and lines[4].split()[1] == b"200", lines
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text


def test_a_fifo_or_a_device_as_scene_out_is_refused(tmp_path):
    from exabricks.errors import ExabricksError
    from exabricks.viewer.server import Viewer

    fifo = tmp_path / "scene.fifo"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "FIFO"), ("/dev/null", "device"), (tmp_path, "directory")):
        with pytest.raises(ExabricksError, match=f"--scene-out .*is a {kind}"):
            Viewer(StubSession(), scene_out=path)


async def ws_save(base: str, token: str) -> dict:
    async with aiohttp.ClientSession() as s:
        async with s.ws_connect(f"{base}/ws?token={token}", headers={"Origin": base}) as ws:
            await ws.receive()  # init
            await ws.send_str(json.dumps({"type": "save"}))
            return json.loads((await asyncio.wait_for(ws.receive(), 10)).data)


def test_a_save_never_holds_the_servers_loop(tmp_path, monkeypatch):
    """A FIFO put at --scene-out after the start is refused when a page saves; and a
    write that blocks (a FIFO swapped in after that check) holds neither the other
    requests nor the stop."""
    from exabricks.viewer import server

    out = tmp_path / "scene.json"
    viewer = server.Viewer(StubSession(), scene_out=out)
    os.mkfifo(out)

    async def refused(base):
        return await asyncio.wait_for(ws_save(base, viewer.token), 10)

    reply = serving(viewer, refused)
    assert reply["type"] == "error" and "is a FIFO" in reply["message"], reply

    monkeypatch.setattr(server, "_regular_output", lambda path: None)  # the race: the FIFO comes later
    viewer = server.Viewer(StubSession(), scene_out=out)

    async def blocked(base):
        save = asyncio.ensure_future(ws_save(base, viewer.token))
        await asyncio.sleep(0.5)
        assert not save.done()  # the write waits for a reader of the FIFO ...
        started = time.monotonic()
        async with aiohttp.ClientSession() as s:  # ... and the server still answers
            async with s.get(f"{base}/?token={viewer.token}") as r:
                assert r.status == 200
        assert time.monotonic() - started < 2
        save.cancel()

    started = time.monotonic()
    try:
        serving(viewer, blocked)
        assert time.monotonic() - started < 5  # stopped at once, the write still blocked
    finally:  # let the blocked writer go
        fd = os.open(out, os.O_RDONLY | os.O_NONBLOCK)
        time.sleep(0.2)
        os.close(fd)


# -- a real Session (the device) ---------------------------------------------------


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    import exabricks as eb
    from exabricks.viewer.session import Session

    return Session(eb.open(GERRIS, cache=tmp_path_factory.mktemp("cache")),
                   options={"field": "T", "size": (64, 48)})


def test_a_builtin_preset_name_never_reads_a_file(session, tmp_path, monkeypatch):
    """A page's scene naming `default` or `inferno-shells` draws the built-in preset,
    whatever file of that name the server's working directory holds."""
    from exabricks.scene import choose_transfer_function

    monkeypatch.chdir(tmp_path)
    bricks = session.renderer.dataset.bricks
    for name in ("default", "inferno-shells"):
        (tmp_path / name).write_text(json.dumps([{"ColorSpace": "RGB", "Name": "planted",
                                                  "RGBPoints": [0, 1, 0, 0, 1, 1, 0, 0],
                                                  "Points": [0, 1, 0.5, 0, 1, 1, 0.5, 0]}]))
        scene = session.check({"volumes": [{"field": "T", "transfer_function": name}]})
        want = choose_transfer_function(bricks, "T", name, builtin=True)
        np.testing.assert_array_equal(scene.volumes[0].transfer_function.rgb_points, want.rgb_points)
        scene = session.check({"volumes": [{"field": "T", "transfer_function": name, "range": [0, 0.5]}]})
        want = choose_transfer_function(bricks, "T", name, value_range=[0, 0.5], builtin=True)
        np.testing.assert_array_equal(scene.volumes[0].transfer_function.rgb_points, want.rgb_points)
        (tmp_path / name).write_text("not a preset")  # a file that would not even parse
        session.check({"volumes": [{"field": "T", "transfer_function": name}]})


def test_one_change_may_ask_only_so_much(session):
    from exabricks.errors import ExabricksError
    from exabricks.viewer.session import MAX_SAMPLES

    with pytest.raises(ExabricksError, match="at most"):
        session.check({**session.doc, "size": [32768, 32768], "spp": 4096})
    session.check({**session.doc, "size": [32768, MAX_SAMPLES // 32768], "spp": 1})


def test_a_tiled_frame_is_the_whole_frame(session, monkeypatch):
    """A frame drawn tile by tile (so that a newer change can drop it) is the
    frame drawn whole, pixel for pixel."""
    from exabricks.viewer import session as module

    scene = session.check({**session.doc, "size": [100, 60], "spp": 3})
    whole = session.draw("converged", scene)
    for budget in (100 * 3 * 7, 3 * 64):  # bands of rows; square tiles
        monkeypatch.setattr(module, "TILE_SAMPLES", budget)
        tiled = session.draw("converged", scene, cancelled=lambda: False)
        assert tiled.png == whole.png


@pytest.mark.slow
def test_the_largest_frame_is_cancelled_within_a_second(session):
    """A frame of the largest size one change may ask, at the most samples, is
    dropped within a second of the newer change."""
    from exabricks.viewer.session import MAX_SAMPLES, Cancelled

    for size, spp in (((32768, MAX_SAMPLES // 32768), 1), ((1024, 32), 1024)):
        scene = session.check({**session.doc, "size": list(size), "spp": spp})
        newer = threading.Event()
        outcome = []

        def draw(scene=scene, newer=newer, outcome=outcome):
            try:
                session.draw("converged", scene, cancelled=newer.is_set)
                outcome.append("drawn")
            except Cancelled:
                outcome.append(time.perf_counter())

        thread = threading.Thread(target=draw)
        thread.start()
        time.sleep(1.0)
        asked = time.perf_counter()
        newer.set()
        thread.join(30)
        assert not thread.is_alive() and outcome and outcome[0] != "drawn", outcome
        took = outcome[0] - asked
        print(f"{size[0]}x{size[1]} at {spp} spp: cancelled {took * 1e3:.0f} ms after the newer change")
        assert took < 1.0, took
