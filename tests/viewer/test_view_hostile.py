"""`exabricks view` against hostile inputs (issue 49, the viewer's part): a frame
in progress is cancelled by a newer change within a second, under a memory
budget too, and one change may ask only so much; a FIFO or a device as
--scene-out is refused and a save never holds the server's loop; a built-in
preset name never makes the server read a file; a non-ASCII cookie gets 403, not
500; listening on every interface, the server answers this machine's own
addresses (and no other name) and warns that the token alone guards it."""

from __future__ import annotations

import asyncio
import io
import ipaddress
import json
import logging
import os
import socket
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from helpers import GERRIS

aiohttp = pytest.importorskip("aiohttp")
# the lighting of a fake scene: the headlight (no key light for the page to take)
UNLIT = SimpleNamespace(integrator="headlight", light=None)


class StubSession:
    """What the server needs of a Session, without a device: frames are never drawn."""

    doc = {"volumes": []}
    inputs = ()

    def info(self):
        return {"type": "init", "scene": self.doc}

    def check(self, doc):
        return SimpleNamespace(settings=SimpleNamespace(width=8, height=8), lighting=UNLIT)

    def layer(self, scene):
        return None

    def stages(self, scene, moving=False):
        return []


async def serving_async(viewer, body):
    """`await body(base_url)` with `viewer` listening; the server stops after."""
    url = await viewer.start()
    try:
        return await body(url.split("/?token=")[0])
    finally:
        await asyncio.wait_for(viewer.stop(), 5)


def serving(viewer, body):
    """Run `await body(base_url)` with `viewer` listening; the server stops after."""
    return asyncio.run(serving_async(viewer, body))


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
    from exabricks.viewer.server import Viewer

    viewer = Viewer(StubSession())

    async def body(base):
        return [await raw_get(base, cookie) for cookie in (
            "Cookie: exabricks_view_token=é\r\n".encode(),
            b"Cookie: exabricks_view_token=\xff\xc3\x28\r\n",
            b"Cookie: \xff\xfe=\xc3\x28\r\n",
            f"Cookie: a=\u00e9; {viewer.cookie}={viewer.token}\r\n".encode(),
            f"Cookie: {viewer.cookie}={viewer.token}\r\n".encode())]

    with caplog.at_level(logging.DEBUG, logger="aiohttp"):
        lines = serving(viewer, body)
    assert [line.split()[1] for line in lines[:3]] == [b"403", b"403", b"403"], lines
    assert lines[3].split()[1] in (b"200", b"403") and lines[4].split()[1] == b"200", lines
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text


def test_two_viewers_cookies_do_not_collide():
    """Cookies do not tell ports apart: a second viewer's page on the same host
    leaves the first one's cookie alone, and each server takes its own."""
    from exabricks.viewer.server import Viewer

    first, second = Viewer(StubSession()), Viewer(StubSession())

    async def body(base):
        async def other(base2):
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as s:
                for b, v in ((base, first), (base2, second)):  # each page opened with its URL
                    async with s.get(f"{b}/?token={v.token}") as r:
                        assert r.status == 200
                statuses = []
                for b in (base, base2):  # then by the cookie alone, as the page's assets are
                    async with s.get(f"{b}/viewer.js") as r:
                        statuses.append(r.status)
                return statuses, {c.key for c in s.cookie_jar}
        return await serving_async(second, other)

    statuses, names = serving(first, body)
    assert statuses == [200, 200] and names == {first.cookie, second.cookie}, (statuses, names)
    assert first.cookie != second.cookie


MALFORMED = {
    "a header line over 8 KB": b"GET / HTTP/1.1\r\nHost: h\r\nX: " + b"a" * 9000 + b"\r\n\r\n",
    "a request line over 8 KB": b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: h\r\n\r\n",
    "a bad HTTP version": b"GET / HTTP/9.9x\r\nHost: h\r\n\r\n",
    "a bad chunked body": b"POST / HTTP/1.1\r\nHost: h\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n",
    "a NUL in a header": b"GET / HTTP/1.1\r\nHost: h\r\nX: a\x00b\r\n\r\n",
    "200 headers": b"GET / HTTP/1.1\r\nHost: h\r\n" + b"".join(b"X%d: y\r\n" % i for i in range(200)) + b"\r\n",
}


