"""Frames of data larger than memory, and frames that improve as they go
(docs/design-scale.md, "Rendering under a memory budget"; Wu, Doyle & Ma's streaming
and progressive rendering, seed paper 004).

A frame is drawn as steps: for each of its spp samples, each domain of the
dataset front to back. Under a memory budget the domains are those of a k-d
partition of space (exabricks.engine.partition.budget_partition) whose every
domain, structures and device copies together, fits the budget. A domain is
read from the mapped files (only its pages) when a step needs it, and stays
resident while the budget holds it beside the next one being made: domains
are kept across samples, bands of tiles and frames, and the one given up for a
new one is the one needed again last, in the order the frame will ask for
them (the next frame's order assumed to be this one's; Belady's choice, which
a cyclic sweep needs: a least-recently-used cache would miss every time).
Each domain's rays continue from the image
composited in front of it (kernels/render.cl EB_DOMAIN_ARGS `front`), so early
ray termination carries from domain to domain and the frame equals the
in-memory one up to float rounding. Without a budget the whole dataset is the
one domain (`Resident`).

After every step the image so far is offered to `on_image`: the average of the
samples completed, or, while the first is under way, that sample composited
over the domains drawn so far. A deadline stops the frame after the step (or
the band of rows, kernels being enqueued by bands) that passes it; the result
then says what it covers (`progress` in its stats).
"""

from __future__ import annotations

import gc
import threading
import time
from collections import deque

import numpy as np

from ..device import opencl
from ..device.kernel_abi import float4_box
from .. import schema
from ..formats.memory import mapping
from ..util.errors import ExabricksError
from .device_data import DatasetScale
from .domains import GRAIN, domain_data, domain_options, region_blocks
from .partition import budget_partition, eye_lattice, mib, needs_image_mode
from ..film.film import develop
from .renderer import Renderer, RenderResult
from .look import table_bytes
from . import light_volume
from .budget_bytes import HELD, SLACK, fixed_bytes, image_bytes, light_bytes

class Resident:
    """The whole dataset as one resident domain (an exabricks.engine.renderer.Renderer)."""

    def __init__(self, renderer: Renderer):
        self.renderer = renderer
        self.n_domains = 1
        self.samples_per_read = 1

    def order(self, scene) -> list[int]:
        return [0]

    def expect(self, indices) -> None:
        pass

    def domain(self, index: int, scene) -> Renderer:
        return self.renderer

    def footprint(self, index: int, scene):
        return 0, 0, int(scene.settings.width), int(scene.settings.height)


