"""One page of the viewer, on whatever channel it comes: the scene it wants drawn,
its frames in stages, a newer change dropping what is left of an older one, and
"Save scene" (the messages: server.py's docstring).
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import stat
import threading
from pathlib import Path

from ..util import progress
from ..util.errors import ExabricksError, one_line
from .session import Cancelled, key_light

log = logging.getLogger(__name__)

# How often a page whose frame waits (a kernel build, numba's first compile) is told
# what it waits for ("status" messages; progress.longest_wait).
STATUS_SECONDS = 0.5


class Page:
    """One page's channel: the version it wants drawn and the drawing of it.

    `host` has the `session`, the `lock` on the device and `save(doc)`; `ws` is the
    page's channel (a websocket, or a notebook widget's comm: notebook.Inline), with
    `send_str`, `send_bytes` and `closed`."""

    def __init__(self, viewer, ws):
        self.viewer, self.ws = viewer, ws
        self.version = 0
        self.doc = self.good = viewer.session.doc  # wanted; last that passed its checks
        self.moving = False
        self.tag = 0  # the page's number of the wanted scene
        self.task = None
        self.saves = set()  # saves under way (each a task)

    async def open(self) -> None:
        """A page has opened (a websocket, a view of the notebook widget): its "init"
        message, then the frames of the current scene."""
        # in a thread: its suggested iso-values are numba's, compiled at a first run
        info = await self._told(asyncio.get_running_loop().run_in_executor(None, self.viewer.session.info))
        await self.ws.send_str(json.dumps(info))
        self.want(self.viewer.session.doc, False)

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
                scene = await self._told(loop.run_in_executor(None, session.check, doc))
                self.good = doc
                layer, light = session.layer(scene), key_light(scene)
                size = [scene.settings.width, scene.settings.height]
                def cancelled(version=version):  # a newer change, or the page went away
                    return version != self.version or self.ws.closed

                for stage, staged in session.stages(scene, moving):
                    if version != self.version:
                        break
                    async with self.viewer.lock:
                        try:
                            frame = await _finished(loop.run_in_executor(None, _outcome, session.draw, stage,
                                                                         staged, cancelled), self._told)
                        except Cancelled:
                            break
                    if version != self.version or self.ws.closed:
                        break
                    await self.ws.send_str(json.dumps({
                        "type": "frame", "stage": frame.stage, "width": frame.width,
                        "height": frame.height, "spp": frame.spp, "ms": round(frame.ms, 1),
                        "samples_per_second": frame.samples_per_second, "device": frame.device,
                        "version": tag, "size": size, "layer": layer, "key_light": light}))
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
            except Exception as e:  # a defect: said on the terminal and the page, not a hang
                log.error("view: drawing a frame failed: %s: %s", type(e).__name__, one_line(str(e)),
                          exc_info=log.isEnabledFor(logging.DEBUG))
                await self.error(f"drawing the frame failed ({type(e).__name__}); the server log "
                                 "has the rest")
                return
            if version == self.version or self.ws.closed:
                return

    async def _told(self, future):
        """`future`'s result (a thread's); meanwhile, every STATUS_SECONDS, the page is
        told of a wait under way in this process that has taken longer than a
        terminal waits before it says so (a "status" message). A cancel leaves the
        thread's future running."""
        while not (await asyncio.wait([future], timeout=STATUS_SECONDS))[0]:
            wait = progress.longest_wait()
            if wait is not None and wait[1] >= progress.announce_after() and not self.ws.closed:
                message, seconds = wait
                await self.ws.send_str(json.dumps({"type": "status",
                                                   "line": f"{message} {seconds:.0f} s"}))
        return future.result()

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


def _outcome(function, *args):
    """(`function(*args)`, None), or (None, the exception it raised): what a frame's
    thread hands back. The executor's future then never holds an exception: one
    whose page went away, or whose loop stopped (SIGTERM) before the thread ended,
    would be reported as "Future exception was never retrieved", with a traceback."""
    try:
        return function(*args), None
    except Exception as e:  # raised again by _finished, in the coroutine that waits
        return None, e


async def _finished(future, told):
    """The result of a frame drawn in a thread (an `_outcome`), or its exception
    raised, awaited through `told` (Page._told). When the page goes away meanwhile,
    the drawing is waited for before the cancel goes on, so that the lock on the
    device is not released while a thread still draws."""
    try:
        result, error = await told(future)
    except asyncio.CancelledError:
        await asyncio.wait([future])
        raise
    if error is not None:
        raise error
    return result


def regular_output(path: Path, inputs=()) -> None:
    """Refuse --scene-out naming something other than a regular file (or nothing yet):
    a FIFO, a device or a descriptor would hold a save up, so the viewer never
    writes into one (exabricks.util.output writes into them for other commands);
    or naming any file the `inputs` are made of (check_output)."""
    from ..util.output import check_output

    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        check_output(path, inputs)
        return
    except OSError as e:
        raise ExabricksError(f"--scene-out {path}: cannot look at it ({e.strerror or e})") from None
    if stat.S_ISREG(mode):
        check_output(path, inputs)
        return
    kind = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    raise ExabricksError(f"--scene-out {path}: is {kind}; the viewer saves scenes to a regular file only")


def save_scene(path: Path | None, doc: dict, inputs=()) -> str | None:
    """Write the scene `doc` to `path` (--scene-out; a regular file, atomically,
    never one of the files `inputs` are made of); its path, or None without one."""
    from ..util.output import write_json

    if path is None:
        return None
    regular_output(path, inputs)
    write_json(path, doc, inputs=inputs)
    return str(path)
