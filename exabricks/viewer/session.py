"""The viewer's dataset and its frames: a scene document in, progressive frames out.

The page edits a scene file's object (docs/scene.md): the camera, one volume layer
as a colour map with opacity knots over a range, iso-surfaces, slices, clipping,
lighting, background and the settings. Each version is drawn in stages:

1. coarse: a quarter of the size (at least 64 pixels), one sample per pixel,
   with level of detail while the camera moves (`moving`);
2. full: the whole size, one sample per pixel;
3. converged: the document as it is — the frame `render --scene` of the saved
   document draws, pixel for pixel.

A newer version drops what is left of an older one. The document reaches the file
system nowhere: a camera or a transfer function must be inline (or a built-in
preset's name), and only the server writes, to `--scene-out`.
"""

from __future__ import annotations

import io
import json
import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import ExabricksError

# The matplotlib colour maps the page offers (any other name in a loaded scene works too).
COLORMAPS = ("viridis", "inferno", "magma", "plasma", "cividis", "turbo", "coolwarm", "RdBu_r",
             "YlGnBu", "gray", "Blues", "Reds")
HISTOGRAM_BINS = 64
HISTOGRAM_SAMPLES = 1 << 20  # values per field the histogram looks at, at most
COARSE_FRACTION = 4
COARSE_MIN = 64
MOVING_LOD = 2.0  # --lod while the camera moves, when the page asks for it
MAX_DOC_BYTES = 1 << 20


@dataclass(frozen=True)
class Frame:
    png: bytes
    stage: str  # coarse, full, converged
    width: int
    height: int
    spp: int
    ms: float
    samples_per_second: float
    device: str


