"""The viewer's web server (aiohttp): the page, its assets and one websocket per page.

Security, as a Jupyter server has it (docs/view.md):

- it listens on the loopback interface unless told otherwise (`--host`);
- every request needs the random token of the printed URL, as `?token=` or as the
  cookie the page gets with it, named after the port (cookies do not tell ports
  apart: two viewers on one host would overwrite each other's, as Jupyter servers
  would without the port in theirs); anything else is 403;
- connections that have shown no token are bounded, the oldest closed for a new
  one, and each has REQUEST_TIMEOUT seconds to send a whole request: idle or slow
  clients never keep the owner's page from being answered (guard.py); each kind
  of refusal is logged once, in one line, never a traceback;
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
                    {"type": "status", "line": "..."}  (what a frame waits for: a kernel
                    build, numba's first compile; every half second while it lasts)
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import logging
import secrets
import socket
from importlib import resources
from pathlib import Path

from ..util.errors import ExabricksError
from .guard import Refusals, Waiting
from .page import Page, regular_output, save_scene

log = logging.getLogger(__name__)

COOKIE = "exabricks_view_token"  # and "_PORT"
WAITING = 64  # connections without the token at most (the fd limit is often 1024)
REQUEST_TIMEOUT = 10.0  # seconds to send a whole request; also a keep-alive connection's idle time
ASSETS = {"/": ("index.html", "text/html"), "/viewer.js": ("viewer.js", "text/javascript"),
          "/viewer.css": ("viewer.css", "text/css")}
MAX_MESSAGE = 1 << 20
# Addresses that mean every interface (and the loopback address its URL names).
WILDCARDS = {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}
SIOCGIFADDR = 0x8915  # Linux's ioctl for an interface's IPv4 address


class Viewer:
    """The web application over one Session."""

    def __init__(self, session, *, host: str = "127.0.0.1", port: int = 0, scene_out=None,
                 token: str | None = None, waiting: int = WAITING,
                 request_timeout: float = REQUEST_TIMEOUT):
        self.session = session
        self.host = host
        self.port = port
        self.scene_out = None if scene_out is None else Path(scene_out)
        if self.scene_out is not None:
            regular_output(self.scene_out, session.inputs)
        self.token = token or secrets.token_urlsafe(24)
        self.lock = asyncio.Lock()  # one frame on the device at a time
        self.runner = None
        self.server = None  # the listening asyncio server
        self.request_timeout = float(request_timeout)
        self.refusals = Refusals()
        self.waiting = Waiting(waiting, self.refusals)
        self.sockets = set()  # the open pages' websockets, closed on stopping
        self.names = set()  # this machine's names and addresses, listening on every interface
        self.warning = None  # one line, listening beyond the loopback interface

    @property
    def cookie(self) -> str:
        """The token cookie's name, this port's own."""
        return f"{COOKIE}_{self.port}"

    # -- checks ---------------------------------------------------------------

    def _allowed_hosts(self) -> set[str]:
        names = {"127.0.0.1", "localhost", "::1", self.host, *self.names}
        return {f"{_url_host(n)}:{self.port}".lower() for n in names}

    def _check(self, request) -> None:
        from aiohttp import web

        if request.host.lower() not in self._allowed_hosts():
            self.refusals.refused("a request naming another host refused (403)")
            raise web.HTTPForbidden(text="unknown host")
        given = request.query.get("token") or _cookie(request, self.cookie) or ""
        if not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), self.token.encode()):
            self.refusals.refused("a request without the token refused (403)")
            raise web.HTTPForbidden(text="a token is needed: open the URL that `exabricks view` printed")
        self.waiting.shown(request.protocol)

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
        response.set_cookie(self.cookie, self.token, httponly=True, samesite="Strict")
        return response

    async def socket(self, request):
        from aiohttp import WSMsgType, web

        self._check(request)
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() not in {f"http://{h}" for h in self._allowed_hosts()}:
            self.refusals.refused("a cross-origin websocket refused (403)")
            raise web.HTTPForbidden(text="cross-origin websocket refused")
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=30)
        await ws.prepare(request)
        page = Page(self, ws)
        self.sockets.add(ws)
        try:
            await page.open()
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

        # aiohttp's keep-alive timeout also runs from a connection's start until
        # its first whole request: the time a client has to send one
        self.runner = web.AppRunner(self.app(), access_log=None, logger=self.refusals,
                                    keepalive_timeout=self.request_timeout)
        await self.runner.setup()
        try:  # aiohttp's server as the protocol factory, as its TCPSite has it, behind the bound
            self.server = await asyncio.get_running_loop().create_server(
                self._connection, self.host, self.port, backlog=128)
        except OSError as e:
            await self.runner.cleanup()
            raise ExabricksError(f"--host {self.host} --port {self.port}: cannot listen there "
                                 f"({e.strerror or e})") from None
        bound = [sock.getsockname()[0] for sock in self.server.sockets]
        self.port = self.server.sockets[0].getsockname()[1]
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

        if self.server is not None:
            self.server.close()
        for ws in list(self.sockets):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b"exabricks view stopped")
        if self.runner is not None:
            await self.runner.cleanup()

    def _connection(self):
        """aiohttp's protocol for a newly accepted connection, once the oldest
        connections without the token beyond the bound are closed."""
        self.waiting.make_room(self.runner.server.connections)
        return self.runner.server()

    def save(self, doc: dict) -> str | None:
        """Write `doc` to --scene-out; its path, or None without one (page.save_scene).
        Called off the event loop (page._in_thread): a write never holds the server up."""
        return save_scene(self.scene_out, doc, self.session.inputs)


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


def _cookie(request, name: str) -> str | None:
    """The token cookie `name`, or None where the Cookie header cannot be parsed (a
    non-ASCII byte, say): then the request simply has no token (403)."""
    try:
        return request.cookies.get(name)
    except (ValueError, KeyError, UnicodeError) as e:
        log.debug("view: unreadable cookie: %s", e)
        return None


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
    # what asyncio would print with a traceback (an accept() out of descriptors,
    # again each second while it lasts): one line a kind
    loop.set_exception_handler(viewer.refusals.loop_error)
    try:
        url = await viewer.start()
        on_url(url)
        await stop.wait()
    finally:
        for s in interrupt.SIGNALS:
            loop.remove_signal_handler(s)
        await viewer.stop()
    return received[0] if received else signal.SIGINT