async def raw_status(base: str, data: bytes) -> bytes:
    """The status line the server answers the raw bytes `data` with."""
    host, port = base.removeprefix("http://").rsplit(":", 1)
    reader, writer = await asyncio.open_connection(host, int(port))
    writer.write(data)
    await writer.drain()
    line = await asyncio.wait_for(reader.readline(), 10)
    writer.close()
    return line


def test_malformed_requests_get_400_and_one_line_a_kind(caplog, capfd):
    """Each malformed request (sent twice) is a 400, logged at most once per kind,
    in one line and without a traceback."""
    from exabricks.viewer.server import Viewer

    viewer = Viewer(StubSession())

    async def body(base):
        return {name: [await raw_status(base, data) for _ in range(2)] for name, data in MALFORMED.items()}

    with caplog.at_level(logging.DEBUG):
        lines = serving(viewer, body)
    assert all(line.split()[1] == b"400" for got in lines.values() for line in got), lines
    assert not [r for r in caplog.records if r.exc_info], caplog.text
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert 1 <= len(warned) <= len(MALFORMED) and len(set(warned)) == len(warned), warned
    assert all("\n" not in w and "malformed request" in w for w in warned), warned
    assert "Traceback" not in caplog.text + capfd.readouterr().err


def test_idle_clients_never_keep_the_owner_waiting(caplog, capfd):
    """200 connections without the token, idle or sending a request slowly: the
    server keeps at most its bound of them (the oldest closed) and closes a slow
    one after its request timeout; the owner's page is answered at once, and the
    refusals are one line each kind, no traceback."""
    from exabricks.viewer.server import Viewer

    viewer = Viewer(StubSession(), waiting=16, request_timeout=0.5)

    async def body(base):
        host, port = base.removeprefix("http://").rsplit(":", 1)
        idle = [await asyncio.open_connection(host, int(port)) for _ in range(200)]
        await asyncio.sleep(0.1)
        started = time.monotonic()
        async with aiohttp.ClientSession() as s:
            async with s.get(f"{base}/?token={viewer.token}") as r:
                owner = r.status, time.monotonic() - started

        async def closed(reader):
            try:
                return await asyncio.wait_for(reader.read(), 0.05) == b""
            except (asyncio.TimeoutError, ConnectionError):
                return False

        still_open = sum([not await closed(reader) for reader, _ in idle])
        slow = []
        for _ in range(4):  # a request's first bytes, and never the rest
            reader, writer = await asyncio.open_connection(host, int(port))
            writer.write(b"GET / HTTP/1.1\r\nHost: ")
            slow.append((reader, writer))
        ended = await asyncio.wait_for(asyncio.gather(*(reader.read() for reader, _ in slow)), 5)
        for _, writer in idle + slow:
            writer.close()
        return owner, still_open, ended

    with caplog.at_level(logging.DEBUG):
        (status, seconds), still_open, ended = serving(viewer, body)
    assert status == 200 and seconds < 2, (status, seconds)
    assert still_open <= 16, still_open
    assert ended == [b""] * 4
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len([w for w in warned if "too many connections" in w]) == 1, warned
    assert not [r for r in caplog.records if r.exc_info]
    assert "Traceback" not in caplog.text + capfd.readouterr().err


def test_an_accept_out_of_descriptors_is_one_line():
    """asyncio reports an accept() that fails (too many open files) through the
    loop's exception handler, with a traceback, again each second while it lasts:
    the viewer's handler logs it once, in one line."""
    from exabricks.viewer.guard import Refusals

    refusals, records = Refusals(), []
    handler = logging.Handler()
    handler.emit = records.append
    logger = logging.getLogger("exabricks.viewer.guard")
    logger.addHandler(handler)
    try:
        for _ in range(3):
            try:
                raise OSError(24, "Too many open files")
            except OSError as e:
                refusals.loop_error(None, {"message": "socket.accept() out of system resource",
                                           "exception": e})
    finally:
        logger.removeHandler(handler)
    warned = [r for r in records if r.levelno >= logging.WARNING]
    assert len(warned) == 1 and not warned[0].exc_info and "\n" not in warned[0].getMessage()
    assert "Too many open files" in warned[0].getMessage()


