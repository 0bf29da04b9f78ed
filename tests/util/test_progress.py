"""exabricks.util.progress.tick: a long step's bar keeps its clock going on a
terminal (the renderer's pacing calls it after each run of launches)."""

from __future__ import annotations

import io
import time

from exabricks.util import progress


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_long_frame_ticks_its_bar(monkeypatch):
    """progress.tick, which the renderer's pacing calls after each run of launches,
    redraws the bar open (its clock), at most every TICK_SECONDS."""
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    monkeypatch.delenv("EXABRICKS_QUIET", raising=False)
    redraws = []
    with progress.bar(total=1, desc="render", unit="frame") as bar:
        monkeypatch.setattr(bar, "refresh", lambda *a, **k: redraws.append(1))
        for _ in range(5):
            progress.tick()
            time.sleep(progress.TICK_SECONDS / 4)
        time.sleep(progress.TICK_SECONDS)
        progress.tick()
    assert 2 <= len(redraws) <= 3
    progress.tick()  # no bar open: nothing to do
