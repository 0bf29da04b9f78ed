"""exabricks.util.numba_compiles: while numba compiles (the builders' first run on a
machine), the progress bar on a terminal says so and keeps redrawing."""

from __future__ import annotations

import io

import numba

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


def test_a_compile_outside_a_bar_draws_nothing(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    numba_compiles.announce()

    @numba.njit
    def thrice(x):
        return 3 * x

    assert thrice(2) == 6 and terminal.getvalue() == ""