# `exabricks view`'s serving, with a session whose frame draws until it is
# cancelled (between tiles, as a real one is): what it prints on stopping
DRAWING = """
import asyncio, logging, sys, time
from types import SimpleNamespace
from exabricks.viewer.server import Viewer, serve
from exabricks.viewer.session import Cancelled

class Drawing:
    doc = {}
    def info(self): return {"type": "init", "scene": self.doc}
    def check(self, doc): return SimpleNamespace(settings=SimpleNamespace(width=8, height=8),
                                                 lighting=SimpleNamespace(integrator="headlight", light=None))
    def layer(self, scene): return None
    def stages(self, scene, moving=False): return [("converged", scene)]
    def draw(self, stage, scene, cancelled):
        print("drawing", file=sys.stderr, flush=True)
        while not cancelled():
            time.sleep(0.01)
        raise Cancelled

logging.basicConfig(level=logging.WARNING, format="%(message)s", stream=sys.stderr)
viewer = Viewer(Drawing())
asyncio.run(serve(viewer, lambda url: print(url, file=sys.stderr, flush=True)))
print("stopped", file=sys.stderr)
"""


@pytest.mark.parametrize("how", ["SIGTERM mid-frame", "page gone mid-frame, then SIGINT"])
def test_stopping_mid_frame_prints_nothing_more(how):
    """Stopped while a frame draws (or after its page went away mid-frame), the
    viewer prints no "Future exception was never retrieved" and no traceback."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    import exabricks

    env = {**os.environ, "PYTHONPATH": str(Path(exabricks.__file__).parents[1])}
    proc = subprocess.Popen([sys.executable, "-c", DRAWING], stderr=subprocess.PIPE, text=True, env=env)
    try:
        url = proc.stderr.readline().strip()
        base, token = url.split("/?token=")

        async def page():
            async with aiohttp.ClientSession() as s:
                async with s.ws_connect(f"{base}/ws?token={token}", headers={"Origin": base}) as ws:
                    await asyncio.wait_for(ws.receive(), 10)  # init
                    assert proc.stderr.readline() == "drawing\n"
                    if how.startswith("SIGTERM"):
                        proc.send_signal(signal.SIGTERM)
                        await asyncio.wait_for(ws.receive(), 10)  # closed by the server
            await asyncio.sleep(0.2)
            if not how.startswith("SIGTERM"):
                proc.send_signal(signal.SIGINT)

        asyncio.run(page())
        rest = proc.communicate(timeout=20)[1]
    finally:
        proc.kill()
    assert rest == "stopped\n", rest


def test_a_fifo_or_a_device_as_scene_out_is_refused(tmp_path):
    from exabricks.util.errors import ExabricksError
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
    from exabricks.viewer import page, server

    out = tmp_path / "scene.json"
    viewer = server.Viewer(StubSession(), scene_out=out)
    os.mkfifo(out)

    async def refused(base):
        return await asyncio.wait_for(ws_save(base, viewer.token), 10)

    reply = serving(viewer, refused)
    assert reply["type"] == "error" and "is a FIFO" in reply["message"], reply

    for module in (page, server):  # the race: the FIFO comes later
        monkeypatch.setattr(module, "regular_output", lambda path, inputs=(): None)
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


def own_address() -> str:
    """An address of this machine that is not loopback (the one its route out
    leaves from; connecting a UDP socket sends nothing), else the test is skipped."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("10.255.255.255", 1))
            address = probe.getsockname()[0]
        except OSError:
            address = None
    if address is None or ipaddress.ip_address(address).is_loopback:
        pytest.skip("this machine has no address but loopback")
    return address


def test_every_interface_answers_this_machines_addresses_and_warns():
    """`--host 0.0.0.0`: a page opened at this machine's own address is served and
    its websocket's Origin accepted; any other name still gets 403 (DNS rebinding),
    and so does a request without the token; the server warns, once started, that it
    is reachable from the network, with a URL that works. On loopback, no warning."""
    from exabricks.viewer.server import Viewer

    address = own_address()
    viewer = Viewer(StubSession(), host="0.0.0.0")

    async def body(base):
        port = base.rsplit(":", 1)[1]
        mine = f"http://{address}:{port}"
        async with aiohttp.ClientSession() as s:
            async def get(url, **headers):
                async with s.get(url, headers=headers) as r:
                    return r.status

            statuses = [await get(f"{mine}/?token={viewer.token}"),
                        await get(f"{mine}/viewer.js?token={viewer.token}"),
                        await get(f"{base}/?token={viewer.token}"),
                        await get(f"{mine}/?token={viewer.token}", Host=f"evil.example:{port}"),
                        await get(f"{mine}/?token={viewer.token}", Host=f"{address}.nip.io:{port}"),
                        await get(f"{mine}/")]
            if viewer.warning:  # the URL it names for another machine works
                statuses.append(await get(viewer.warning.split()[-1]))
            async with s.ws_connect(f"{mine}/ws?token={viewer.token}", headers={"Origin": mine}) as ws:
                init = json.loads((await asyncio.wait_for(ws.receive(), 10)).data)
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await s.ws_connect(f"{mine}/ws?token={viewer.token}", headers={"Origin": "http://evil.example"})
        return statuses, init, refused.value.status

    statuses, init, refused = serving(viewer, body)
    assert statuses == [200, 200, 200, 403, 403, 403, 200], statuses
    assert init["type"] == "init" and refused == 403
    assert "reachable from the network" in viewer.warning and "only by its token" in viewer.warning
    assert f"token={viewer.token}" in viewer.warning and "0.0.0.0" not in viewer.warning.split()[-1]

    loopback = Viewer(StubSession())
    serving(loopback, lambda base: asyncio.sleep(0))
    assert loopback.warning is None


