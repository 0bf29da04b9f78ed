"""Say so on a terminal while numba compiles: the first run after an install (or
an upgrade of numba) compiles the builders for this machine, tens of seconds on
two cores (35 s for the embedded plume's first render), before numba's cache
serves every later run. The innermost progress bar open (exabricks.util.progress)
says "compiling for this machine (once)" and is redrawn at each function numba
compiles, so its clock keeps ticking; off a terminal nothing is drawn.
"""

from __future__ import annotations

NOTE = "compiling for this machine (once)"

_INSTALLED = []


def announce() -> None:
    """Listen to numba's compiles (once per process; imports numba)."""
    if _INSTALLED:
        return
    from numba.core import event

    from . import progress

    class Listener(event.Listener):
        depth = 0

        def on_start(self, _event):
            self.depth += 1
            shown = progress.current()
            if shown is not None:
                shown.set_postfix_str(NOTE, refresh=True)

        def on_end(self, _event):
            self.depth -= 1
            shown = progress.current()
            if shown is not None and self.depth == 0:
                shown.set_postfix_str("", refresh=True)

    listener = Listener()
    event.register("numba:compile", listener)
    _INSTALLED.append(listener)
