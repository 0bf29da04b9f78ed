"""exabricks.util.numba_compiles: while numba compiles (the builders' first run on a
machine), the progress bar on a terminal says so and keeps redrawing; outside a
bar a wait line says so; off a terminal nothing is drawn."""

from __future__ import annotations

import io
import time

import numba
from numba.core import event

from exabricks.util import numba_compiles, progress


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_compile_inside_a_bar_says_so(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    monkeypatch.delenv("EXABRICKS_QUIET", raising=False)
    numba_compiles.announce()

    @numba.njit  # a function of its own: never in numba's cache
    def twice(x):
        return 2 * x

    with progress.bar(total=2, desc="build", unit="step") as bar:
        assert progress.current() is bar
        bar.update()
        assert twice(21) == 42
        during = terminal.getvalue()
        assert bar.postfix == ""  # the note goes when the compile ends
    assert numba_compiles.NOTE in during
    assert progress.current() is None


def test_a_compile_outside_a_bar_shows_a_wait_line(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    monkeypatch.delenv("EXABRICKS_QUIET", raising=False)
    numba_compiles.announce()

    @numba.njit
    def thrice(x):
        return 3 * x

    assert thrice(2) == 6
    assert numba_compiles.NOTE in terminal.getvalue()
    assert terminal.getvalue().endswith("\r\x1b[K")  # the line goes when the compile ends


def test_a_bar_keeps_ticking_through_one_long_compile(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    monkeypatch.delenv("EXABRICKS_QUIET", raising=False)
    numba_compiles.announce()
    redraws = []
    with progress.bar(total=1, desc="build", unit="step") as bar:
        monkeypatch.setattr(bar, "refresh", lambda *a, **k: redraws.append(1))
        # one compile held for a second, as a large builder's takes
        with event.trigger_event("numba:compile", data={"dispatcher": None, "args": ()}):
            time.sleep(1.0)
    assert len(redraws) >= 1.0 / progress.TICK_SECONDS - 1


def test_off_a_terminal_a_compile_draws_nothing(monkeypatch):
    terminal = io.StringIO()
    monkeypatch.setattr("sys.stderr", terminal)
    numba_compiles.announce()

    @numba.njit
    def four_times(x):
        return 4 * x

    assert four_times(2) == 8 and terminal.getvalue() == ""

