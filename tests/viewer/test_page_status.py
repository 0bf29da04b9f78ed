"""A page whose frame waits (a kernel build, numba's first compile) is told what it
waits for, every half second, in "status" messages (viewer/page.py)."""

from __future__ import annotations

import asyncio
import json
import time
from types import SimpleNamespace

from exabricks.util import progress
from exabricks.viewer import page

# the lighting of a fake scene: the headlight (no key light for the page to take)
UNLIT = SimpleNamespace(integrator="headlight", light=None)


class Channel:
    """A page's channel that keeps what the server sends."""

    closed = False

    def __init__(self):
        self.sent = []

    async def send_str(self, text):
        self.sent.append(json.loads(text))

    async def send_bytes(self, data):
        self.sent.append(data)


class Session:
    """A session whose one stage waits `seconds` in a progress.waiting block, as a
    kernel build does."""

    doc = {}

    def __init__(self, seconds):
        self.seconds = seconds

    def info(self):
        return {"type": "init"}

    def check(self, doc):
        return SimpleNamespace(settings=SimpleNamespace(width=8, height=8), lighting=UNLIT)

    def layer(self, scene):
        return None

    def stages(self, scene, moving=False):
        return [("converged", scene)]

    def draw(self, stage, scene, cancelled=None):
        with progress.waiting("compiling the renderer for a device…"):
            time.sleep(self.seconds)
        return SimpleNamespace(stage=stage, width=8, height=8, spp=1, ms=1.0,
                               samples_per_second=0, device="d", png=b"png")


def messages(seconds, monkeypatch):
    monkeypatch.setenv("EXABRICKS_ANNOUNCE_AFTER", "1")
    channel = Channel()
    viewer = SimpleNamespace(session=Session(seconds), lock=None)

    async def run():
        viewer.lock = asyncio.Lock()
        p = page.Page(viewer, channel)
        await p.open()
        await p.task
    asyncio.run(run())
    return channel.sent


def test_a_long_wait_is_told_to_the_page(monkeypatch):
    sent = messages(2.2, monkeypatch)
    told = [m["line"] for m in sent if isinstance(m, dict) and m["type"] == "status"]
    assert told and all(line.startswith("compiling the renderer for a device…") for line in told)
    assert told[-1].endswith(" 2 s")  # the seconds tick
    assert [m["type"] for m in sent if isinstance(m, dict)][-1] == "frame"
    assert progress.longest_wait() is None  # the wait is over


def test_a_short_wait_is_not(monkeypatch):
    sent = messages(0.3, monkeypatch)
    assert [m["type"] for m in sent if isinstance(m, dict)] == ["init", "frame"]


def test_a_defect_in_a_draw_is_said_not_hung(monkeypatch, caplog):
    monkeypatch.setattr(Session, "stages", lambda self, scene, moving=False: 1 / 0)
    sent = messages(0.0, monkeypatch)
    errors = [m["message"] for m in sent if isinstance(m, dict) and m["type"] == "error"]
    assert errors == ["drawing the frame failed (ZeroDivisionError); the server log has the rest"]
    assert "ZeroDivisionError" in caplog.text
