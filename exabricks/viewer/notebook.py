"""The viewer in a notebook's output cell: `eb.view(ds, ...)` (docs/view.md, "In a
notebook").

The cell shows `exabricks view`'s page (static/: the same controls, the same
progressive frames, the same "Save scene"), drawn by an anywidget widget. The
page's messages (server.py's docstring) travel over the widget's comm instead of
a websocket of ours: through the Jupyter server and the kernel's own channels,
behind Jupyter's (or JupyterHub's) authentication, with no port, token or tunnel
of ours. Each comm message is {"text": JSON} or, for a frame's PNG,
{"binary": true} with the PNG as its buffer; the page's "hello" asks for the
"init" message and the frame, as a websocket's opening does.

The frames are drawn on the widget's own event loop, in a thread (page.Page), so
the kernel goes on taking the page's messages: a newer change drops what is left
of an older frame, as on `exabricks view`'s page. That loop, its threads and the
dataset's copy on the device exist only while a view shows the widget: they
start with a view's "hello" and go when the last view says "bye" (its output
cleared, its cell run again: ipywidgets keeps every widget until it is closed, so
a dropped one is never collected), on `close()`, or when the widget is collected.
`viewer.document` is the scene file's object that "Save scene" writes,
`viewer.scene` its eb.Scene for `eb.render`.
"""

from __future__ import annotations

import asyncio
import json
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from ..util.errors import ExabricksError
from .page import Page, regular_output, save_scene

if TYPE_CHECKING:
    import anywidget

# Threads drawing a widget's frames while it is shown: one draws under the device
# lock while the other checks the newest change.
DRAWING_THREADS = 2


def view(dataset, scene=None, *, device: str | None = None, scene_out=None,
         memory_budget=None, **options) -> anywidget.AnyWidget:
    """The progressive viewer of `dataset` (a Dataset, or anything eb.open takes) in
    the output cell, a widget; `scene` and `options` as for eb.render (the first
    picture is render's). `scene_out`: a file "Save scene" writes too. Needs
    anywidget (pip install 'exabricks[notebook]').

    Parameters
    ----------
    dataset
        A Dataset, or anything `eb.open` takes.
    scene
        A scene file path, a dict in the scene-file format, or an eb.Scene.
    device
        As `eb.render`.
    scene_out
        A regular file (or none yet) that "Save scene" writes besides the
        download; never one of the dataset's files.
    memory_budget
        Bytes, or a size such as "512MiB" or "2G": each frame drawn within it, as
        `render --memory-budget` draws it; only for a dataset with files (not one
        opened with cache=False, nor a yt dataset).
    **options
        The render flags by their keyword, `-` as `_`, and the scene file's keys, as
        `eb.render` takes them (docs/reference/scene-options.md).

    Returns
    -------
    anywidget.AnyWidget
        Shown by the cell; its `document` is the scene file's object of the view,
        its `scene` the eb.Scene, and `close()` frees the device's copy for good.

    Raises
    ------
    ExabricksError
        anywidget is not installed; `scene_out` is not a regular file or names an
        input; `memory_budget` is not a size or the dataset has no files; the scene
        or an option is not valid.
    TypeError
        An option that is no render flag.
    """
    from ..api import open as open_dataset
    from ..scene import Scene, scene_to_dict
    from ..util.sizes import parse_size
    from .session import Session

    widget = _widget_class()
    budget = None if memory_budget is None else parse_size(memory_budget)
    dataset = open_dataset(dataset)
    if scene_out is not None:
        regular_output(Path(scene_out), dataset.inputs)
    if isinstance(scene, Scene):
        scene = scene_to_dict(scene)
    session = Session(dataset, device=device, scene=scene, options=options, budget=budget)
    return widget(session, scene_out=scene_out)


@cache
def _widget_class():
    try:
        import anywidget
    except ImportError:
        raise ExabricksError("eb.view: the viewer in a notebook needs anywidget in the kernel's "
                             "environment: pip install 'exabricks[notebook]'") from None

    class Inline(anywidget.AnyWidget):
        """`exabricks view`'s page in an output cell (module docstring)."""

        _esm = _module()
        _css = _styles()

        def __init__(self, session, *, scene_out=None):
            super().__init__()
            self.session = session
            self.scene_out = None if scene_out is None else Path(scene_out)
            self._drawing = _Drawing(session, self.scene_out, _Comm(weakref.ref(self)))
            # the drawing holds no reference to the widget: collected, it stops
            self._release = weakref.finalize(self, self._drawing.close)
            self.on_msg(self._received)

        @property
        def document(self) -> dict:
            """The scene file's object of the view (what "Save scene" writes)."""
            return json.loads(json.dumps(self._drawing.page.good))

        @property
        def scene(self):
            """The view as an eb.Scene, for eb.render."""
            return self.session.check(self.document)

        def save(self, doc: dict) -> str | None:
            """"Save scene": write `scene_out`, if given (page.save_scene)."""
            return save_scene(self.scene_out, doc, self.session.inputs)

        def close(self) -> None:
            self._release()
            super().close()

        def _received(self, _widget, content, _buffers) -> None:
            if self.comm is None:
                return  # closed: nothing answers
            self._drawing.received(content.get("text") if isinstance(content, dict) else None)

    return Inline