class Budgeted:
    """The domains of a dataset (mapped, schema.load(mapped=True)) that each fit
    `budget` bytes with the images of `scene` (SLACK, PER_BRICK), kept resident
    while the budget holds them (module docstring). `prefetch`: make the next
    domain on a thread while the one before it draws (the domains are then
    planned smaller, so that the budget holds both); default on devices that
    are not CPUs. `where`: the two files' names for errors."""

    def __init__(self, bricks: schema.Bricks, regions: schema.Regions, scene, budget: int, *,
                 device=None, where=("the bricks", "the regions"), tile=None, prefetch=None):
        self.bricks, self.regions, self.device, self.where = bricks, regions, device, where
        self.budget, self.tile = int(budget), tile
        # where samples can be, in lattice units: the bricks' cells and half a
        # coarsest cell around them (the support of the basis reconstruction)
        lo, hi = (np.asarray(b, np.float64) for b in schema.world_bounds(bricks))
        self.world_box = (lo, hi)
        margin = float(2.0 ** int(bricks.level.max())) if bricks.n_bricks else 0.0
        self.data_box = (eye_lattice(bricks, lo) - margin, eye_lattice(bricks, hi) + margin)
        schema.release(bricks)
        self.fields = scene.fields()
        self.scale = DatasetScale.of(bricks, self.fields)
        self.blocks = region_blocks(regions)
        self._cache = {}  # domain index -> Renderer, least recently used first
        self._last = self._pending = None  # the domain last asked for; one being prefetched
        self._future, self._cycle = deque(), []  # the domains the frame will ask for next
        if prefetch is None:  # where the host is idle while the device draws
            prefetch = not opencl.is_cpu(opencl.choose_device(device))
        self.prefetch = bool(prefetch)
        self.reads = self.prefetched = 0  # domains made so far, and of them on a thread
        self._plan(scene)

    def _plan(self, scene) -> None:
        options = domain_options(self.bricks, scene)
        # a step of reads from a mapped file brings in one GRAIN-aligned window of
        # folios for the first field and at most two for each other one
        # (partition._copy_parts)
        reads = 0
        if mapping(self.bricks.values) is not None:
            reads = min(GRAIN * (2 * len(self.fields) - 1), self.bricks.values.nbytes)
        # the samples a domain draws while it is resident, each with its own image
        # (render_steps without a deadline or images so far): as many as a quarter
        # of the budget holds, so that a frame of spp samples reads each domain
        # ceil(spp / that) times instead of spp times
        frame = image_bytes(scene, self.tile) // 4
        self.samples_per_read = int(min(scene.settings.spp, 1 + (self.budget // 4) // max(frame, 1)))
        self.tables = table_bytes(scene)
        self.light_bytes = light_bytes(scene, self.budget)
        fixed = (fixed_bytes(scene, self.bricks.n_bricks, self.tile, self.budget)
                 + (self.samples_per_read - 1) * frame + reads)
        # a domain being made takes SLACK times its bytes; one made on a thread while
        # the one before it draws (prefetch) takes that beside the one drawing
        room = int((self.budget - fixed) / (SLACK + HELD if self.prefetch else SLACK))
        if room <= 0:
            raise ExabricksError(
                f"a memory budget of {mib(self.budget)} leaves nothing for the data besides "
                f"{mib(fixed)} of images, transfer-function tables, indices over the "
                f"dataset's {self.bricks.n_bricks:,} bricks and reads from its files"
                + (", and the light's cached transmittance" if self.light_bytes else ""))
        self.options, self.room, self.capacity = options, room, self.budget - fixed
        self._settle()
        self._cache.clear()
        self.partition = budget_partition(self.bricks, self.regions, room, fields=self.fields,
                                          where=self.where, grid_bytes=self.budget // 4,
                                          blocks=self.blocks, **options)
        self.n_domains = self.partition.n_domains
        # the shadow integrator's transmittance, one for every domain (light_volume)
        self.light = light_volume.Cache(max_bytes=self.light_bytes or 4 * light_volume.MAX_NODES)
        if self.n_domains > 1:
            reason = needs_image_mode(scene)
            if reason:
                raise ExabricksError(
                    f"{reason} need the whole dataset at once, but a memory budget of "
                    f"{mib(self.budget)} holds it in {self.n_domains} domains only: "
                    "raise the budget or leave them out")

    def order(self, scene) -> list[int]:
        """The domains front to back for `scene`'s frame, every domain's part of its
        cached transmittance toward the light made (`light`)."""
        if (domain_options(self.bricks, scene) != self.options or set(scene.fields()) - set(self.fields)
                or table_bytes(scene) > self.tables or light_bytes(scene, self.budget) > self.light_bytes):
            self.fields = scene.fields()
            self.scale = DatasetScale.of(self.bricks, self.fields)
            self._plan(scene)
        order = self.partition.visibility_order(eye_lattice(self.bricks, scene.camera.position))
        self.light_all(scene, order)
        return order

    def light_all(self, scene, order) -> None:
        """Under the shadow integrator, have every domain add its part to the
        transmittance toward the light that they share (light_volume), in `order`,
        unless it holds them all already: the first domain finds whether the
        light, the look or the clipping changed."""
        if self.n_domains == 1 or not light_volume.cached(scene):
            return
        parts = [light_volume.part(float4_box((self.partition.lower[i], self.partition.upper[i])), None)
                 for i in range(self.n_domains)]
        self.light.box = light_volume.seen_box(self.regions, self.bricks.field_index, scene.volumes) \
            or self.world_box
        for index in order:
            self.domain(index, scene).light(scene)
            if self.light.holds(parts):
                return
        raise ExabricksError("the domains of a memory budget disagree on the light's transmittance")

    def footprint(self, index: int, scene):
        """Pixels (col0, row0, col1, row1) that domain `index` can draw (Camera.footprint)."""
        lo = np.maximum(self.partition.lower[index], self.data_box[0])
        hi = np.minimum(self.partition.upper[index], self.data_box[1])
        if (lo >= hi).any():
            return None
        world = lambda x: self.bricks.origin_world + self.bricks.spacing_world * x
        s = scene.settings
        return scene.camera.footprint(world(lo), world(hi), int(s.width), int(s.height))

    def expect(self, indices) -> None:
        """The domains that the steps to come will ask for, in order (repeats of the
        same domain in a row counted once); after them, the same again."""
        self._future = deque(_runs(indices))
        self._cycle = list(self._future)

    def domain(self, index: int, scene) -> Renderer:
        if index == self._last and index in self._cache:  # its next tile or sample
            return self._cache[index]
        self._advance(index)
        self._settle()
        renderer = self._cache.pop(index, None)
        if renderer is None:
            self._make_room(SLACK * self._bytes(index))
            renderer = self._make(index)
        self._cache[index], self._last = renderer, index  # the most recently used
        if self.prefetch:
            self._prefetch()
        return renderer

    def _bytes(self, index: int) -> int:
        return int(self.partition.nbytes[index])

    def _held(self) -> int:
        """What the resident domains count for beside one being made (HELD)."""
        return HELD * sum(self._bytes(i) for i in self._cache)

    def _make(self, index: int) -> Renderer:
        """Read domain `index` from the files and upload it."""
        self.reads += 1
        box = (self.partition.lower[index], self.partition.upper[index])
        data = domain_data(self.bricks, self.regions, *box, fields=self.fields, where=self.where,
                           blocks=self.blocks, touch=self.room // 4, **self.options)
        for whole in (self.bricks, self.regions):
            schema.release(whole)
        return Renderer(*data, fields=self.fields, device=self.device,
                        domain=box if self.n_domains > 1 else None, scale=self.scale,
                        light=self.light)

    def _prefetch(self) -> None:
        """Make the next domain expected, on a thread while the current one draws,
        where the budget holds it (SLACK times its bytes while it is made) beside
        every resident domain."""
        following = next((i for i in self._future if i not in self._cache), None)
        if following is None or self._held() + SLACK * self._bytes(following) > self.capacity:
            return
        made = {}

        def make():
            try:
                made["renderer"] = self._make(following)
            except BaseException as error:  # raised when the domain is asked for
                made["error"] = error

        thread = threading.Thread(target=make, name="exabricks-prefetch", daemon=True)
        thread.start()
        self._pending = (following, thread, made)
        self.prefetched += 1

    def _settle(self) -> None:
        """Wait for the domain being prefetched: resident if it was made; an error
        making it comes again when that domain is asked for."""
        if self._pending is None:
            return
        index, thread, made = self._pending
        self._pending = None
        thread.join()
        if "renderer" in made:  # resident, not yet used
            self._cache = {index: made["renderer"], **self._cache}
        else:
            self.reads -= 1  # made again when asked for
            self.prefetched -= 1

    def _advance(self, index: int) -> None:
        """`index` is asked for now: the expected order moves past it."""
        if index in self._future:
            while self._future.popleft() != index:
                pass
        if not self._future:
            self._future.extend(self._cycle)

    def _make_room(self, making: float) -> None:
        """Give up resident domains until the rest and `making` bytes (a domain
        being made) fit the budget: first those not expected again, then the
        one expected last; among equals the least recently used."""
        held, gone = self._held(), False
        if self._cache and held + making > self.capacity:
            future = list(self._future) + self._cycle  # and after it, the same order again
            next_use = {}
            for at, index in enumerate(future):
                next_use.setdefault(index, at)
        while self._cache and held + making > self.capacity:
            # the first of equals: least recent
            victim = max(self._cache, key=lambda i: next_use.get(i, len(future)))
            held -= HELD * self._bytes(victim)
            del self._cache[victim]
            gone = True
        if gone or not self._cache:
            gc.collect()
        schema.trim_heap()


def render_steps(domains, scene, *, band=None, tile_width=None, deadline: float | None = None,
                 on_image=None, stop=None) -> RenderResult:
    """One frame of `scene` from `domains` (Resident or Budgeted) step by step
    (module docstring). `on_image(rgba, progress)` is called after every step
    but the last with the image so far (developed by the film) and
    what it covers; `deadline` (time.perf_counter() seconds) ends the frame
    early. stats["progress"]: samples and domains done, complete or not.

    `band` (first row, rows): draw only those rows of the frame, in tiles of
    `tile_width` columns (render_tiled; no deadline or on_image then); the
    result is the band. A domain is read only when its footprint on the screen
    meets a tile, and then draws only the tiles it meets. Without `band`,
    `tile_width` draws the whole frame in tiles of that many columns, every
    domain only once for each sample (or samples_per_read samples) all the same.

    `stop()`, called before every tile of every domain and sample (and before a
    domain is read), ends the frame by raising (the viewer's Cancelled: a newer
    change came): a frame is dropped within one tile's drawing."""
    cfg = scene.settings
    spp, width, height = int(cfg.spp), int(cfg.width), int(cfg.height)
    row0, rows = (0, height) if band is None else (int(band[0]), int(band[1]))
    tiles = _band_tiles(width, row0, rows, tile_width)
    whole = tiles == [(0, 0, width, height)]
    if not whole and (deadline is not None or on_image is not None):
        raise ExabricksError("a band of tiles is drawn whole: no deadline or image so far")
    total = np.zeros((rows, width, 4), np.float32)
    order = domains.order(scene)
    several = domains.n_domains > 1
    meets = _meets(domains, scene, order, tiles)
    start = time.perf_counter()
    samples, stats, done_samples, done_domains, drawn = 0, {}, 0, 0, rows
    depth = over = None
    group = domains.samples_per_read if deadline is None and on_image is None else 1
    if band is None:  # render_tiled expects a band's domains for the whole frame
        domains.expect([i for i in order if meets[i]] * -(-spp // group))
    if several and group > 1:
        for first in range(0, spp, group):
            over, stats, n = _group(domains, scene, order, meets, whole, rows, width,
                                    range(first, min(spp, first + group)), total, stop)
            samples += n
        done_samples, done_domains, drawn = spp, len(order), rows
    for sample in range(done_samples, spp):
        if sample and deadline is not None and time.perf_counter() > deadline:
            break
        over = None
        for k, index in enumerate(order):
            if k and deadline is not None and time.perf_counter() > deadline:
                break
            for tile in meets[index]:
                if stop is not None:
                    stop()
                c, _, w, _ = tile
                front = None
                if several and over is not None:
                    front = over if whole else np.ascontiguousarray(over[:, c:c + w])
                result = domains.domain(index, scene).integrate(
                    scene, window=None if whole else tile, sample=sample if spp > 1 else None,
                    front=front, deadline=deadline)
                stats = dict(result.stats)
                if whole:
                    over = result.rgba
                else:
                    if over is None:
                        over = np.zeros((rows, width, 4), np.float32)
                    over[:, c:c + w] = result.rgba
                if result.depth is not None:  # one domain only (Budgeted refuses more)
                    if depth is None:
                        depth = np.full((rows, width), np.inf, np.float32)
                    np.minimum(depth[:, c:c + w], result.depth, out=depth[:, c:c + w])
                samples += stats["samples"]
                drawn = stats["rows"]
            if drawn < rows:
                break
            done_domains = k + 1
            if on_image is not None and (sample, k) != (spp - 1, len(order) - 1):
                on_image(*_so_far(total, over, sample, done_domains, len(order), spp, scene))
        if done_domains == len(order) and drawn == rows:
            if over is not None:
                total += over
            done_samples = sample + 1
            done_domains = 0 if done_samples < spp else len(order)
        if done_samples < sample + 1:
            break
    film = {}
    rgba, progress = _so_far(total, over, done_samples, done_domains, len(order), spp, scene,
                             rows=drawn, stats=film)
    if depth is None and cfg.depth:
        depth = np.full((rows, width), np.inf, np.float32)
    seconds = time.perf_counter() - start
    if not stats and band is not None:  # nothing here: render_tiled fills the settings in
        return RenderResult(rgba, depth, {"samples": 0})
    if not stats:
        stats = _settings(domains, order, scene)
    _frame_stats(stats, domains, samples, seconds, done_samples, progress)
    return RenderResult(rgba, depth, {**stats, **film})


def _frame_stats(stats: dict, domains, samples: int, seconds: float, done_samples: int,
                 progress: dict) -> None:
    """A streamed frame's stats, from its last domain's (`stats`, in place): the
    frame's samples, times, pieces, progress and reads, no domain's regions."""
    if domains.n_domains > 1:
        for key in ("regions", "visible_regions"):  # the last domain's only
            stats.pop(key, None)
    stats.pop("rows", None)
    stats.update(samples=samples, ms=1e3 * seconds, ms_per_sample=1e3 * seconds / max(done_samples, 1),
                 samples_per_second=samples / seconds if seconds > 0 else 0.0,
                 pieces=domains.n_domains, progress=progress)
    if isinstance(domains, Budgeted):
        stats["memory_budget"] = domains.budget
        stats["domain_reads"] = domains.reads
        if domains.prefetch:
            stats["domains_prefetched"] = domains.prefetched


def _group(domains, scene, order, meets, whole, rows, width, group, total, stop=None):
    """The samples `group` of a frame drawn domain after domain, each domain made
    once for all of them (its rays of each sample continuing that sample's image
    in front), their images added into `total`: (the last sample's image, the
    last stats, samples taken); `stop()` before every tile of every sample
    (render_steps). No depth: a depth frame has one domain."""
    overs = dict.fromkeys(group)
    stats, samples = {}, 0
    for index in order:
        for tile in meets[index]:
            c, _, w, _ = tile
            for sample in group:
                if stop is not None:
                    stop()
                over = overs[sample]
                front = None if over is None else (over if whole else np.ascontiguousarray(over[:, c:c + w]))
                result = domains.domain(index, scene).integrate(
                    scene, window=None if whole else tile, sample=sample, front=front)
                stats = dict(result.stats)
                samples += stats["samples"]
                if whole:
                    overs[sample] = result.rgba
                else:
                    if over is None:
                        overs[sample] = over = np.zeros((rows, width, 4), np.float32)
                    over[:, c:c + w] = result.rgba
    for over in overs.values():
        if over is not None:
            total += over
    return overs[group[-1]], stats, samples


def _runs(indices) -> list:
    """`indices` with each run of one index in a row counted once."""
    return [i for k, i in enumerate(indices) if k == 0 or indices[k - 1] != i]


def _band_tiles(width: int, row0: int, rows: int, tile_width=None) -> list:
    """The tiles (col0, row0, cols, rows) of a band of rows: `tile_width` columns each,
    or the band whole."""
    step = width if tile_width is None else int(tile_width)
    return [(c, row0, min(step, width - c), rows) for c in range(0, width, step)]


def _meets(domains, scene, order, tiles) -> dict:
    """{domain: the tiles it can draw into}."""
    return {index: _tiles_met(tiles, domains.footprint(index, scene)) for index in order}


def _tiles_met(tiles, rect) -> list:
    """The tiles (col0, row0, cols, rows) that the pixel rectangle `rect` (col0,
    row0, col1, row1; None: nothing) meets."""
    if rect is None:
        return []
    c0, r0, c1, r1 = rect
    return [t for t in tiles if t[0] < c1 and c0 < t[0] + t[2] and t[1] < r1 and r0 < t[1] + t[3]]


def render_tiled(domains, scene, tile, put, *, deadline: float | None = None,
                 on_band=None) -> dict:
    """One frame of `scene` from `domains` in tiles of `tile` (W, H) pixels, a row
    of tiles at a time: each band of H rows is drawn whole (every sample, every
    domain that meets it front to back) and handed to `put(row0, rgba, depth)`
    top to bottom, so that only a band is ever in memory. `on_band(progress)`
    follows each band but the last; `deadline` stops after the band that passes
    it. Returns the frame's stats (progress: rows [done, height]). The automatic
    exposure, which no band can meter alone, is metered first on a preview of
    the whole frame (`metered_scene`)."""
    scene, film = metered_scene(domains, scene)
    width, height = int(scene.settings.width), int(scene.settings.height)
    tile_w, tile_h = min(int(tile[0]), width), min(int(tile[1]), height)
    order = domains.order(scene)
    group = domains.samples_per_read
    expected = []
    for row0 in range(0, height, tile_h):
        meets = _meets(domains, scene, order, _band_tiles(width, row0, min(tile_h, height - row0), tile_w))
        expected += [i for i in order if meets[i]] * -(-int(scene.settings.spp) // group)
    domains.expect(expected)
    start = time.perf_counter()
    stats, samples, done = {}, 0, 0
    for row0 in range(0, height, tile_h):
        if row0 and deadline is not None and time.perf_counter() > deadline:
            break
        rows = min(tile_h, height - row0)
        result = render_steps(domains, scene, band=(row0, rows), tile_width=tile_w)
        put(row0, result.rgba, result.depth)
        samples += result.stats["samples"]
        stats = result.stats if len(result.stats) > 1 else stats
        done = row0 + rows
        if on_band is not None and done < height:
            on_band(_tiled_progress(scene, domains, done))
    seconds = time.perf_counter() - start
    if not stats:  # nothing in view
        stats = _settings(domains, domains.order(scene), scene)
    stats.update(samples=samples, ms=1e3 * seconds,
                 samples_per_second=samples / seconds if seconds > 0 else 0.0,
                 tile=[tile_w, tile_h], progress=_tiled_progress(scene, domains, done), **film)
    return stats


# The longer side of the preview that metered_scene measures.
PREVIEW_PIXELS = 256


def metered_scene(domains, scene):
    """(`scene` with its automatic exposure measured and made fixed, the film's
    figures): where settings.auto_exposure is on, the stops metered on a preview
    of the whole frame at most PREVIEW_PIXELS a side (one sample, no background)
    are added to settings.exposure and the automatic exposure turned off, so
    that the bands of a tiled frame share one exposure."""
    from dataclasses import replace

    from ..film.exposure import fixed_exposure, metered_stops

    s = scene.settings
    if not s.auto_exposure:
        return scene, {}
    shrink = min(1.0, PREVIEW_PIXELS / max(s.width, s.height))
    preview = scene.replace(background=(0.0, 0.0, 0.0, 0.0), settings=replace(
        s, width=max(1, round(s.width * shrink)), height=max(1, round(s.height * shrink)),
        spp=1, exposure=0.0, auto_exposure=False, denoise=False, depth=False))
    stops = metered_stops(render_steps(domains, preview).rgba)
    return fixed_exposure(scene, stops), {"metered_exposure": stops}


def _tiled_progress(scene, domains, done: int) -> dict:
    spp, n, height = int(scene.settings.spp), domains.n_domains, int(scene.settings.height)
    return {"complete": done == height, "samples": [spp, spp], "pieces": [n, n],
            "rows": [done, height]}


def _settings(domains, order, scene) -> dict:
    """The stats of a frame of `scene` that draws nothing (none of its domains is
    in view): those of the first domain drawing no row (its deadline passed)."""
    return dict(domains.domain(order[0], scene).integrate(scene, window=(0, 0, 1, 1),
                                                        deadline=0.0).stats)


def _so_far(total, over, samples_done, domains_done, n_domains, spp, scene, rows=None,
            stats=None):
    """(image developed by the film, progress): the average of the samples done,
    or while none is, the first sample's composite of the domains done; the
    film's figures into `stats`."""
    if samples_done:
        rgba = total / np.float32(samples_done)
    elif over is not None:
        rgba = over.copy()
    else:
        rgba = np.zeros_like(total)
    complete = samples_done == spp
    progress = {"complete": complete, "samples": [samples_done, spp],
                "pieces": [n_domains if complete else domains_done, n_domains]}
    if not complete and rows is not None and 0 < rows < total.shape[0] and not samples_done:
        progress["rows"] = rows
    return develop(rgba, scene, stats), progress
