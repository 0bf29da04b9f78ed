"""Time series on a fixed hierarchy (DESIGN.md "Time series on a fixed hierarchy",
docs/time-series.md): the structures of one step serve every step whose leaf
cells are the same.

- `step_values(cells, bricks)`: a step's fields laid out in the bricks' cell
  order, a `schema.Values` that records the bricks' content sha256; refused,
  naming a cell, when the step's cells are not the bricks' cells.
- `with_values(bricks, regions, bvh, step)`: the three structures of that step:
  the bricks with its values, and the value ranges that space skipping reads
  (each region's over the cells whose support overlaps it, each BVH node's over
  its regions) recomputed by the builders' own functions, so that everything
  equals a full rebuild of the step.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from .. import schema
from ..util.constants import VALUE_DTYPE
from ..util.errors import ExabricksError


class CellsDiffer(ExabricksError):
    """A step whose leaf cells (or world frame) are not the bricks' cells: it needs
    structures of its own."""


REGION_CHUNK = 1 << 16  # regions per step of the range pass (mapped values handed back after each)


def step_values(cells: schema.Cells, bricks: schema.Bricks, *, where: str = "the source",
                bricks_where: str = "the bricks") -> schema.Values:
    """The values of `cells` in the cell order of `bricks` (exabricks.builders.bricks:
    brick after brick, x fastest); ExabricksError unless the cells are exactly the
    bricks' cells, with the same fields and world frame."""
    if tuple(cells.fields) != tuple(bricks.fields):
        raise ExabricksError(f"{where}: its fields {list(cells.fields)} are not those of "
                             f"{bricks_where} {list(bricks.fields)} (choose them with --field)")
    if not (np.array_equal(cells.origin_world, bricks.origin_world)
            and np.array_equal(cells.spacing_world, bricks.spacing_world)):
        raise CellsDiffer(f"{where}: its world frame (origin, spacing) is not that of "
                          f"{bricks_where}: the cells differ, rebuild the structures")
    n = int(bricks.values.shape[1])
    if cells.n_cells != n:
        raise CellsDiffer(f"{where}: {cells.n_cells:,} leaf cells, {bricks_where} hold {n:,}: "
                          "the cells differ, rebuild the structures")
    lower = np.asarray(cells.lower_lattice)
    cell_lo, cell_hi = _extent(lower)
    brick_lo, _ = _extent(bricks.lower_lattice)
    brick_hi = (bricks.lower_lattice.astype(np.int64) + (bricks.dims.astype(np.int64)
                << bricks.level.astype(np.int64)[:, None])).max(axis=0, initial=0)
    origin = np.minimum(cell_lo, brick_lo)
    if np.any(np.maximum(cell_hi, brick_hi) - origin >= KEY_SPAN):
        raise ExabricksError(f"{where}: lattices wider than 2**21 finest cells per axis are not "
                             "supported by time series")
    slot_level = np.empty(n, np.int8)
    slot_key = _slot_keys(bricks.lower_lattice, bricks.level, bricks.dims, bricks.offset, origin, slot_level)
    cell_key = _cell_keys(lower, origin)
    with ThreadPoolExecutor(2) as pool:  # NumPy sorts without the GIL: one on each core
        by_cell, by_slot = pool.map(lambda k: np.argsort(k, kind="stable"), (cell_key, slot_key))
    differ = _first_difference(cell_key, by_cell, slot_key, by_slot)
    del cell_key, slot_key
    if differ >= 0:
        i = int(by_cell[differ])
        raise CellsDiffer(f"{where}: cell {i} at {lower[i].tolist()} (level {int(cells.level[i])}) "
                          f"is not a cell of {bricks_where}: the cells differ, rebuild the "
                          "structures")
    source = np.empty(n, np.int64)
    source[by_slot] = by_cell  # slot s of the bricks holds cell source[s]
    del by_cell, by_slot
    wrong = np.flatnonzero(np.asarray(cells.level)[source] != slot_level)
    if wrong.size:
        i = int(source[wrong[0]])
        raise CellsDiffer(f"{where}: cell {i} at {lower[i].tolist()} is level "
                          f"{int(cells.level[i])}, in {bricks_where} level "
                          f"{int(slot_level[wrong[0]])}: the cells differ, rebuild the structures")
    values = np.empty((cells.n_fields, n), VALUE_DTYPE)
    for f in range(cells.n_fields):
        np.take(np.asarray(cells.values[f], VALUE_DTYPE), source, out=values[f])
    return schema.Values(fields=tuple(cells.fields), origin_world=cells.origin_world.copy(),
                         spacing_world=cells.spacing_world.copy(), values=values)


