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
of an older frame, as on `exabricks view`'s page. `viewer.document` is the scene
file's object that "Save scene" writes, `viewer.scene` its eb.Scene for
`eb.render`.
"""

from __future__ import annotations

import asyncio
import json
import threading
from functools import cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from ..util.errors import ExabricksError
from .page import Page, regular_output, save_scene

if TYPE_CHECKING:
    import anywidget


def view(dataset, scene=None, *, device: str | None = None, scene_out=None,
         memory_budget=None, **options) -> anywidget.AnyWidget:
    """The progressive viewer of `dataset` (a Dataset, or anything eb.open takes) in
    the output cell, a widget; `scene` and `options` as for eb.render (the first
    picture is render's). `scene_out`: a file "Save scene" writes too. Needs
    anywidget (pip install 'exabricks[notebook]')."""
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
            self.lock = asyncio.Lock()  # one frame on the device at a time
            self._loop = asyncio.new_event_loop()
            threading.Thread(target=self._loop.run_forever, name="exabricks-inline", daemon=True).start()
            self._page = Page(self, _Comm(self))
            self.on_msg(self._received)

        @property
        def document(self) -> dict:
            """The scene file's object of the view (what "Save scene" writes)."""
            return json.loads(json.dumps(self._page.good))

        @property
        def scene(self):
            """The view as an eb.Scene, for eb.render."""
            return self.session.check(self.document)

        def save(self, doc: dict) -> str | None:
            """"Save scene": write `scene_out`, if given (page.save_scene)."""
            return save_scene(self.scene_out, doc, self.session.inputs)

        def close(self) -> None:
            self._page.close()
            super().close()
            self._loop.call_soon_threadsafe(self._loop.stop)

        def _received(self, _widget, content, _buffers) -> None:
            if self.comm is None or self._loop.is_closed() or not self._loop.is_running():
                return  # closed: nothing answers
            text = content.get("text") if isinstance(content, dict) else None
            asyncio.run_coroutine_threadsafe(self._handle(text), self._loop)

        async def _handle(self, text) -> None:
            if not isinstance(text, str):
                await self._page.error('a message is {"text": ...}')
                return
            try:
                hello = json.loads(text) == {"type": "hello"}
            except (ValueError, RecursionError):
                hello = False
            if hello:  # a view of the widget opened (a cell shown, a page reloaded)
                await self._page.open()
            else:
                await self._page.receive(text)

    return Inline


class _Comm:
    """The page's channel (page.Page's `ws`) over the widget's comm. ipykernel's
    messages may be sent from any thread."""

    def __init__(self, widget):
        self.widget = widget

    @property
    def closed(self) -> bool:
        return self.widget.comm is None

    async def send_str(self, text: str) -> None:
        if not self.closed:
            self.widget.send({"text": text})

    async def send_bytes(self, data: bytes) -> None:
        if not self.closed:
            self.widget.send({"binary": True}, buffers=[data])


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
    return () => viewer.close();
  }},
}};
"""


def _styles() -> str:
    return resources.files(__package__).joinpath("static", "viewer.css").read_text()
