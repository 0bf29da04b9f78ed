"""The viewer's web server against clients without its token: connections that
have shown no token yet are bounded (the oldest closed to make room, so that the
owner's page is still answered while many idle or slow clients hold connections
open), and each kind of refusal (a malformed request, a connection closed, the
process out of descriptors) is logged once, as one line, never as a traceback
(DESIGN.md, "Errors"): a flood of them must neither fill the terminal nor hide
the URL.
"""

from __future__ import annotations

import logging
import sys

from ..util.errors import one_line

log = logging.getLogger(__name__)

KINDS = 64  # kinds of refusal remembered (and logged) at most: a bounded set
DETAIL = 100  # characters of a refusal's detail in its log line, at most


class Refusals:
    """Each kind of refusal logged once at warning level; the rest at debug level.
    Also aiohttp's server logger (its `logger`: a malformed request is a 400
    logged through `exception`, which would print a traceback) and, through
    `loop_error`, the event loop's exception handler (asyncio prints a traceback
    for each accept() that fails with too many open files)."""

    def __init__(self):
        self.seen: set[str] = set()

    def refused(self, kind: str, detail: str = "") -> None:
        detail = one_line(detail)[:DETAIL]
        line = f"view: {kind}" + (f" ({detail})" if detail else "")
        if kind in self.seen or len(self.seen) >= KINDS:
            log.debug("%s", line)
            return
        self.seen.add(kind)
        log.warning("%s; later ones of this kind are not logged", line)

    # -- aiohttp's server logger ----------------------------------------------

    def exception(self, msg, *args, exc_info=None, **_):
        error = exc_info if isinstance(exc_info, BaseException) else sys.exc_info()[1]
        if error is None:
            self.refused("a request failed", str(msg) % args if args else str(msg))
            return
        status = getattr(error, "code", None)
        # aiohttp's message: its words before the first colon name the kind
        # ("Too many headers received", "Bad status line"), the rest quotes the request
        name, _, rest = " ".join(str(getattr(error, "message", "") or error).split()).partition(":")
        kind = f"{type(error).__name__}: {name}" if name else type(error).__name__
        what = "a malformed request refused" if status == 400 else "a request failed"
        self.refused(f"{what} ({kind})", rest.strip())

    def error(self, msg, *args, **kwargs):
        self.exception(msg, *args, **kwargs)

    def warning(self, msg, *args, **_):
        self.refused(str(msg) % args if args else str(msg))

    def info(self, msg, *args, **_):
        log.debug(msg, *args)

    def debug(self, msg, *args, **_):
        log.debug(msg, *args)

    # -- the event loop's exception handler -----------------------------------

    def loop_error(self, _loop, context: dict) -> None:
        message = str(context.get("message") or "an error in the event loop")
        error = context.get("exception")
        self.refused(message.split(":")[0], "" if error is None else f"{type(error).__name__}: {error}")


class Waiting:
    """At most `limit` connections that have shown no token yet (`shown`): for a
    new one the oldest others are closed. A token shown on a connection (a page's
    websocket, its browser's keep-alive connection) takes it out of the count."""

    def __init__(self, limit: int, refusals: Refusals):
        self.limit = max(1, int(limit))
        self.refusals = refusals
        self.proven: set = set()

    def shown(self, handler) -> None:
        """`handler` (aiohttp's protocol of one connection) sent the token."""
        self.proven.add(handler)

    def make_room(self, connections) -> None:
        """Before a new connection: close the oldest of `connections` (aiohttp's
        protocols of the open ones, oldest first) that have shown no token, until
        fewer than `limit` of them are left open."""
        open_now = [h for h in connections if h.transport is not None and not h.transport.is_closing()]
        self.proven &= set(open_now)  # closed ones go
        waiting = [h for h in open_now if h not in self.proven]
        for handler in waiting[:max(0, len(waiting) - self.limit + 1)]:
            handler.force_close()
            self.refusals.refused("too many connections without the token: the oldest closed")
