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

The first document draws what `render` draws with the same options: without a
transfer function it holds the automatic one's spec (`{"colormap": NAME}` with no
opacity, exabricks.picture.auto_transfer), which the page shows as the knots it would
become (`Session.layer`) until the user edits them. The automatic function of a
layer is computed once per (field, colour map, range, scale), not per frame.
"""

from __future__ import annotations

import io
import json
import os
import time
from dataclasses import dataclass, replace

import numpy as np

from ..util.errors import ExabricksError

# The matplotlib colour maps the page offers (any other name in a loaded scene works too).
COLORMAPS = ("viridis", "inferno", "magma", "plasma", "cividis", "turbo", "coolwarm", "RdBu_r",
             "YlGnBu", "gray", "Blues", "Reds")
HISTOGRAM_BINS = 64
HISTOGRAM_SAMPLES = 1 << 20  # values per field the histogram looks at, at most
COARSE_FRACTION = 4
COARSE_MIN = 64
MOVING_LOD = 2.0  # --lod while the camera moves, when the page asks for it
# Under --integrator path, each stage between the first full frame and the
# converged one takes this many times the samples of the one before (the
# stages cost 1/(PATH_REFINE - 1) more than the converged frame alone).
PATH_REFINE = 4
MAX_DOC_BYTES = 1 << 20
# Knots the page is shown (and edits, once touched) for a layer whose transfer
# function has none of its own (the automatic one, a preset).
SHOWN_KNOTS = 17
AUTOMATIC_CACHE = 32  # automatic transfer functions kept
# What one change may ask: width x height x spp of its scene (docs/view.md,
# "Bounds"): 1280x800 at 32 spp, 4096x4096 at 2, 32768x1024 at 1.
MAX_SAMPLES = 1 << 25
# Pixels x spp drawn between two looks for a newer change: a frame larger than
# this is drawn in tiles, and a newer change drops it between two tiles.
TILE_SAMPLES = 1 << 16


class Cancelled(Exception):
    """A newer change came (or the page went away): the frame in progress was dropped."""


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
        self._automatic = {}  # automatic transfer functions as inline presets, by spec
        start = self.renderer.scene(scene, **(options or {}))
        self.meshes = {m.path for m in start.meshes}  # the only files a page may name
        self.doc = page_document(start, options or {}, scene)
        self.check(self.doc)
        self.budget, self.device = budget, device
        if budget is not None and dataset.paths is None:
            raise ExabricksError("--memory-budget: reads the structures from files by parts: view "
                                 "a source through the cache (not --no-cache)")
        self._domains = None  # (fields, size, Budgeted) under a memory budget

    @property
    def inputs(self) -> list:
        """The files no save of the viewer may replace: the dataset's and the meshes'."""
        return [*self.renderer.dataset.inputs, *self.meshes]

    def release(self) -> None:
        """Free the dataset's copy on the device and a budget's domains there; the
        next frame uploads them again."""
        self.renderer.release()
        self._domains = None

    def check(self, doc) -> object:
        """The eb.Scene of a document from the page, or ExabricksError (one line)."""
        if not isinstance(doc, dict):
            raise ExabricksError("scene: expected a scene object")
        if len(json.dumps(doc)) > MAX_DOC_BYTES:
            raise ExabricksError(f"scene: larger than {MAX_DOC_BYTES} bytes")
        _no_files(doc, self.meshes)
        scene = self.renderer.scene(self._builtin_presets(self._resolved(doc)))
        s = scene.settings
        asked = int(s.width) * int(s.height) * int(s.spp)
        if asked > MAX_SAMPLES:
            raise ExabricksError(f"scene: {s.width}x{s.height} at {s.spp} spp is {asked} samples; the viewer "
                                 f"draws at most {MAX_SAMPLES} (width x height x spp) per change: "
                                 "draw a larger frame with `exabricks render`")
        return scene

    def _builtin_presets(self, doc: dict) -> dict:
        """`doc` with each volume layer that names a built-in preset given as the
        inline preset that name stands for, stretched over the layer's range (what
        `--transfer-function NAME` draws): the scene builder would look for a file
        of that name first (relative to the working directory, for a scene object),
        and no string from a page is ever opened as a path."""
        from ..scene import choose_transfer_function
        from ..picture.transfer_function import builtin_presets

        volumes = doc.get("volumes")
        if not isinstance(volumes, list):
            return doc
        bricks = self.renderer.dataset.bricks
        out = []
        for i, entry in enumerate(volumes):
            tf = entry.get("transfer_function") if isinstance(entry, dict) else None
            if not isinstance(tf, str):
                out.append(entry)
                continue
            if tf not in builtin_presets():  # _no_files refused it already
                raise ExabricksError(f"scene: volumes[{i}].transfer_function: not a built-in preset")
            field, value_range, scale = entry.get("field"), entry.get("range"), entry.get("scale")
            if field not in bricks.fields:
                raise ExabricksError(f"scene: volumes[{i}].field: expected one of {', '.join(bricks.fields)}")
            try:
                made = choose_transfer_function(bricks, field, tf, value_range=value_range, scale=scale,
                                                builtin=True)
            except (TypeError, ValueError) as e:
                raise ExabricksError(f"scene: volumes[{i}]: {e}") from None
            except ExabricksError as e:
                raise ExabricksError(f"scene: volumes[{i}]: {e}") from None
            out.append({k: v for k, v in entry.items() if k not in ("transfer_function", "range", "scale")}
                       | {"transfer_function": made.to_paraview_dict()})
        return {**doc, "volumes": out}

    def _resolved(self, doc: dict) -> dict:
        """`doc` with each automatic layer (`{"colormap": NAME}`, no opacity) given as
        the inline preset of its automatic transfer function, computed once per spec:
        the same function, read back exactly (scene_to_dict's contract), without
        the histogram and column sums behind it on every frame of a drag."""
        from ..scene import choose_transfer_function

        volumes = doc.get("volumes")
        if not isinstance(volumes, list) or not volumes:
            return doc
        bricks = self.renderer.dataset.bricks
        out = []
        for entry in volumes:
            spec = _automatic_spec(entry, bricks.fields)
            preset = None if spec is None else self._automatic.get(json.dumps(spec))
            if spec is not None and preset is None:
                field, colormap, value_range, scale = spec
                try:
                    tf = choose_transfer_function(bricks, field, colormap=colormap,
                                                  value_range=value_range, scale=scale)
                except (ExabricksError, TypeError, ValueError):
                    pass  # left as it is: the scene's own checks say what is wrong
                else:
                    preset = tf.to_paraview_dict()
                    while len(self._automatic) >= AUTOMATIC_CACHE:
                        self._automatic.pop(next(iter(self._automatic)), None)
                    self._automatic[json.dumps(spec)] = preset
            out.append(entry if preset is None else {"field": entry["field"], "transfer_function": preset})
        return {**doc, "volumes": out}

    def layer(self, scene) -> dict | None:
        """The first volume layer as the page shows it: its field, the range and
        scale its knots span (the colours' span, which holds all but a sliver of the
        automatic function's opacity), and SHOWN_KNOTS opacity knots evenly over that range
        on that scale (what `{"colormap", "opacity"}` over the range reads back as):
        for a layer without knots of its own, what the editor shows and starts from."""
        from ..picture.scaling import inverse, scaled_range

        if not scene.volumes:
            return None
        layer = scene.volumes[0]
        tf = layer.transfer_function
        lo, hi = float(tf.rgb_points[0, 0]), float(tf.rgb_points[-1, 0])  # the colours' span
        scale, threshold = tf.scale, tf.threshold
        try:
            a, b = scaled_range((lo, hi), scale, threshold)
        except ExabricksError:
            scale, (a, b) = "linear", (lo, hi if hi > lo else lo + 1.0)
        at = inverse(np.linspace(a, b, SHOWN_KNOTS), scale, threshold)
        alpha = np.interp(at, tf.alpha_points[:, 0], tf.alpha_points[:, 1])
        return _finite({"field": layer.field, "range": [lo, hi], "scale": scale,
                        "opacity": [round(float(x), 4) for x in alpha]})

    def info(self) -> dict:
        """What the page needs at the start: the document, the fields with their ranges,
        histograms and suggested iso-values (exabricks.picture.auto_transfer.suggested_iso_value:
        "Add iso-surface" starts there), the colour maps, the integrators and the
        data's bounds."""
        from ..picture.auto_transfer import suggested_iso_value
        from ..scene.modes import INTEGRATORS

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
            try:
                iso = suggested_iso_value(bricks, name)
            except (ExabricksError, ValueError):
                iso = None
            if iso is not None and np.isfinite(iso):
                fields[name]["iso"] = iso
        lo, hi = self.renderer.dataset.bounds
        return {"type": "init", "scene": self.doc, "fields": fields, "colormaps": list(COLORMAPS),
                "integrators": list(INTEGRATORS), "bounds": [list(lo), list(hi)]}

    def stages(self, scene, moving: bool = False) -> list[tuple[str, object]]:
        """(stage, scene) to draw, coarse to converged."""
        s = scene.settings
        w = max(min(COARSE_MIN, s.width), s.width // COARSE_FRACTION)
        h = max(1, round(s.height * w / s.width))
        coarse = replace(s, width=w, height=h, spp=1, depth=False,
                         lod=max(s.lod, MOVING_LOD) if moving and _takes_lod(scene) else s.lod)
        out = [("coarse", scene.replace(settings=coarse))]
        if not moving:
            if s.spp > 1:
                out.append(("full", scene.replace(settings=replace(s, spp=1, depth=False))))
            # a path-traced frame refines in sight: PATH_REFINE times the samples a stage
            spp, path = PATH_REFINE, scene.lighting.integrator == "path"
            while path and spp < s.spp:
                out.append((f"{spp} spp", scene.replace(settings=replace(s, spp=spp, depth=False))))
                spp *= PATH_REFINE
            out.append(("converged", scene.replace(settings=replace(s, depth=False))))
        return out

    def draw(self, stage: str, scene, cancelled=None) -> Frame:
        """One stage's frame as PNG bytes: the pixels `render -o frame.png` writes of
        the same scene (composited over its opaque backdrop, exabricks.film.image_io), or
        `Image.shown()` of a --transparent scene's. `cancelled()`, looked at between
        the tiles of a frame larger than TILE_SAMPLES (under a memory budget, also
        between its domains and samples), raises Cancelled when true."""
        from PIL import Image as PILImage

        from ..film.annotate import png_backdrop
        from ..film.image_io import to_png_pixels

        started = time.perf_counter()
        s = scene.settings
        if self.budget is not None:
            image = self._budgeted(scene, cancelled)
        elif cancelled is None or int(s.width) * int(s.height) * int(s.spp) <= TILE_SAMPLES:
            image = self.renderer.render(scene)
        else:
            image = self._tiled(scene, cancelled)
        if cancelled is not None and cancelled():
            raise Cancelled
        backdrop = png_backdrop(scene)
        pixels = image.shown() if backdrop is None else to_png_pixels(image.rgba, backdrop)[..., :3]
        out = io.BytesIO()
        PILImage.fromarray(np.ascontiguousarray(pixels), "RGB").save(out, format="PNG", compress_level=1)
        st = image.metadata.get("settings", {})
        return Frame(out.getvalue(), stage, scene.settings.width, scene.settings.height,
                     scene.settings.spp, (time.perf_counter() - started) * 1e3,
                     float(st.get("samples_per_second", 0.0)), str(st.get("device", "")))

    def _tiled(self, scene, cancelled):
        """The frame drawn tile by tile (each tile's radiance the very pixels the
        whole frame has there, Renderer.integrate's `window`), then developed by the
        film once, whole (its denoiser sees the whole frame, as `render`'s does: tile
        by tile it left seams), Cancelled between two tiles once `cancelled()` is
        true."""
        from ..film import denoise
        from ..film.film import develop
        from ..film.image import Image
        from ..schema import memory_limit

        s = scene.settings
        width, height, spp = int(s.width), int(s.height), int(s.spp)
        limit = memory_limit()
        if limit is not None and width * height * 16 > limit:
            raise ExabricksError(f"scene: a {width}x{height} frame needs more than the memory available")
        if s.denoise:
            denoise.check()  # before the frame, not after
        device = self.renderer._on_device(scene.fields())
        rgba = np.zeros((height, width, 4), np.float32)
        if width * spp <= TILE_SAMPLES:
            tiles = [(0, r, width, min(TILE_SAMPLES // (width * spp), height - r))
                     for r in range(0, height, max(1, TILE_SAMPLES // (width * spp)))]
        else:
            side = max(8, int(np.sqrt(TILE_SAMPLES // spp)) // 8 * 8)
            tiles = [(c, r, min(side, width - c), min(side, height - r))
                     for r in range(0, height, side) for c in range(0, width, side)]
        started, samples, stats = time.perf_counter(), 0, {}
        for c, r, w, h in tiles:
            if cancelled():
                raise Cancelled
            result = device.integrate(scene, window=(c, r, w, h))
            rgba[r:r + h, c:c + w] = result.rgba
            samples += int(result.stats.get("samples", 0))
            stats = result.stats
        if cancelled():  # before the film's work (the denoiser's is a whole frame's)
            raise Cancelled
        stats = dict(stats)
        develop(rgba, scene, stats)
        seconds = time.perf_counter() - started
        stats = {**stats, "width": width, "height": height, "samples": samples, "ms": 1e3 * seconds,
                 "samples_per_second": samples / seconds if seconds > 0 else 0.0}
        return Image(rgba, None, {"settings": stats}, scene=scene)

    def _budgeted(self, scene, cancelled=None):
        """The frame drawn domain by domain within the memory budget, the pixels
        `render --memory-budget` draws (exabricks.engine.streaming); with
        `cancelled`, in tiles of whole columns of at most TILE_SAMPLES pixels (each
        domain drawn once a sample all the same), Cancelled before any tile, domain
        or sample once `cancelled()` is true."""
        from ..engine.streaming import Budgeted, render_steps
        from ..film.image import Image

        stop = tile_width = None
        if cancelled is not None:
            def stop():
                if cancelled():
                    raise Cancelled

            width, height = int(scene.settings.width), int(scene.settings.height)
            if width * height > TILE_SAMPLES:  # each step draws one sample
                tile_width = max(1, TILE_SAMPLES // height)
        key = (scene.fields(), scene.settings.width, scene.settings.height)
        if self._domains is None or self._domains[0] != key:
            paths = self.renderer.dataset.paths
            bricks, regions, _ = self.renderer.dataset.load("data")
            self._domains = (key, Budgeted(bricks, regions, scene, self.budget, device=self.device,
                                           where=tuple(map(str, paths[:2]))))
        result = render_steps(self._domains[1], scene, tile_width=tile_width, stop=stop)
        return Image(result.rgba, None, {"settings": result.stats}, scene=scene)


def key_light(scene) -> list | None:
    """The direction toward the camera's key light that `scene` is lit by, where
    its integrator has a light and it names no direction: the page takes it as
    the scene's own (docs/view.md, "Lights"), so that the light stays fixed in
    the world as the camera moves and the shadow integrator's cached
    transmittance is reused; None otherwise."""
    from ..picture.light import light_direction

    lighting = scene.lighting
    if lighting.integrator == "headlight" or lighting.light is not None:
        return None
    return [float(x) for x in light_direction(scene)]


def _takes_lod(scene) -> bool:
    """Whether the scene's integrator and reconstruction draw with level of detail
    (the feature table's refusals: the path integrator, and the nearest and vertex
    reconstructions, draw at full resolution only)."""
    from ..engine import variants

    return variants.refusal(variants.frame(integrator=scene.lighting.integrator, lod=True,
                                           reconstruction=scene.settings.reconstruction)) is None


def page_document(scene, options: dict, source=None) -> dict:
    """The scene file's object of `scene` (exabricks.scene.scene_to_dict), its first
    volume layer as it was asked for (by the flags in `options`, else by the scene
    file or object `source`), so that the page edits it and draws what `render`
    draws with the same options:

    - a colour map (`--colormap`, `--opacity`, `--range`, `--scale`, or no transfer
      function at all: the automatic one, in viridis) stays that spec, with no
      opacity knots where none were given (the automatic opacity);
    - a preset (`--transfer-function`, a preset file or object) becomes the inline
      preset it was read as."""
    from ..scene import scene_to_dict
    from ..scene.model import DEFAULT_COLORMAP
    from ..scene.options import VOLUME_FLAGS

    doc = scene_to_dict(scene)
    if scene.volumes:
        layer = scene.volumes[0]
        if any(options.get(name) not in (None, ()) for name in VOLUME_FLAGS):
            asked = {"transfer_function": options.get("transfer_function"),
                     "colormap": options.get("colormap"), "opacity": options.get("opacity"),
                     "range": options.get("range"), "scale": options.get("scale")}
        else:
            asked = _first_volume(source)
        if asked.get("transfer_function") is None:
            tf = {"colormap": asked.get("colormap") or DEFAULT_COLORMAP}
            if asked.get("opacity"):
                tf["opacity"] = [float(a) for a in asked["opacity"]]
            entry = {"field": layer.field, "transfer_function": tf}
            if asked.get("range"):
                entry["range"] = [float(x) for x in asked["range"]]
            if asked.get("scale"):
                entry["scale"] = asked["scale"]
            doc["volumes"][0] = entry
    return _finite(doc)


def _first_volume(source) -> dict:
    """What the first volume layer of a scene file or object asks for: its
    transfer_function (None for a colour map or none), colormap, opacity, range
    and scale."""
    from ..scene import read_scene_file

    if source is None:
        return {}
    if isinstance(source, dict):
        doc = source
    elif isinstance(source, (str, os.PathLike)):
        doc = read_scene_file(source)
    else:  # an eb.Scene: its transfer functions as they are
        return {"transfer_function": "inline"}
    volumes = doc.get("volumes") or [{}]
    entry = volumes[0] if isinstance(volumes[0], dict) else {}
    tf = entry.get("transfer_function")
    if isinstance(tf, dict) and "colormap" in tf:
        return {"colormap": tf["colormap"], "opacity": tf.get("opacity"), "range": entry.get("range"),
                "scale": entry.get("scale")}
    return {"transfer_function": tf, "range": entry.get("range"), "scale": entry.get("scale")}


def _automatic_spec(entry, fields):
    """(field, colormap, range, scale) of a volume entry that asks for the automatic
    transfer function (`{"colormap": NAME}` and nothing else), else None."""
    if not isinstance(entry, dict) or not set(entry) <= {"field", "transfer_function", "range", "scale"}:
        return None
    tf, value_range, scale = entry.get("transfer_function"), entry.get("range"), entry.get("scale")
    if not (isinstance(tf, dict) and set(tf) == {"colormap"} and isinstance(tf["colormap"], str)):
        return None
    if entry.get("field") not in fields or not (scale is None or isinstance(scale, str)):
        return None
    if value_range is not None:
        if not (isinstance(value_range, list) and len(value_range) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in value_range)):
            return None
        value_range = [float(x) for x in value_range]
    return entry["field"], tf["colormap"], value_range, scale


def _finite(doc):
    """`doc` with no NaN or infinity (a scene file holds neither)."""
    text = json.dumps(doc, allow_nan=True)
    if "NaN" in text or "Infinity" in text:
        raise ExabricksError("scene: a value is not a finite number")
    return json.loads(text)


def _no_files(doc: dict, meshes=frozenset()) -> None:
    """Refuse what would make the server read a file: a camera file, a preset file, a
    mesh file other than `meshes` (those the viewer was started with)."""
    from ..picture.transfer_function import builtin_presets

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
