"""exabricks: volume rendering of adaptive-mesh-refinement data (Wald et al. 2020).

    import exabricks as eb
    ds = eb.open("plt00020")
    eb.render(ds, field="phi", size=(512, 512)).save("phi.png")

docs/python.md walks through the library; `exabricks --help` lists the commands.
The public names are imported when first used, so that a command's start does not
pay for the library.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .util.version import __version__

# public name -> the module that defines it
_PUBLIC = {
    "open": "api", "render": "api", "render_job": "api", "probe": "api", "Renderer": "api",
    "Dataset": "dataset", "Image": "film.image", "Scene": "scene", "ExabricksError": "util.errors",
    "open_series": "series", "render_series": "series", "Series": "series",
    "view": "viewer.notebook",
}

__all__ = ["__version__", *sorted(_PUBLIC)]

if TYPE_CHECKING:
    from .api import Renderer, open, probe, render, render_job  # noqa: F401
    from .dataset import Dataset  # noqa: F401
    from .util.errors import ExabricksError  # noqa: F401
    from .film.image import Image  # noqa: F401
    from .scene import Scene  # noqa: F401
    from .series import Series, open_series, render_series  # noqa: F401
    from .viewer.notebook import view  # noqa: F401


def __getattr__(name: str):
    if name in _PUBLIC:
        value = getattr(importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'exabricks' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_PUBLIC])