class Session:
    """A dataset kept on the device (exabricks.api.Renderer) and the scene document
    the page edits."""

    def __init__(self, dataset, *, device=None, scene=None, options: dict | None = None,
                 budget: int | None = None):
        from ..api import Renderer

        self.renderer = Renderer(dataset, device=device)
        start = self.renderer.scene(scene, **(options or {}))
        self.meshes = {m.path for m in start.meshes}  # the only files a page may name
        self.doc = page_document(start, options or {})
        self.check(self.doc)
        self.budget, self.device = budget, device
        if budget is not None and dataset.paths is None:
            raise ExabricksError("--memory-budget: reads the structures from files by parts: view "
                                 "a source through the cache (not --no-cache)")
        self._domains = None  # (fields, size, Budgeted) under a memory budget

    def check(self, doc) -> object:
        """The eb.Scene of a document from the page, or ExabricksError (one line)."""
        if not isinstance(doc, dict):
            raise ExabricksError("scene: expected a scene object")
        if len(json.dumps(doc)) > MAX_DOC_BYTES:
            raise ExabricksError(f"scene: larger than {MAX_DOC_BYTES} bytes")
        _no_files(doc, self.meshes)
        return self.renderer.scene(doc)

    def info(self) -> dict:
        """What the page needs at the start: the document, the fields with their ranges
        and histograms, the colour maps, the data's bounds and the device."""
        bricks = self.renderer.dataset.bricks
        fields = {}
        for i, name in enumerate(bricks.fields):
            values = np.asarray(bricks.values[i])
            step = max(1, values.size // HISTOGRAM_SAMPLES)
            sample = values[::step]
            sample = sample[np.isfinite(sample)]
            lo, hi = (float(sample.min()), float(sample.max())) if sample.size else (0.0, 1.0)
            counts, _ = np.histogram(sample, bins=HISTOGRAM_BINS, range=(lo, hi if hi > lo else lo + 1))
            fields[name] = {"range": [lo, hi], "histogram": counts.tolist()}
        lo, hi = self.renderer.dataset.bounds
        return {"type": "init", "scene": self.doc, "fields": fields, "colormaps": list(COLORMAPS),
                "bounds": [list(lo), list(hi)]}

    def stages(self, scene, moving: bool = False) -> list[tuple[str, object]]:
        """(stage, scene) to draw, coarse to converged."""
        s = scene.settings
        w = max(min(COARSE_MIN, s.width), s.width // COARSE_FRACTION)
        h = max(1, round(s.height * w / s.width))
        coarse = replace(s, width=w, height=h, spp=1, depth=False,
                         lod=max(s.lod, MOVING_LOD) if moving else s.lod)
        out = [("coarse", scene.replace(settings=coarse))]
        if not moving:
            if s.spp > 1:
                out.append(("full", scene.replace(settings=replace(s, spp=1, depth=False))))
            out.append(("converged", scene.replace(settings=replace(s, depth=False))))
        return out

    def draw(self, stage: str, scene) -> Frame:
        from PIL import Image as PILImage

        started = time.perf_counter()
        image = self._budgeted(scene) if self.budget is not None else self.renderer.render(scene)
        out = io.BytesIO()
        PILImage.fromarray(image.shown(), "RGB").save(out, format="PNG", compress_level=1)
        st = image.metadata.get("settings", {})
        return Frame(out.getvalue(), stage, scene.settings.width, scene.settings.height,
                     scene.settings.spp, (time.perf_counter() - started) * 1e3,
                     float(st.get("samples_per_second", 0.0)), str(st.get("device", "")))


    def _budgeted(self, scene):
        """The frame drawn domain by domain within the memory budget, as `render
        --memory-budget` draws it (exabricks.engine.streaming)."""
        from ..engine.streaming import Budgeted, render_steps
        from ..image import Image
        key = (scene.fields(), scene.settings.width, scene.settings.height)
        if self._domains is None or self._domains[0] != key:
            paths = self.renderer.dataset.paths
            bricks, regions, _ = self.renderer.dataset.load("data")
            self._domains = (key, Budgeted(bricks, regions, scene, self.budget, device=self.device,
                                           where=tuple(map(str, paths[:2]))))
        result = render_steps(self._domains[1], scene)
        return Image(result.rgba, None, {"settings": result.stats}, scene=scene)


def page_document(scene, options: dict) -> dict:
    """The scene file's object of `scene` (exabricks.scene.scene_to_dict), its first
    volume layer as the page edits one: a colour map with opacity knots over a range
    (the flags' --colormap and --opacity, viridis and a ramp by default)."""
    from ..scene import scene_to_dict

    doc = scene_to_dict(scene)
    if scene.volumes:
        layer = scene.volumes[0]
        points = layer.transfer_function.rgb_points
        opacity = options.get("opacity") or (0.0, 1.0)
        doc["volumes"] = [{"field": layer.field,
                           "transfer_function": {"colormap": options.get("colormap") or "viridis",
                                                 "opacity": [float(a) for a in opacity]},
                           "range": [float(points[0, 0]), float(points[-1, 0])]}]
    return _finite(doc)


def _finite(doc):
    """`doc` with no NaN or infinity (a scene file holds neither)."""
    text = json.dumps(doc, allow_nan=True)
    if "NaN" in text or "Infinity" in text:
        raise ExabricksError("scene: a value is not a finite number")
    return json.loads(text)


def _no_files(doc: dict, meshes=frozenset()) -> None:
    """Refuse what would make the server read a file: a camera file, a preset file, a
    mesh file other than `meshes` (those the viewer was started with)."""
    from ..transfer_function import builtin_presets

    entries = doc.get("meshes")
    for i, m in enumerate(entries if isinstance(entries, list) else []):
        if isinstance(m, dict) and m.get("path") not in meshes:
            raise ExabricksError(f"scene: meshes[{i}].path: the viewer draws only the meshes it "
                                 "was started with (--mesh, or the scene file's meshes)")

    if "camera" in doc and not isinstance(doc["camera"], dict):
        raise ExabricksError("scene: camera: the viewer takes an inline camera object, not a file")
    volumes = doc.get("volumes")
    for i, v in enumerate(volumes if isinstance(volumes, list) else []):
        tf = v.get("transfer_function") if isinstance(v, dict) else None
        if isinstance(tf, str) and tf not in builtin_presets():
            raise ExabricksError(f"scene: volumes[{i}].transfer_function: the viewer takes an inline "
                                 f"transfer function or a built-in preset "
                                 f"({', '.join(builtin_presets())}), not a file")