class _Drawing:
    """What draws a widget's frames while a view shows it: an event loop in a thread
    of its own, with its executor's threads, and the dataset's copy on the device
    (module docstring). The host of the widget's page.Page (its `session`, `lock`
    and `save`); it holds no reference to the widget (its channel's is weak), so
    that none of its threads keeps a dropped widget alive."""

    def __init__(self, session, scene_out, channel):
        self.session, self.scene_out = session, scene_out
        self.page = Page(self, channel)
        self.lock = None  # one frame on the device at a time: an asyncio.Lock of the running loop
        self.views = 0
        self.loop = self.thread = None
        self.closed = False
        self._starting = threading.Lock()  # the kernel's thread starts; a finalizer may stop

    def save(self, doc: dict) -> str | None:
        """"Save scene": write `scene_out`, if given (page.save_scene)."""
        return save_scene(self.scene_out, doc, self.session.inputs)

    def received(self, text) -> None:
        """A message of a view (on the kernel's thread): "hello" counts a view and
        "bye" one gone, the last stopping the drawing; any other is handled on the
        loop, started if none runs (a view that opened before a "bye" of another)."""
        kind = _kind(text)
        if kind == "bye":
            self.views = max(0, self.views - 1)
            if self.views == 0:
                self.stop()
            return
        if kind == "hello":
            self.views += 1
        with self._starting:
            if self.closed:
                return
            if self.loop is None:
                self.loop, self.lock = asyncio.new_event_loop(), asyncio.Lock()
                self.thread = threading.Thread(target=self._run, args=(self.loop,), name="exabricks-inline",
                                               daemon=True)
                self.thread.start()
            asyncio.run_coroutine_threadsafe(self._handle(text, kind == "hello"), self.loop)

    async def _handle(self, text, hello: bool) -> None:
        if not isinstance(text, str):
            await self.page.error('a message is {"text": ...}')
        elif hello:  # a view of the widget opened (a cell shown, a page reloaded)
            await self.page.open()
        else:
            await self.page.receive(text)

    def _run(self, loop) -> None:
        """The loop's thread: until stopped, then the page's frame and saves dropped
        (the frame's thread ends its tile) and the executor's threads ended."""
        asyncio.set_event_loop(loop)
        loop.set_default_executor(ThreadPoolExecutor(DRAWING_THREADS, thread_name_prefix="exabricks-inline"))
        try:
            loop.run_forever()
            loop.run_until_complete(self._wind_down())
            loop.run_until_complete(loop.shutdown_default_executor())
        finally:
            loop.close()

    async def _wind_down(self) -> None:
        tasks = [t for t in (self.page.task, *self.page.saves) if t is not None]
        self.page.close()
        if tasks:
            await asyncio.wait(tasks)

    def stop(self) -> None:
        """Stop the loop and its threads (waited for) and free the device's copy of
        the dataset; the next message starts them again."""
        with self._starting:
            loop, thread = self.loop, self.thread
            self.loop = self.thread = None
        if loop is None:
            return
        loop.call_soon_threadsafe(loop.stop)
        # a finalizer may run on one of the drawing's own threads (the widget
        # collected there): waiting for the loop would then wait for itself
        if not threading.current_thread().name.startswith("exabricks-inline"):
            thread.join()
        self.session.release()

    def close(self) -> None:
        """Stop for good: no message starts the drawing again."""
        with self._starting:
            self.closed = True
        self.stop()


def _kind(text) -> str | None:
    """The "type" of a view's message, if it is "hello" or "bye"."""
    if not isinstance(text, str) or len(text) > 64:  # either is a few bytes
        return None
    try:
        message = json.loads(text)
    except (ValueError, RecursionError):
        return None
    return message["type"] if message in ({"type": "hello"}, {"type": "bye"}) else None


class _Comm:
    """The page's channel (page.Page's `ws`) over the comm of the widget `widget()`
    (a weak reference: the channel is closed once the widget is gone). ipykernel's
    messages may be sent from any thread."""

    def __init__(self, widget):
        self.widget = widget

    @property
    def closed(self) -> bool:
        widget = self.widget()
        return widget is None or widget.comm is None

    async def send_str(self, text: str) -> None:
        widget = self.widget()
        if widget is not None and widget.comm is not None:
            widget.send({"text": text})

    async def send_bytes(self, data: bytes) -> None:
        widget = self.widget()
        if widget is not None and widget.comm is not None:
            widget.send({"binary": True}, buffers=[data])


def _module() -> str:
    """The widget's ES module: the page's script, its markup and the widget's entry."""
    static = resources.files(__package__).joinpath("static")
    page = static.joinpath("index.html").read_text()
    markup = page[page.index("<main>"):page.index("</main>") + len("</main>")]
    return static.joinpath("viewer.js").read_text() + f"""
const MARKUP = {json.dumps(markup)};
export default {{
  render({{ model, el }}) {{
    el.classList.add("exabricks", "exabricks-inline");
    el.innerHTML = MARKUP;
    const viewer = exabricksViewer(el, widgetChannel(model));
    (window.exabricksViews ||= []).push(viewer);  // for the browser tests and the curious
    return () => viewer.close();  // the channel's close says "bye": the kernel frees the drawing
  }},
}};
"""


def _styles() -> str:
    return resources.files(__package__).joinpath("static", "viewer.css").read_text()