def with_values(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh,
                step: schema.Values, *, where: str = "the values file",
                bricks_where: str = "the bricks"):
    """(bricks, regions, bvh) of the step `step`: the structures of another step of
    the same cells with `step`'s values and the value ranges they imply."""
    check_values_for(step, bricks, where=where, bricks_where=bricks_where)
    from .bvh import refit
    from .region_merge import leaf_ranges

    ranges = np.empty_like(regions.value_range)
    lo2 = np.rint(np.asarray(regions.lower_lattice, np.float64) * 2).astype(np.int64)
    hi2 = np.rint(np.asarray(regions.upper_lattice, np.float64) * 2).astype(np.int64)
    start = np.asarray(regions.brick_start)
    for a in range(0, regions.n_regions, REGION_CHUNK):
        b = min(a + REGION_CHUNK, regions.n_regions)
        ids = np.asarray(regions.brick_ids[start[a]:start[b]])
        ranges[a:b], _ = leaf_ranges(lo2[a:b], hi2[a:b], start[a:b + 1] - start[a], ids,
                                      bricks.lower_lattice, bricks.dims, bricks.offset,
                                      step.values, bricks.level)
        schema.release_arrays(step.values)  # a mapped file's pages: read again if needed
    _, _, node_ranges, _ = refit(bvh.first, bvh.count, bvh.region_index,
                                  np.ascontiguousarray(regions.lower_lattice),
                                  np.ascontiguousarray(regions.upper_lattice), ranges,
                                  np.ascontiguousarray(regions.finest_level))
    meta = {**bricks.meta, "values": {"content_sha256": step.meta.get("content_sha256")}}
    if "source" in step.meta:
        meta["source"] = step.meta["source"]  # this step's time and units
    return (bricks.replace(values=step.values, meta=meta), regions.replace(value_range=ranges),
            bvh.replace(value_range=node_ranges))


def check_values_for(step: schema.Values, bricks: schema.Bricks, *, where: str = "the values file",
                     bricks_where: str = "the bricks") -> None:
    """ExabricksError (one line naming both) unless `step` was made for `bricks`."""
    recorded = step.meta.get("built_from")
    recorded = recorded.get("content_sha256") if isinstance(recorded, dict) else None
    actual = bricks.meta.get("content_sha256") or schema.content_sha256(bricks)
    if not isinstance(recorded, str):
        raise ExabricksError(f"{where}: records no bricks it was made for (meta.built_from): make "
                             f"it with `exabricks values SOURCE --bricks {bricks_where}`")
    if recorded != actual:
        raise ExabricksError(
            f"{where}: was made for other bricks than {bricks_where} (it records bricks content "
            f"sha256 {str(recorded)[:12]}..., {bricks_where} holds {actual[:12]}...): make it "
            f"with `exabricks values SOURCE --bricks {bricks_where}`")
    if tuple(step.fields) != tuple(bricks.fields) or step.values.shape != bricks.values.shape \
            or not (np.array_equal(step.origin_world, bricks.origin_world)
                    and np.array_equal(step.spacing_world, bricks.spacing_world)):
        raise ExabricksError(f"{where}: its fields, shape or world frame are not those of "
                             f"{bricks_where}, although it records them")


KEY_SPAN = 1 << 21  # lattice units per axis that one int64 key holds (21 bits each)


def _extent(lower: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis (min, max) of int32 (N, 3) corners, as int64 (3,) each (zeros for none)."""
    return _column_extent(lower) if lower.shape[0] else (np.zeros(3, np.int64), np.zeros(3, np.int64))


@numba.njit(cache=True)
def _column_extent(lower):
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for ax in range(3):
        lo[ax] = hi[ax] = lower[0, ax]
    for i in range(lower.shape[0]):
        for ax in range(3):
            v = lower[i, ax]
            if v < lo[ax]:
                lo[ax] = v
            elif v > hi[ax]:
                hi[ax] = v
    return lo, hi


@numba.njit(cache=True)
def _first_difference(a, order_a, b, order_b):
    """The first k with a[order_a[k]] != b[order_b[k]], or -1."""
    for k in range(order_a.shape[0]):
        if a[order_a[k]] != b[order_b[k]]:
            return k
    return -1


@numba.njit(cache=True, parallel=True)
def _cell_keys(lower, origin):
    """One int64 per cell: its corner less `origin`, 21 bits per axis, z highest."""
    out = np.empty(lower.shape[0], np.int64)
    for i in numba.prange(lower.shape[0]):
        out[i] = (((np.int64(lower[i, 2]) - origin[2]) << 42) | ((np.int64(lower[i, 1]) - origin[1]) << 21)
                  | (np.int64(lower[i, 0]) - origin[0]))
    return out


@numba.njit(cache=True, parallel=True)
def _slot_keys(lower, level, dims, offset, origin, slot_level):
    """The `_cell_keys` of every cell slot of the bricks (their lower corners), and
    their levels into slot_level."""
    n = slot_level.shape[0]
    out = np.empty(n, np.int64)
    for b in numba.prange(lower.shape[0]):
        w = np.int64(1) << np.int64(level[b])
        o = offset[b]
        dx, dy, dz = np.int64(dims[b, 0]), np.int64(dims[b, 1]), np.int64(dims[b, 2])
        x0 = np.int64(lower[b, 0]) - origin[0]
        y0 = np.int64(lower[b, 1]) - origin[1]
        z0 = np.int64(lower[b, 2]) - origin[2]
        for z in range(dz):
            for y in range(dy):
                row = o + (z * dy + y) * dx
                for x in range(dx):
                    out[row + x] = ((z0 + z * w) << 42) | ((y0 + y * w) << 21) | (x0 + x * w)
                    slot_level[row + x] = level[b]
    return out