# -- a real Session (the device) ---------------------------------------------------

BUDGET = 4 << 20  # the Gerris plume in 4 domains at 100x60


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def session(cache):
    import exabricks as eb
    from exabricks.viewer.session import Session

    return Session(eb.open(GERRIS, cache=cache), options={"field": "T", "size": (64, 48)})


@pytest.fixture(scope="module")
def budgeted(cache):
    """A viewer's session under `--memory-budget` (frames streamed domain by domain)."""
    import exabricks as eb
    from exabricks.viewer.session import Session

    return Session(eb.open(GERRIS, cache=cache), options={"field": "T", "size": (64, 48)}, budget=BUDGET)


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
    from exabricks.util.errors import ExabricksError
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


def test_a_tiled_denoised_frame_is_renders(session, monkeypatch):
    """`--integrator path --spp 4 --denoise`: the frame drawn in tiles is denoised
    once, whole, as `render` does (tile by tile, the denoiser left seams of up to
    76/255): the frame drawn whole, within float rounding."""
    pytest.importorskip("pyoidn", reason="--denoise needs pyoidn (the denoise extra)")
    from exabricks.viewer import session as module

    lighting = {**session.doc["lighting"], "integrator": "path"}
    scene = session.check({**session.doc, "lighting": lighting, "size": [100, 60], "spp": 4, "denoise": True})
    whole = session.draw("converged", scene)
    monkeypatch.setattr(module, "TILE_SAMPLES", 4 * 32)  # square tiles of 8 pixels
    tiled = session.draw("converged", scene, cancelled=lambda: False)
    a, b = (np.asarray(Image.open(io.BytesIO(f.png)), np.int16) for f in (whole, tiled))
    assert int(np.abs(a - b).max()) <= 1, int(np.abs(a - b).max())


@pytest.mark.slow
def test_a_budgeted_frame_in_tiles_is_the_whole_frame(budgeted, monkeypatch):
    """Under a memory budget, the frame drawn in tiles of columns (so that a newer
    change can drop it) is the frame `render --memory-budget` draws, pixel for pixel."""
    from exabricks.viewer import session as module

    scene = budgeted.check({**budgeted.doc, "size": [100, 60], "spp": 3})
    whole = budgeted.draw("converged", scene)
    assert budgeted._domains[1].n_domains > 1
    monkeypatch.setattr(module, "TILE_SAMPLES", 60 * 16)  # 16 columns a tile
    tiled = budgeted.draw("converged", scene, cancelled=lambda: False)
    assert tiled.png == whole.png


def test_a_budgeted_frame_is_dropped_by_a_newer_change(budgeted, monkeypatch):
    """Under a memory budget, a newer change drops the frame at the next tile,
    domain or sample: nothing more is drawn of it (sample by sample at 1 spp;
    samples drawn together with each domain read at 4)."""
    from exabricks.engine.renderer import Renderer
    from exabricks.viewer import session as module
    from exabricks.viewer.session import Cancelled

    drawn, newer = [], threading.Event()
    integrate = Renderer.integrate  # every tile of every domain is integrated

    def drawing(self, *args, **kwargs):  # a newer change comes while the first tile draws
        drawn.append(kwargs.get("window"))
        newer.set()
        return integrate(self, *args, **kwargs)

    monkeypatch.setattr(Renderer, "integrate", drawing)
    monkeypatch.setattr(module, "TILE_SAMPLES", 60 * 16)  # 16 columns a tile
    for spp in (1, 4):
        scene = budgeted.check({**budgeted.doc, "size": [100, 60], "spp": spp})
        drawn.clear()
        newer.clear()
        with pytest.raises(Cancelled):
            budgeted.draw("converged", scene, cancelled=newer.is_set)
        assert len(drawn) == 1 and budgeted._domains[1].n_domains > 1, (spp, len(drawn))


