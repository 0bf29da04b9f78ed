"""Statistics of a field over the bricks, in bounded memory: its finite range,
and the volume-weighted sums that the defaults read (exabricks.picture.auto_transfer,
exabricks.picture.framing): a histogram of its scaled values, and where its opacity
lies, along axes and over columns of a view.

The sums walk the bricks a run of whole bricks (about CHUNK values) at a time
in small jitted loops that allocate nothing per cell, handing back the pages
of mapped values after each run, so that they hold to a render's memory budget
(docs/design-scale.md, "Rendering under a memory budget") on any dataset size.
A cell of level l weighs its lattice volume 8**l.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..util.errors import ExabricksError
from ..util import numba_compiles

numba_compiles.announce()  # its first compile on a machine says so on a terminal

# Scales by code in the jitted loops (exabricks.picture.scaling.SCALES less "auto").
SCALE_CODES = {"linear": 0, "log": 1, "symlog": 2}
POWER = 1


def _runs(bricks, field: str):
    """(values of the field (V,), first brick, end brick) of runs of whole bricks
    of about CHUNK values; a mapped run's pages are handed back after it."""
    from ..formats.memory import CHUNK, discard, mapping

    values = bricks.values[bricks.field_index(field)]
    counts = np.prod(bricks.dims.astype(np.int64), axis=1)
    ends = np.cumsum(counts)
    start = 0
    while start < bricks.n_bricks:
        before = ends[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, before + CHUNK, side="right")))
        yield values, start, stop
        if mapping(values) is not None:
            first = int(bricks.offset[start])
            discard(values[first:first + int(ends[stop - 1] - before)])
        start = stop


def _bricks(bricks):
    """The per-brick arrays the loops take, as int64."""
    return (bricks.lower_lattice.astype(np.int64), bricks.level.astype(np.int64),
            bricks.dims.astype(np.int64), bricks.offset.astype(np.int64))


def volume_histogram(bricks, field: str, scale: str, threshold: float, axis_range,
                     bins: int) -> np.ndarray:
    """(bins,) float64: the lattice volume of the cells of `field` whose scaled
    value (exabricks.picture.scaling) falls in each of `bins` even bins over
    `axis_range` (beyond it: the end bins; log of a value <= 0: the first bin;
    non-finite values: none)."""
    out = np.zeros(bins)
    _, level, dims, offset = _bricks(bricks)
    a, b = (float(x) for x in axis_range)
    for values, start, stop in _runs(bricks, field):
        _histogram(values, level, dims, offset, start, stop, SCALE_CODES[scale], float(threshold),
                   a, b, out)
    return out


def steepness_histogram(bricks, field: str, scale: str, threshold: float, axis_range,
                        bins: int) -> np.ndarray:
    """(bins,) float64: over `bins` even bins of `axis_range` on the scaled axis,
    how much iso-surface each value has, weighted by how steeply the field
    crosses it. Every two neighbouring cells of a brick (a face of width w
    lattice units between them) whose scaled values s1 < s2 are crossed by the
    iso-surface of every value in [s1, s2], on a face of area w**2 with the
    gradient (s2 - s1) / w: each bin they span gets w * (s2 - s1). So a value
    is scored by its surface's area times its mean steepness, and a level that
    many cells hold exactly (a plateau, whose own cells cross nothing) scores no
    more than the values its edges step to (exabricks.picture.auto_transfer.
    suggested_iso_value). Pairs with a non-finite value count for nothing."""
    steps = np.zeros(bins + 1)
    _, level, dims, offset = _bricks(bricks)
    a, b = (float(x) for x in axis_range)
    for values, start, stop in _runs(bricks, field):
        _crossings(values, level, dims, offset, start, stop, SCALE_CODES[scale], float(threshold),
                   a, b, steps)
    return np.cumsum(steps[:-1])


