"""Say so on a terminal while numba compiles: the first run after an install (or
an upgrade of numba) compiles the builders and the field statistics for this
machine, tens of seconds on two cores (35 s for the embedded plume's first
render), before numba's cache serves every later run. The innermost progress bar
open (exabricks.util.progress) says "compiling for this machine (once)" and is
redrawn every tick while numba compiles, so its clock keeps going through a
single compile of seconds; outside a bar the same words come at once as a wait
line (`progress.waiting`): numba tells only of compiles, never of functions its
cache serves. Off a terminal nothing is drawn, but the wait is known
(`progress.longest_wait`: what the viewer's page is told).
"""

from __future__ import annotations

import contextlib
import threading

NOTE = "compiling for this machine (once)"

_INSTALLED = []


class _Shown:
    """What a compile shows while it lasts: the bar open now with the note, redrawn
    each tick by a thread, or a wait line where no bar is open."""

    def __init__(self, progress):
        self.bar = progress.current()
        self.done = threading.Event()
        self.stack = contextlib.ExitStack()
        if self.bar is None:
            self.stack.enter_context(progress.waiting(NOTE + "…", after=0.0))
            return
        self.bar.set_postfix_str(NOTE, refresh=True)
        ticker = threading.Thread(target=self._tick, args=(progress.TICK_SECONDS,),
                                  name="exabricks-numba-compiles", daemon=True)
        ticker.start()
        self.stack.callback(ticker.join)
        self.stack.callback(self.done.set)

    def _tick(self, seconds: float) -> None:
        while not self.done.wait(seconds):
            self.bar.refresh()

    def close(self) -> None:
        self.stack.close()
        if self.bar is not None:
            self.bar.set_postfix_str("", refresh=True)


def announce() -> None:
    """Listen to numba's compiles (once per process; imports numba)."""
    if _INSTALLED:
        return
    from numba.core import event

    from . import progress

    class Listener(event.Listener):
        depth = 0
        shown = None

        def on_start(self, _event):
            self.depth += 1
            if self.depth == 1:
                self.shown = _Shown(progress)

        def on_end(self, _event):
            self.depth -= 1
            if self.depth == 0 and self.shown is not None:
                self.shown, shown = None, self.shown
                shown.close()

    listener = Listener()
    event.register("numba:compile", listener)
    _INSTALLED.append(listener)
