"""The file kinds: cells, bricks, regions, bvh, values, each a frozen dataclass of the
arrays it stores (`SPECS`: dtype and symbolic shape of each), and the
summaries of one (`world_bounds`, `summary`, for `exabricks info`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..util.constants import (
    BOUNDS_DTYPE, INDEX_DTYPE, LATTICE_DTYPE, LEVEL_DTYPE, OFFSET_DTYPE, VALUE_DTYPE, WORLD_DTYPE
)
from ..util.errors import ExabricksError, quoted
from .pieces import RUNS_KEY
from .memory import rows


@dataclass(frozen=True)
class ArraySpec:
    """dtype and shape of one stored array; shape entries are ints or symbol names."""

    dtype: np.dtype
    shape: tuple


def _common_specs() -> dict[str, ArraySpec]:
    return {
        "origin_world": ArraySpec(WORLD_DTYPE, (3,)),
        "spacing_world": ArraySpec(WORLD_DTYPE, (3,)),
    }


@dataclass(frozen=True, eq=False)
class Kind:
    """Fields shared by every kind: field names, world frame and free-form meta."""

    fields: tuple[str, ...]
    origin_world: np.ndarray
    spacing_world: np.ndarray
    meta: dict = field(default_factory=dict, repr=False)

    KIND: ClassVar[str] = ""
    VERSION: ClassVar[int] = 0
    SPECS: ClassVar[dict[str, ArraySpec]] = {}

    @property
    def n_fields(self) -> int:
        return len(self.fields)

    def field_index(self, name: str | None) -> int:
        """Index of field `name` (None: the first field); ExabricksError if absent."""
        if name is None:
            return 0
        if name not in self.fields:
            raise ExabricksError(
                f"no field {quoted(name)} (fields: {', '.join(self.fields) or 'none'})"
            )
        return self.fields.index(name)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self.SPECS}

    def replace(self, **changes) -> "Kind":
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, eq=False)
class Cells(Kind):
    """Leaf cells of an AMR dataset.

    lower_lattice: int32 (N, 3), lower corner in finest-cell units, a multiple of 2**level.
    level:         int8 (N,), 0 is the finest; a cell is 2**level lattice units wide.
    values:        float32 (F, N), one row per field in `fields`.
    """

    lower_lattice: np.ndarray = None
    level: np.ndarray = None
    values: np.ndarray = None

    KIND: ClassVar[str] = "cells"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(LATTICE_DTYPE, ("N", 3)),
        "level": ArraySpec(LEVEL_DTYPE, ("N",)),
        "values": ArraySpec(VALUE_DTYPE, ("F", "N")),
        **_common_specs(),
    }

    @property
    def n_cells(self) -> int:
        return int(self.level.shape[0])


@dataclass(frozen=True, eq=False)
class Bricks(Kind):
    """Same-level, fully filled bricks of cells (paper §3.1).

    lower_lattice: int32 (B, 3), lower corner in finest-cell units.
    level:         int8 (B,), level of every cell of the brick.
    dims:          int32 (B, 3), cells per axis.
    offset:        int64 (B,), index of the brick's first value in `values`.
    values:        float32 (F, V), per field, brick after brick, x fastest then y then z.
    """

    lower_lattice: np.ndarray = None
    level: np.ndarray = None
    dims: np.ndarray = None
    offset: np.ndarray = None
    values: np.ndarray = None

    KIND: ClassVar[str] = "bricks"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(LATTICE_DTYPE, ("B", 3)),
        "level": ArraySpec(LEVEL_DTYPE, ("B",)),
        "dims": ArraySpec(LATTICE_DTYPE, ("B", 3)),
        "offset": ArraySpec(OFFSET_DTYPE, ("B",)),
        "values": ArraySpec(VALUE_DTYPE, ("F", "V")),
        **_common_specs(),
    }

    @property
    def n_bricks(self) -> int:
        return int(self.level.shape[0])


@dataclass(frozen=True, eq=False)
class Regions(Kind):
    """Active Brick Regions (paper §3.2.3): disjoint boxes with the bricks active in each.

    lower_lattice, upper_lattice: float32 (R, 3), box bounds in finest-cell units.
    brick_start:  int64 (R + 1,), CSR row pointers into `brick_ids`.
    brick_ids:    int32 (K,), ids of the bricks whose support overlaps each region.
    value_range:  float32 (R, F, 2), min and max of every cell whose support overlaps.
    finest_level: int8 (R,), level of the finest cell influencing the region.
    """

    lower_lattice: np.ndarray = None
    upper_lattice: np.ndarray = None
    brick_start: np.ndarray = None
    brick_ids: np.ndarray = None
    value_range: np.ndarray = None
    finest_level: np.ndarray = None

    KIND: ClassVar[str] = "regions"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(BOUNDS_DTYPE, ("R", 3)),
        "upper_lattice": ArraySpec(BOUNDS_DTYPE, ("R", 3)),
        "brick_start": ArraySpec(OFFSET_DTYPE, ("R+1",)),
        "brick_ids": ArraySpec(INDEX_DTYPE, ("K",)),
        "value_range": ArraySpec(VALUE_DTYPE, ("R", "F", 2)),
        "finest_level": ArraySpec(LEVEL_DTYPE, ("R",)),
        **_common_specs(),
    }

    @property
    def n_regions(self) -> int:
        return int(self.finest_level.shape[0])


@dataclass(frozen=True, eq=False)
class Bvh(Kind):
    """Bounding-volume hierarchy over the regions (flat node array, node 0 the root).

    lower_lattice, upper_lattice: float32 (M, 3), node bounds in finest-cell units.
    first:        int32 (M,), inner node: index of its left child (the right one is
                  first + 1); leaf: index of its first entry in `region_index`.
    count:        int32 (M,), 0 for an inner node, else the number of regions of the leaf.
    region_index: int32 (R,), region ids in leaf order.
    value_range:  float32 (M, F, 2), min and max over the node's regions.
    finest_level: int8 (M,), finest level influencing the node.
    """

    lower_lattice: np.ndarray = None
    upper_lattice: np.ndarray = None
    first: np.ndarray = None
    count: np.ndarray = None
    region_index: np.ndarray = None
    value_range: np.ndarray = None
    finest_level: np.ndarray = None

    KIND: ClassVar[str] = "bvh"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "lower_lattice": ArraySpec(BOUNDS_DTYPE, ("M", 3)),
        "upper_lattice": ArraySpec(BOUNDS_DTYPE, ("M", 3)),
        "first": ArraySpec(INDEX_DTYPE, ("M",)),
        "count": ArraySpec(INDEX_DTYPE, ("M",)),
        "region_index": ArraySpec(INDEX_DTYPE, ("R",)),
        "value_range": ArraySpec(VALUE_DTYPE, ("M", "F", 2)),
        "finest_level": ArraySpec(LEVEL_DTYPE, ("M",)),
        **_common_specs(),
    }

    @property
    def n_nodes(self) -> int:
        return int(self.count.shape[0])


@dataclass(frozen=True, eq=False)
class Values(Kind):
    """One step of a time series on a fixed hierarchy (docs/time-series.md): the
    step's fields in the cell order of the bricks it was made for, whose content
    sha256 meta["built_from"] records.

    values: float32 (F, V), laid out as those bricks' `values`.
    """

    values: np.ndarray = None

    KIND: ClassVar[str] = "values"
    VERSION: ClassVar[int] = 1
    SPECS: ClassVar[dict[str, ArraySpec]] = {
        "values": ArraySpec(VALUE_DTYPE, ("F", "V")),
        **_common_specs(),
    }


KINDS: dict[str, type[Kind]] = {k.KIND: k for k in (Cells, Bricks, Regions, Bvh, Values)}


# ---------------------------------------------------------------------------
# summaries (for `exabricks info`; the keys are documented in docs/file-formats.md)


def world_bounds(obj: Kind) -> tuple[list[float], list[float]]:
    """World-space bounding box of the data (cells/bricks) or the structure (regions/bvh)."""
    if isinstance(obj, Values):
        return [], []  # the bricks it goes with have the bounds
    if isinstance(obj, Cells):
        lo, hi = _cell_box(obj.lower_lattice, obj.level)
    elif isinstance(obj, Bricks):
        lo, hi = _cell_box(obj.lower_lattice, obj.level, obj.dims)
    elif isinstance(obj, Bvh):
        lo, hi = (obj.lower_lattice[:1], obj.upper_lattice[:1])
        lo, hi = (lo.min(axis=0), hi.max(axis=0)) if lo.size else (lo, hi)
    else:
        lo, hi = obj.lower_lattice, obj.upper_lattice
        lo, hi = (lo.min(axis=0), hi.max(axis=0)) if lo.size else (lo, hi)
    if np.size(lo) == 0:
        return [], []
    to_world = lambda x: (obj.origin_world + obj.spacing_world * np.asarray(x, float)).tolist()
    return to_world(lo), to_world(hi)


def _cell_box(lower, level, dims=None):
    """Lattice bounds of boxes of `dims` cells (one cell each without), in `rows` steps
    (the pages of mapped arrays handed back as it goes)."""
    if lower.size == 0:
        return lower[:0], lower[:0]
    lo, hi = [], []
    ones = np.ones((1, 3), np.int64)
    for _, (low, lv, *d) in rows(lower, level, *([] if dims is None else [dims])):
        width = (1 << lv.astype(np.int64))[:, None]
        lo.append(low.min(axis=0))
        hi.append((low.astype(np.int64) + (d[0] if d else ones) * width).max(axis=0))
    return np.min(lo, axis=0), np.max(hi, axis=0)


def summary(obj: Kind) -> dict[str, Any]:
    """A JSON-ready description: kind, version, counts, fields with ranges, frame, meta."""
    counts: dict[str, Any] = {}
    ranges: dict[str, list[float | None]] = {}
    if isinstance(obj, (Cells, Bricks, Values)):
        if isinstance(obj, Values):
            counts["cells"] = int(obj.values.shape[1])
        elif isinstance(obj, Cells):
            per_level = np.bincount(obj.level.astype(np.int64), minlength=1)
            counts["cells"] = obj.n_cells
            runs = obj.meta.get(RUNS_KEY)
            if isinstance(runs, dict) and isinstance(runs.get("starts"), list):
                counts["piece_runs"] = len(runs["starts"])
        else:
            n = obj.dims.astype(np.int64).prod(axis=1)
            per_level = np.bincount(obj.level.astype(np.int64), weights=n, minlength=1)
            counts["cells"] = int(n.sum())
            counts["bricks"] = obj.n_bricks
            counts["bricks_per_level"] = {
                str(l): int(c) for l, c in enumerate(np.bincount(obj.level.astype(np.int64)))
                if c
            }
        if not isinstance(obj, Values):
            counts["cells_per_level"] = {str(l): int(c) for l, c in enumerate(per_level) if c}
        for i, name in enumerate(obj.fields):
            v = obj.values[i]
            finite = v[np.isfinite(v)]
            ranges[name] = [float(finite.min()), float(finite.max())] if finite.size else [None, None]
    else:
        vr = obj.value_range
        for i, name in enumerate(obj.fields):
            ranges[name] = (
                [float(vr[:, i, 0].min()), float(vr[:, i, 1].max())] if vr.shape[0] else [None, None]
            )
        if isinstance(obj, Regions):
            counts["regions"] = obj.n_regions
            counts["region_brick_refs"] = int(obj.brick_ids.shape[0])
        else:
            counts["nodes"] = obj.n_nodes
            counts["leaves"] = int(np.count_nonzero(obj.count))
            counts["regions"] = int(obj.region_index.shape[0])
    lo, hi = world_bounds(obj)
    return {
        "kind": obj.KIND,
        "version": obj.VERSION,
        "counts": counts,
        "fields": [{"name": n, "min": ranges[n][0], "max": ranges[n][1]} for n in obj.fields],
        "world_bounds": {"lower": lo, "upper": hi},
        "origin": obj.origin_world.tolist(),
        "spacing": obj.spacing_world.tolist(),
        "bytes": {k: int(a.nbytes) for k, a in obj.arrays().items()},
        "meta": obj.meta,
    }