@numba.njit(cache=True, nogil=True)
def _crossings(values, level, dims, offset, start, stop, code, threshold, a, b, steps):
    bins = steps.shape[0] - 1
    per = bins / (b - a)
    for brick in range(start, stop):
        width = float(1 << level[brick])
        nx, ny, nz = dims[brick, 0], dims[brick, 1], dims[brick, 2]
        first = offset[brick]
        for z in range(nz):
            for y in range(ny):
                for x in range(nx):
                    i = first + x + nx * (y + ny * z)
                    here = _scaled(float(values[i]), code, threshold)
                    if not math.isfinite(here):
                        continue
                    for axis in range(3):
                        if (x, y, z)[axis] + 1 >= (nx, ny, nz)[axis]:
                            continue
                        there = _scaled(float(values[i + (1, nx, nx * ny)[axis]]), code, threshold)
                        if not math.isfinite(there) or there == here:
                            continue
                        s1, s2 = min(here, there), max(here, there)
                        k1 = 0 if not s1 > a else min(int((s1 - a) * per), bins - 1)
                        k2 = 0 if not s2 > a else min(int((s2 - a) * per), bins - 1)
                        steps[k1] += width * (s2 - s1)
                        steps[k2 + 1] -= width * (s2 - s1)


def opacity_along(bricks, field: str, transfer_function, axes, lower, span, bins: int) -> np.ndarray:
    """(3, bins) float64: the opacity (`transfer_function`'s alpha x lattice
    volume) of `field` by where its cell centres lie along each row of `axes`
    ((3, 3) world directions): bin i of row k covers world positions
    ``lower[k] + span[k] * [i, i + 1) / bins`` along it."""
    out = np.zeros((3, bins))
    xs, alpha = _alpha(transfer_function)
    world = _world(bricks, np.asarray(axes, np.float64))
    for values, start, stop in _runs(bricks, field):
        _along(values, *_bricks(bricks), start, stop, xs, alpha, *world,
               np.asarray(lower, np.float64), np.asarray(span, np.float64), out)
    return out


def opacity_columns(bricks, field: str, transfer_function, axes, lower, size: float, bins: int,
                    splat: int) -> np.ndarray:
    """(bins, bins) float64: the opacity (alpha x lattice volume) of `field`
    over square columns along a view: column (i, j) holds what projects to
    world positions ``lower + size * ([i, i + 1), [j, j + 1))`` along the two
    rows of `axes` ((2, 3) world directions). Each cell is spread over its
    footprint at up to `splat` points a side."""
    out = np.zeros((bins, bins))
    xs, alpha = _alpha(transfer_function)
    axes3 = np.vstack([np.asarray(axes, np.float64), np.zeros((1, 3))])
    world = _world(bricks, axes3)
    for values, start, stop in _runs(bricks, field):
        _columns(values, *_bricks(bricks), start, stop, xs, alpha, *world,
                 np.asarray(lower, np.float64), float(size), int(splat), out)
    return out


def _alpha(transfer_function):
    points = transfer_function.alpha_points
    return np.ascontiguousarray(points[:, 0]), np.ascontiguousarray(points[:, 1])


def _world(bricks, axes):
    """(per-lattice-unit steps along each axis (3, 3), world origin along each
    axis (3,)): a lattice point p lies at ``origin_along + steps @ p`` along the
    rows of `axes`."""
    spacing = np.asarray(bricks.spacing_world, np.float64)
    origin = np.asarray(bricks.origin_world, np.float64)
    return np.ascontiguousarray(axes * spacing[None, :]), axes @ origin


@numba.njit(cache=True, nogil=True)
def _scaled(v, code, threshold):
    if code == 0:
        return v
    if code == 1:
        return math.log10(v) if v > 0 else -math.inf
    return math.copysign(math.log10(1.0 + abs(v) / threshold), v)


@numba.njit(cache=True, nogil=True)
def _histogram(values, level, dims, offset, start, stop, code, threshold, a, b, out):
    bins = out.shape[0]
    per = bins / (b - a)
    for brick in range(start, stop):
        weight = 8.0 ** level[brick]
        first = offset[brick]
        for i in range(dims[brick, 0] * dims[brick, 1] * dims[brick, 2]):
            v = values[first + i]
            if not math.isfinite(v):
                continue
            s = _scaled(float(v), code, threshold)
            k = 0 if not s > a else min(int((s - a) * per), bins - 1)
            out[k] += weight


