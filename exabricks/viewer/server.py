"""The viewer's web server (aiohttp): the page, its assets and one websocket per page.

Security, as a Jupyter server has it (docs/view.md):

- it listens on the loopback interface unless told otherwise (`--host`);
- every request needs the random token of the printed URL, as `?token=` or as the
  cookie the page gets with it; anything else is 403;
- the Host header must name this server (no DNS rebinding): the loopback names,
  `--host`, and, listening on every interface (`--host 0.0.0.0` or `::`), this
  machine's names and addresses (_own_names); a websocket's Origin must be this
  server's own page; listening beyond the loopback interface, it warns once
  (Viewer.warning) that the token alone guards it;
- nothing a page sends names a file: the page reads its assets by fixed names, and a
  scene from the page may hold no file reference but the mesh files the viewer was
  started with (session._no_files);
- a malformed message gets an error reply on its websocket; the server goes on.

Messages (JSON text; frames are PNG bytes, each after a "frame" message):

    page -> server  {"type": "scene", "scene": {...}, "moving": false, "version": N}
                    {"type": "save"}          (writes --scene-out, sends the document back)
    server -> page  {"type": "init", ...}     (session.Session.info)
                    {"type": "frame", "stage", "width", "height", "spp", "ms",
                     "samples_per_second", "device", "version", "size", "layer"}, then the PNG
                    (version: the page's number of the scene it shows, 0 at the start;
                    size: the scene's whole size, which the page shows every stage at;
                    layer: the first volume layer's knots as the page shows them,
                    session.Session.layer)
                    {"type": "saved", "scene": {...}, "path": ...}
                    {"type": "error", "message": "..."}
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import logging
import os
import secrets
import socket
import stat
import threading
from importlib import resources
from pathlib import Path

from ..util.errors import ExabricksError, one_line
from .session import Cancelled

log = logging.getLogger(__name__)

COOKIE = "exabricks_view_token"
ASSETS = {"/": ("index.html", "text/html"), "/viewer.js": ("viewer.js", "text/javascript"),
          "/viewer.css": ("viewer.css", "text/css")}
MAX_MESSAGE = 1 << 20
# Addresses that mean every interface (and the loopback address its URL names).
WILDCARDS = {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}
SIOCGIFADDR = 0x8915  # Linux's ioctl for an interface's IPv4 address


class Viewer:
    """The web application over one Session."""

    def __init__(self, session, *, host: str = "127.0.0.1", port: int = 0, scene_out=None,
                 token: str | None = None):
        self.session = session
        self.host = host
        self.port = port
        self.scene_out = None if scene_out is None else Path(scene_out)
        if self.scene_out is not None:
            _regular_output(self.scene_out)
        self.token = token or secrets.token_urlsafe(24)
        self.lock = asyncio.Lock()  # one frame on the device at a time
        self.runner = None
        self.sockets = set()  # the open pages' websockets, closed on stopping
        self.names = set()  # this machine's names and addresses, listening on every interface
        self.warning = None  # one line, listening beyond the loopback interface

    # -- checks ---------------------------------------------------------------

    def _allowed_hosts(self) -> set[str]:
        names = {"127.0.0.1", "localhost", "::1", self.host, *self.names}
        return {f"{_url_host(n)}:{self.port}".lower() for n in names}

    def _check(self, request) -> None:
        from aiohttp import web

        if request.host.lower() not in self._allowed_hosts():
            raise web.HTTPForbidden(text="unknown host")
        given = request.query.get("token") or _cookie(request) or ""
        if not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), self.token.encode()):
            raise web.HTTPForbidden(text="a token is needed: open the URL that `exabricks view` printed")

    # -- handlers -------------------------------------------------------------

    async def asset(self, request):
        from aiohttp import web

        self._check(request)
        name, kind = ASSETS[request.path]
        body = resources.files(__package__).joinpath("static", name).read_bytes()
        response = web.Response(body=body, content_type=kind,
                                headers={"Cache-Control": "no-store",
                                         "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; "
                                         "connect-src 'self'; style-src 'self'",
                                         "X-Content-Type-Options": "nosniff"})
        response.set_cookie(COOKIE, self.token, httponly=True, samesite="Strict")
        return response

    async def socket(self, request):
        from aiohttp import WSMsgType, web

        self._check(request)
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() not in {f"http://{h}" for h in self._allowed_hosts()}:
            raise web.HTTPForbidden(text="cross-origin websocket refused")
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=30)
        await ws.prepare(request)
        page = _Page(self, ws)
        self.sockets.add(ws)
        try:
            await ws.send_str(json.dumps(self.session.info()))
            page.want(self.session.doc, False)
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    await page.receive(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    await page.error("binary messages are not understood")
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            self.sockets.discard(ws)
            page.close()
        return ws

    def app(self):
        from aiohttp import web

        app = web.Application(client_max_size=MAX_MESSAGE)
        for path in ASSETS:
            app.router.add_get(path, self.asset)
        app.router.add_get("/ws", self.socket)
        return app

    async def start(self) -> str:
        """Listen; the URL with the token."""
        from aiohttp import web

        self.runner = web.AppRunner(self.app(), access_log=None)
        await self.runner.setup()
        site = web.TCPSite(self.runner, self.host, self.port)
        try:
            await site.start()
        except OSError as e:
            await self.runner.cleanup()
            raise ExabricksError(f"--host {self.host} --port {self.port}: cannot listen there "
                                 f"({e.strerror or e})") from None
        bound = [sock.getsockname()[0] for sock in site._server.sockets]
        self.port = site._server.sockets[0].getsockname()[1]
        url = f"http://{_url_host(WILDCARDS.get(self.host, self.host))}:{self.port}/?token={self.token}"
        if self.host in WILDCARDS:
            self.names = _own_names()
        if not all(_loopback(a) for a in bound):
            elsewhere = url
            if self.host in WILDCARDS:
                # an address of this machine another one can reach (of the family
                # listened on first, link-local last), else its name
                outside = sorted((a for a in self.names if _address(a) is not None and not _loopback(a)),
                                 key=lambda a: ((":" in a) != (":" in self.host),
                                                _address(a).is_link_local, a))
                name = outside[0] if outside else socket.getfqdn()
                elsewhere = f"http://{_url_host(name)}:{self.port}/?token={self.token}"
            self.warning = (f"--host {self.host}: the viewer is reachable from the network, guarded "
                            f"only by its token; from another machine open {elsewhere}")
        return url

    async def stop(self) -> None:
        """Close the open pages' websockets (else the server waits out aiohttp's
        shutdown timeout, tens of seconds, for pages left open), then the server."""
        from aiohttp import WSCloseCode

        for ws in list(self.sockets):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b"exabricks view stopped")
        if self.runner is not None:
            await self.runner.cleanup()

    def save(self, doc: dict) -> str | None:
        """Write `doc` to --scene-out (atomically); its path, or None without one.
        Called off the event loop (_in_thread): a write never holds the server up."""
        from ..util.output import write_json

        if self.scene_out is None:
            return None
        _regular_output(self.scene_out)
        write_json(self.scene_out, doc)
        return str(self.scene_out)


class _Page:
    """One page's websocket: the version it wants drawn and the drawing of it."""

    def __init__(self, viewer: Viewer, ws):
        self.viewer, self.ws = viewer, ws
        self.version = 0
        self.doc = self.good = viewer.session.doc  # wanted; last that passed its checks
        self.moving = False
        self.tag = 0  # the page's number of the wanted scene
        self.task = None
        self.saves = set()  # saves under way (each a task)

    def want(self, doc: dict, moving: bool, tag=0) -> None:
        self.version += 1
        self.doc, self.moving = doc, moving
        self.tag = tag if isinstance(tag, int) and not isinstance(tag, bool) else 0
        if self.task is None or self.task.done():
            self.task = asyncio.ensure_future(self._draw())

    async def _draw(self) -> None:
        session = self.viewer.session
        loop = asyncio.get_running_loop()
        while True:
            version, doc, moving, tag = self.version, self.doc, self.moving, self.tag
            try:
                scene = await loop.run_in_executor(None, session.check, doc)
                self.good = doc
                layer = session.layer(scene)
                size = [scene.settings.width, scene.settings.height]
                def cancelled(version=version):  # a newer change, or the page went away
                    return version != self.version or self.ws.closed

                for stage, staged in session.stages(scene, moving):
                    if version != self.version:
                        break
                    async with self.viewer.lock:
                        try:
                            frame = await _finished(loop.run_in_executor(None, session.draw, stage, staged,
                                                                         cancelled))
                        except Cancelled:
                            break
                    if version != self.version or self.ws.closed:
                        break
                    await self.ws.send_str(json.dumps({
                        "type": "frame", "stage": frame.stage, "width": frame.width,
                        "height": frame.height, "spp": frame.spp, "ms": round(frame.ms, 1),
                        "samples_per_second": frame.samples_per_second, "device": frame.device,
                        "version": tag, "size": size, "layer": layer}))
                    await self.ws.send_bytes(frame.png)
                else:
                    if version == self.version:
                        self.viewer.session.doc = doc  # the last complete view: what save writes
            except ExabricksError as e:
                if version == self.version:
                    self.doc = self.good  # what "save" writes stays a scene that draws
                await self.error(str(e))
            except (ConnectionError, RuntimeError) as e:  # the page went away mid-send
                log.debug("view: %s", e)
                return
            if version == self.version or self.ws.closed:
                return

    async def receive(self, text: str) -> None:
        try:
            message = json.loads(text)
        except (ValueError, RecursionError):
            await self.error("not a JSON message")
            return
        if not isinstance(message, dict) or not isinstance(message.get("type"), str):
            await self.error('a message is an object with a "type"')
            return
        kind = message["type"]
        if kind == "scene":
            doc = message.get("scene")
            if not isinstance(doc, dict):
                await self.error('"scene" needs a scene object')
                return
            self.want(doc, bool(message.get("moving", False)), message.get("version", 0))
        elif kind == "save":  # a task of its own: the page's messages go on meanwhile
            self.saves.add(asyncio.ensure_future(self._save(self.good)))
        else:
            await self.error(f"unknown message type {one_line(kind)[:40]!r}")

    async def _save(self, doc: dict) -> None:
        try:
            path = await _in_thread(self.viewer.save, doc)
            if not self.ws.closed:
                await self.ws.send_str(json.dumps({"type": "saved", "scene": doc, "path": path}))
        except ExabricksError as e:
            await self.error(str(e))
        except (ConnectionError, RuntimeError) as e:  # the page went away
            log.debug("view: %s", e)
        finally:
            self.saves.discard(asyncio.current_task())

    async def error(self, message: str) -> None:
        if not self.ws.closed:
            await self.ws.send_str(json.dumps({"type": "error", "message": one_line(message)}))

    def close(self) -> None:
        self.version += 1
        if self.task is not None:
            self.task.cancel()
        for save in list(self.saves):
            save.cancel()