def cancelled_after(session, size, spp, monkeypatch) -> tuple[float, int, int]:
    """A frame of `size` at `spp`, drawn for a second, then dropped by a newer
    change: the seconds from the change to the drop (a figure to print), the
    device launches begun after a look that saw the change, and the most samples (pixels x
    samples per pixel) any launch drew between two looks for a change."""
    from exabricks.engine.renderer import Renderer
    from exabricks.viewer.session import Cancelled

    scene = session.check({**session.doc, "size": list(size), "spp": spp})
    newer = threading.Event()
    outcome, launches, looks = [], [], [False]
    integrate = Renderer.integrate

    def look():
        looks.append(newer.is_set())
        return looks[-1]

    def spy(self, scene, *, window=None, sample=None, **options):
        s = scene.settings
        pixels = int(s.width) * int(s.height) if window is None else window[2] * window[3]
        launches.append((looks[-1], pixels * (1 if sample is not None else int(s.spp))))
        return integrate(self, scene, window=window, sample=sample, **options)

    monkeypatch.setattr(Renderer, "integrate", spy)

    def draw():
        try:
            session.draw("converged", scene, cancelled=look)
            outcome.append("drawn")
        except Cancelled:
            outcome.append(time.perf_counter())

    thread = threading.Thread(target=draw)
    thread.start()
    time.sleep(1.0)
    asked = time.perf_counter()
    newer.set()
    thread.join(60)
    monkeypatch.undo()
    assert not thread.is_alive() and outcome and outcome[0] != "drawn", outcome
    assert launches, "nothing was drawn before the change"
    return outcome[0] - asked, sum(after for after, _ in launches), max(n for _, n in launches)


# A frame is dropped at the first look after a newer change, and the looks are at
# most TILE_SAMPLES samples apart: the work a change waits for is one launch's
# (about 0.1-0.3 s on PoCL, 2 cores), whatever the frame's size. Wall-clock time is
# printed, not asserted: on a loaded machine one launch can take longer.
FRAMES = (((32768, 1 << 25 >> 15), 1), ((1024, 32), 1024))


@pytest.mark.slow
def test_the_largest_budgeted_frame_is_dropped_at_the_next_look(cache, monkeypatch):
    """Under a memory budget too: the largest frames one change may ask (under a
    budget that holds their images) are dropped before another launch once a newer
    change comes, and no launch draws more than TILE_SAMPLES samples."""
    import exabricks as eb
    from exabricks.viewer.session import MAX_SAMPLES, TILE_SAMPLES, Session

    assert FRAMES[0][0][0] * FRAMES[0][0][1] == MAX_SAMPLES
    dataset = eb.open(GERRIS, cache=cache)
    for budget, (size, spp) in zip((3 << 30, 8 << 20), FRAMES):
        session = Session(dataset, options={"field": "T", "size": (64, 48)}, budget=budget)
        took, after, largest = cancelled_after(session, size, spp, monkeypatch)
        print(f"--memory-budget {session.budget >> 20}M, {size[0]}x{size[1]} at {spp} spp: "
              f"cancelled {took * 1e3:.0f} ms after the newer change; launches of at most {largest} samples")
        assert after == 0 and largest <= TILE_SAMPLES, (after, largest)


@pytest.mark.slow
def test_the_largest_frame_is_dropped_at_the_next_look(session, monkeypatch):
    """A frame of the largest size one change may ask, at the most samples, is
    dropped before another launch once a newer change comes, and no launch draws
    more than TILE_SAMPLES samples."""
    from exabricks.viewer.session import TILE_SAMPLES

    for size, spp in FRAMES:
        took, after, largest = cancelled_after(session, size, spp, monkeypatch)
        print(f"{size[0]}x{size[1]} at {spp} spp: cancelled {took * 1e3:.0f} ms after the newer change; "
              f"launches of at most {largest} samples")
        assert after == 0 and largest <= TILE_SAMPLES, (after, largest)
