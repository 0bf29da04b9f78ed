"""Progress bars and waits that show on a terminal and stay quiet in batch logs and with -q.

On a terminal (stderr a TTY, no -q / EXABRICKS_QUIET) a long step shows a transient
line that goes when the step is done; off a terminal nothing is drawn, and what a
batch log should keep goes through logging (`-v`) instead.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from contextlib import contextmanager

from tqdm import tqdm

# Seconds a wait stays silent before `waiting` says what it is waiting for
# (EXABRICKS_ANNOUNCE_AFTER overrides it): a step served from a cache ends first.
ANNOUNCE_AFTER = 1.0
# How often the elapsed seconds and the spinner of a shown wait are redrawn.
TICK_SECONDS = 0.25
SPINNER = "|/-\\"


def enabled(stream=None) -> bool:
    """Whether to draw on `stream` (default: stderr): a terminal, and no -q."""
    stream = sys.stderr if stream is None else stream
    return stream.isatty() and os.environ.get("EXABRICKS_QUIET", "") in ("", "0")


class _Bar(tqdm):
    """A tqdm bar that is `current()` while it is open and drawn."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        if not self.disable:
            _OPEN.append(self)

    def close(self):
        if self in _OPEN:
            _OPEN.remove(self)
        super().close()


_OPEN: list = []


def bar(total=None, desc: str = "", unit: str = "it", disable: bool = False, **kw) -> tqdm:
    """A tqdm bar on stderr, disabled off a terminal, under -q, or by `disable`."""
    return _Bar(total=total, desc=desc, unit=unit, disable=disable or not enabled(),
                file=sys.stderr, leave=False, dynamic_ncols=True, **kw)


def current():
    """The innermost bar open now, or None (what a wait inside a step is told to)."""
    return _OPEN[-1] if _OPEN else None


def tick() -> None:
    """Redraw the innermost bar open (its elapsed time), at most every TICK_SECONDS:
    what a long step calls between its parts, so that a frame of many seconds
    does not sit silent at 0 %."""
    shown = current()
    now = time.perf_counter()
    if shown is not None and now - _TICKED[0] >= TICK_SECONDS:
        _TICKED[0] = now
        shown.refresh()


_TICKED = [0.0]


def announce_after() -> float:
    """Seconds before a wait is announced: EXABRICKS_ANNOUNCE_AFTER, else ANNOUNCE_AFTER."""
    try:
        return max(0.0, float(os.environ.get("EXABRICKS_ANNOUNCE_AFTER", "") or ANNOUNCE_AFTER))
    except ValueError:
        return ANNOUNCE_AFTER


class Wait:
    """What `waiting` saw: `seconds` the block took (from `since`), whether the line was `shown`."""

    def __init__(self, since: float):
        self.since = since
        self.seconds = 0.0
        self.shown = False


def _line(message: str, elapsed: float, tick: int, width: int) -> str:
    """`message` and the elapsed seconds, cut to fit one terminal line of `width`."""
    tail = f" {elapsed:.0f} s {SPINNER[tick % len(SPINNER)]}"
    room = max(width - 1 - len(tail), 10)
    if len(message) > room:
        message = message[:room - 1] + "…"
    return message + tail


def _width(stream) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns or 80  # 0: a terminal of no size
    except (OSError, ValueError, AttributeError):
        return 80


@contextmanager
def waiting(message: str, *, after: float | None = None, since: float | None = None,
            stream=None):
    """Say `message` on a terminal, with the seconds ticking and a spinner, once the block
    has taken `after` seconds (default announce_after()) counted from `since`
    (time.perf_counter(); default now); the line goes when the block ends. Off a
    terminal or under -q nothing is written. The block must wait without the GIL
    (in a driver call, sleeping, reading files) for the line to tick. `stream`: where
    the line goes (default stderr; a kernel build's own stderr is held aside,
    exabricks.device.opencl). Yields a Wait."""
    wait = Wait(time.perf_counter() if since is None else since)
    after = announce_after() if after is None else after
    stream = sys.stderr if stream is None else stream
    done = threading.Event()
    thread = None
    with _WAITS_LOCK:
        _WAITS.append((message, wait))
    if enabled(stream):

        def draw():
            if done.wait(max(0.0, wait.since + after - time.perf_counter())):
                return
            width, tick = _width(stream), 0
            try:
                while True:
                    stream.write("\r" + _line(message, time.perf_counter() - wait.since, tick, width)
                                 + "\x1b[K")
                    stream.flush()
                    wait.shown = True
                    tick += 1
                    if done.wait(TICK_SECONDS):
                        break
                stream.write("\r\x1b[K")
                stream.flush()
            except (OSError, ValueError):  # the terminal went away: keep waiting quietly
                pass

        thread = threading.Thread(target=draw, name="exabricks-waiting", daemon=True)
        thread.start()
    try:
        yield wait
    finally:
        wait.seconds = time.perf_counter() - wait.since
        with _WAITS_LOCK:
            _WAITS.remove((message, wait))
        done.set()
        if thread is not None:
            thread.join()


# The waits under way in this process, on or off a terminal (`waiting` adds and
# removes them): what the viewer's page is told while its frame waits (`longest_wait`).
_WAITS: list = []
_WAITS_LOCK = threading.Lock()


def longest_wait() -> tuple[str, float] | None:
    """(message, seconds so far) of the oldest `waiting` block under way in this
    process, in any thread, or None."""
    with _WAITS_LOCK:
        if not _WAITS:
            return None
        message, wait = min(_WAITS, key=lambda item: item[1].since)
    return message, time.perf_counter() - wait.since