def _url_host(name: str) -> str:
    """`name` as a URL's (and a Host header's) host: an IPv6 address in brackets."""
    return f"[{name}]" if ":" in name else name


def _address(name: str):
    """The IP address `name` is, or None (a host name)."""
    try:
        return ipaddress.ip_address(name.split("%")[0])
    except ValueError:
        return None


def _loopback(name: str) -> bool:
    address = _address(name)
    return name == "localhost" if address is None else address.is_loopback


def _own_names() -> set[str]:
    """This machine's names and addresses, any of which a page on another machine
    may name in its Host header when the server listens on every interface: the
    host name and its FQDN, what they resolve to, and each interface's addresses
    (on Linux: the first IPv4 address of each by SIOCGIFADDR, every IPv6 one from
    /proc/net/if_inet6). Never an error: what cannot be found is left out."""
    names = {socket.gethostname(), socket.getfqdn()} - {""}
    for name in list(names):
        try:
            names |= {info[4][0].split("%")[0] for info in socket.getaddrinfo(name, None)}
        except (OSError, UnicodeError):
            pass
    try:
        import fcntl
        import struct

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            for _, interface in socket.if_nameindex():
                try:
                    request = struct.pack("256s", interface.encode()[:15])
                    names.add(socket.inet_ntoa(fcntl.ioctl(probe.fileno(), SIOCGIFADDR, request)[20:24]))
                except OSError:  # no IPv4 address there
                    pass
    except (ImportError, OSError, AttributeError):  # not Linux
        pass
    try:
        with open("/proc/net/if_inet6") as f:
            for line in f:
                names.add(ipaddress.IPv6Address(bytes.fromhex(line.split()[0])).compressed)
    except (OSError, ValueError, IndexError):
        pass
    return names


