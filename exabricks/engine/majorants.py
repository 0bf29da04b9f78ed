"""The path integrator's majorants (docs/design-rendering.md, "Path tracing"): a
coarse grid of macrocells over the data, each holding, per field, the range of
the values of every cell whose reconstruction can reach into it, and per frame
the largest extinction the volume layers' transfer functions give over those
ranges. Delta and ratio tracking (kernels/path.cl) step through the grid with
each macrocell's majorant, so a free path is as long as the densest matter in
its macrocell allows, not the densest of the whole frame (Beyond ExaBricks
builds such a grid for the same reason: the regions suit coherent primary rays,
not incoherent scattered ones).

The value ranges are the dataset's (made once per field and kept); the
majorants are the frame's (a transfer-function change remakes them from the
ranges in milliseconds, with no rebuild of bricks, regions or BVH).

A cell of width w with lower corner c reaches [c - w/2, c + 3w/2] per axis: its
basis function's support (kernels/reconstruction.cl); the nearest
reconstruction's support is the cell itself. Either reconstruction is a convex
combination of the values of the cells whose support holds the point, so it
lies in the macrocell's range, and the transfer function's largest opacity over
that range bounds the extinction there."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .look import alpha_tolerance

# Macrocells along the grid's longest axis (a power-of-two macrocell width in
# finest cells): docs/benchmarks-render.md "Path integrator" measures 16 to 128.
MACROCELLS = 64
# Opacities per unit distance are capped here for the path integrator: an
# opacity of 1 is an infinite extinction, which no free path can sample. At the
# cap a unit distance lets through 2**-20 of the light.
ALPHA_CAP = 1.0 - 2.0 ** -20
# The majorants are raised by this much relative to the bound, for the float32
# arithmetic of the kernel's extinction.
MARGIN = 1e-4


@dataclass(frozen=True)
class MacrocellGrid:
    """A grid of `dims` (x, y, z) macrocells of `width` finest cells from lattice
    point `lower`."""

    lower: np.ndarray
    width: float
    dims: tuple[int, int, int]

    @classmethod
    def over(cls, lower, upper, macrocells: int = MACROCELLS) -> "MacrocellGrid":
        """The grid over the lattice box [lower, upper] with at most `macrocells` along
        its longest axis."""
        lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
        extent = float(np.max(upper - lower))
        width = 2.0 ** max(0, int(np.ceil(np.log2(max(extent, 1.0) / macrocells))))
        dims = tuple(int(max(1, np.ceil((u - l) / width))) for l, u in zip(lower, upper))
        return cls(lower, width, dims)

    @property
    def n(self) -> int:
        return int(np.prod(self.dims))

    def params(self) -> dict:
        """Its eb_params members (kernel_abi.PARAMS; the majorants' offset is the look's)."""
        return {"majorant_lower": (*self.lower, 1.0 / self.width), "majorant_dims": (*self.dims, 0)}


def value_ranges(bricks, field_index: int, grid: MacrocellGrid, nearest: bool = False) -> np.ndarray:
    """float32 (n, 2): per macrocell (x fastest) the smallest and largest value of
    field `field_index` among the cells reaching into it (+inf, -inf where none;
    NaN values are no data). `nearest`: a cell reaches only its own box."""
    out = np.empty((grid.n, 2), np.float32)
    out[:, 0], out[:, 1] = np.inf, -np.inf
    _ranges(np.asarray(bricks.lower_lattice, np.float64), np.asarray(bricks.level, np.int64),
            np.asarray(bricks.dims, np.int64), np.asarray(bricks.offset, np.int64),
            bricks.values[field_index], np.asarray(grid.lower, np.float64), 1.0 / grid.width,
            np.asarray(grid.dims, np.int64), 0.0 if nearest else 0.5, out)
    return out


@numba.njit(cache=True, nogil=True)
def _ranges(lower, level, dims, offset, values, grid_lower, inv_width, n, reach, out):
    for b in range(level.shape[0]):
        w = 2.0 ** level[b]
        nx, ny, nz = dims[b, 0], dims[b, 1], dims[b, 2]
        for k in range(nz):
            for j in range(ny):
                for i in range(nx):
                    v = values[offset[b] + i + nx * (j + ny * k)]
                    if v != v:
                        continue
                    lo = np.empty(3, np.int64)
                    hi = np.empty(3, np.int64)
                    cell = (i, j, k)
                    for a in range(3):
                        c = lower[b, a] + cell[a] * w
                        lo[a] = max(0, int(np.floor((c - reach * w - grid_lower[a]) * inv_width)))
                        hi[a] = min(n[a] - 1, int(np.floor((c + (1.0 + reach) * w - grid_lower[a])
                                                           * inv_width)))
                    for z in range(lo[2], hi[2] + 1):
                        for y in range(lo[1], hi[1] + 1):
                            for x in range(lo[0], hi[0] + 1):
                                m = x + n[0] * (y + n[1] * z)
                                if v < out[m, 0]:
                                    out[m, 0] = v
                                if v > out[m, 1]:
                                    out[m, 1] = v


def largest_alpha(transfer_function, ranges: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """float64 (n,): the largest opacity of `transfer_function` over each value range
    [lo, hi] of `ranges` (n, 2) (0 where the range is empty), plus `tolerance` (the
    lookup table's largest error). Exact: a piecewise-linear function's maximum
    over an interval is at an end or at a knot inside, and the knots inside are a
    range-maximum query over a sparse table (O(1) per macrocell)."""
    x, a = transfer_function.alpha_points[:, 0], transfer_function.alpha_points[:, 1]
    lo, hi = ranges[:, 0].astype(np.float64), ranges[:, 1].astype(np.float64)
    filled = lo <= hi
    lo, hi = np.where(filled, lo, 0.0), np.where(filled, hi, 0.0)
    best = np.maximum(np.interp(lo, x, a), np.interp(hi, x, a))
    first = np.searchsorted(x, lo, side="right")   # knots strictly inside: [first, end)
    end = np.searchsorted(x, hi, side="left")
    table = [a]  # table[k][i]: the largest of a[i:i + 2**k]
    while (1 << len(table)) <= len(a):
        prev, half = table[-1], 1 << (len(table) - 1)
        table.append(np.maximum(prev[:-half], prev[half:]))
    inside = end > first
    if inside.any():
        f, e = first[inside], end[inside]
        k = np.floor(np.log2(e - f)).astype(np.int64)
        stacked = np.full((len(table), len(a)), -np.inf)
        for level, row in enumerate(table):
            stacked[level, :len(row)] = row
        best[inside] = np.maximum(best[inside], np.maximum(stacked[k, f], stacked[k, e - (1 << k)]))
    return np.where(filled, np.minimum(best + tolerance, ALPHA_CAP), 0.0)


def extinction(alpha, inv_unit_distance: float) -> np.ndarray:
    """Extinction per world unit of slab opacity `alpha` per unit distance (capped)."""
    return -np.log1p(-np.minimum(alpha, ALPHA_CAP)) * inv_unit_distance


def majorants(layers, inv_unit_distance: float) -> np.ndarray:
    """float32 (n,): per macrocell the sum over the volume layers (value ranges (n, 2)
    of its field, transfer function, lookup-table tolerance) of their largest
    extinction per world unit there, raised by MARGIN."""
    total = None
    for ranges, transfer_function, tolerance in layers:
        mu = extinction(largest_alpha(transfer_function, ranges, tolerance), inv_unit_distance)
        total = mu if total is None else total + mu
    return (total * (1.0 + MARGIN)).astype(np.float32)


def frame_majorants(scene, dataset, unit_distance: float, cache: dict) -> tuple[MacrocellGrid, np.ndarray]:
    """The majorant grid over `dataset` (a DeviceDataset) and the majorants of
    `scene`'s volume layers with opacity per `unit_distance` (world); `cache`
    keeps the grid and its value ranges per field and reconstruction across frames."""
    grid = cache.get("grid")
    if grid is None:
        bvh = dataset.bvh
        grid = cache["grid"] = MacrocellGrid.over(bvh.lower_lattice[0], bvh.upper_lattice[0])
    nearest = scene.settings.reconstruction == "nearest"
    layers = []
    for volume in scene.volumes:
        key = (volume.field, nearest)
        if key not in cache:
            cache[key] = value_ranges(dataset.bricks, dataset.bricks.field_index(volume.field), grid,
                                      nearest)
        layers.append((cache[key], volume.transfer_function, alpha_tolerance(volume, scene.settings)))
    if not layers:
        return grid, np.zeros(grid.n, np.float32)
    return grid, majorants(layers, 1.0 / unit_distance)