@numba.njit(cache=True, nogil=True)
def _visit(values, lower, level, dims, offset, brick, xs, alpha):
    """(weights (n,), centres (n, 3)) of the visible cells of one brick."""
    n = dims[brick, 0] * dims[brick, 1] * dims[brick, 2]
    weights = np.empty(n)
    centres = np.empty((n, 3))
    width = float(1 << level[brick])
    volume = width * width * width
    count = 0
    i = 0
    for z in range(dims[brick, 2]):
        for y in range(dims[brick, 1]):
            for x in range(dims[brick, 0]):
                v = values[offset[brick] + i]
                i += 1
                if not math.isfinite(v):
                    continue
                w = np.interp(float(v), xs, alpha)
                if w > 0:
                    weights[count] = w * volume
                    centres[count, 0] = lower[brick, 0] + (x + 0.5) * width
                    centres[count, 1] = lower[brick, 1] + (y + 0.5) * width
                    centres[count, 2] = lower[brick, 2] + (z + 0.5) * width
                    count += 1
    return weights[:count], centres[:count]


@numba.njit(cache=True, nogil=True)
def _along(values, lower, level, dims, offset, start, stop, xs, alpha, steps, origin, low, span,
           out):
    bins = out.shape[1]
    for brick in range(start, stop):
        weights, centres = _visit(values, lower, level, dims, offset, brick, xs, alpha)
        for c in range(weights.shape[0]):
            for k in range(3):
                at = origin[k] + steps[k, 0] * centres[c, 0] + steps[k, 1] * centres[c, 1] \
                    + steps[k, 2] * centres[c, 2]
                j = int((at - low[k]) / span[k] * bins) if span[k] > 0 else 0
                out[k, min(max(j, 0), bins - 1)] += weights[c]


@numba.njit(cache=True, nogil=True)
def _columns(values, lower, level, dims, offset, start, stop, xs, alpha, steps, origin, low, size,
             splat, out):
    bins = out.shape[0]
    for brick in range(start, stop):
        weights, centres = _visit(values, lower, level, dims, offset, brick, xs, alpha)
        width = float(1 << level[brick])
        reach = np.sqrt(steps[0, 0] ** 2 + steps[0, 1] ** 2 + steps[0, 2] ** 2) * width
        k = min(splat, max(1, int(math.ceil(reach / size))))
        share = 1.0 / (k * k * k)
        for c in range(weights.shape[0]):
            for a in range(k):
                for b in range(k):
                    for d in range(k):
                        px = centres[c, 0] + ((a + 0.5) / k - 0.5) * width
                        py = centres[c, 1] + ((b + 0.5) / k - 0.5) * width
                        pz = centres[c, 2] + ((d + 0.5) / k - 0.5) * width
                        u = origin[0] + steps[0, 0] * px + steps[0, 1] * py + steps[0, 2] * pz
                        v = origin[1] + steps[1, 0] * px + steps[1, 1] * py + steps[1, 2] * pz
                        i = min(max(int((u - low[0]) / size), 0), bins - 1)
                        j = min(max(int((v - low[1]) / size), 0), bins - 1)
                        out[i, j] += weights[c] * share


def field_range(bricks, field: str | None) -> tuple[float, float]:
    """(min, max) of the finite values of `field` (None: the first field);
    ExabricksError if it has none."""
    from ..schema import reduce_chunks

    def extent(chunk):
        finite = chunk[np.isfinite(chunk)]
        return (float(finite.min()), float(finite.max())) if finite.size else (np.inf, -np.inf)

    lo, hi = reduce_chunks(bricks.values[bricks.field_index(field)], extent,
                           lambda a, b: (min(a[0], b[0]), max(a[1], b[1])))
    if lo > hi:
        raise ExabricksError(f"field {field or bricks.fields[0]!r} has no finite values")
    return lo, hi


def smallest_positive(bricks, field: str) -> float | None:
    """The smallest positive finite value of `field`, or None where it has none."""
    from ..schema import reduce_chunks

    def least(chunk):
        positive = chunk[np.isfinite(chunk) & (chunk > 0)]
        return float(positive.min()) if positive.size else math.inf

    low = reduce_chunks(bricks.values[bricks.field_index(field)], least, min)
    return low if math.isfinite(low) else None