def _cookie(request) -> str | None:
    """The token cookie, or None where the Cookie header cannot be parsed (a
    non-ASCII byte, say): then the request simply has no token (403)."""
    try:
        return request.cookies.get(COOKIE)
    except (ValueError, KeyError, UnicodeError) as e:
        log.debug("view: unreadable cookie: %s", e)
        return None


def _regular_output(path: Path) -> None:
    """Refuse --scene-out naming something other than a regular file (or nothing yet):
    a FIFO, a device or a descriptor would hold a save up, so the viewer never
    writes into one (exabricks.util.output writes into them for other commands)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise ExabricksError(f"--scene-out {path}: cannot look at it ({e.strerror or e})") from None
    if stat.S_ISREG(mode):
        return
    kind = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    raise ExabricksError(f"--scene-out {path}: is {kind}; the viewer saves scenes to a regular file only")


def _in_thread(function, *args):
    """`function(*args)` in a daemon thread of its own, awaited: a write that blocks
    (a FIFO swapped in after the check) holds neither the loop nor the stop."""
    loop = asyncio.get_running_loop()
    future = loop.create_future()

    def done(result, error):
        if not future.done():
            if error is None:
                future.set_result(result)
            else:
                future.set_exception(error)

    def run():
        try:
            result, error = function(*args), None
        except BaseException as e:  # handed to the awaiting coroutine
            result, error = None, e
        try:
            loop.call_soon_threadsafe(done, result, error)
        except RuntimeError:  # the loop has closed meanwhile
            pass

    threading.Thread(target=run, name="exabricks-view-save", daemon=True).start()
    return future


async def _finished(future):
    """The result of a frame drawn in a thread. When the page goes away meanwhile,
    the drawing is waited for before the cancel goes on, so that the lock on the
    device is not released while a thread still draws."""
    try:
        return await asyncio.shield(future)
    except asyncio.CancelledError:
        await asyncio.wait([future])
        raise


async def serve(viewer: Viewer, on_url) -> int | None:
    """Run until SIGINT, SIGTERM or SIGHUP, calling `on_url(url)` once listening; the
    signal's number. The signals are the loop's own (they wake it up; they never
    interrupt a callback, whose exception asyncio would swallow), and the server
    stops cleanly before returning."""
    import signal

    from ..util import interrupt

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    received = []

    def on_signal(signum):
        received.append(signum)
        stop.set()

    for s in interrupt.SIGNALS:
        loop.add_signal_handler(s, on_signal, s)
    try:
        url = await viewer.start()
        on_url(url)
        await stop.wait()
    finally:
        for s in interrupt.SIGNALS:
            loop.remove_signal_handler(s)
        await viewer.stop()
    return received[0] if received else signal.SIGINT
