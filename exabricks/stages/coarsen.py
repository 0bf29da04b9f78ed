"""Level of detail: merge complete octets of fine cells into coarser cells.

The rule (docs/coarsen.md): bottom-up octree merging.  Let `f` be the finest
level present.  For each level l = f, f + 1, ..., f + K - 1 in turn, every
complete group of 8 sibling leaves of level l (the 8 children of one aligned
level-(l+1) cube, all present as level-l leaves, counting cells merged at the
step before) becomes one level-(l+1) cell whose value is, per field, the mean
of the 8 (their volumes are equal, so this is the volume-weighted average).
A group with a hole, or with a child that is refined further (not a level-l
leaf), stays as it is; so near holes and near finer cells that did not merge,
finer cells remain.  The covered volume and every field's volume integral
sum(value * 8**level) are preserved exactly, up to the one float32 rounding of
each output value: sums run in float64 through all K steps and are rounded once.
A NaN among the 8 makes the merged value NaN (for that field only).

`coarsen_plotfile` does the same for an AMReX plotfile, which stores the coarse
cells that finer levels cover (averaged down by the simulation): it reads the
levels down to the coarsest one that is no coarser than the target and takes
those values as they are, merging octets only below an AMReX level boundary
(refinement ratio 4) — and never reads the finer levels' data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE
from ..util.errors import ExabricksError
from ..schema import Cells


def coarsen_cells(cells: Cells, *, levels: int) -> Cells:
    """Cells with every complete octet of leaves merged, `levels` times bottom-up.

    cells.lower_lattice: int32 (N, 3), lower corners in finest-cell units.
    cells.level:         int8 (N,), 0 finest; a cell is 2**level lattice units wide.
    cells.values:        float32 (F, N).
    levels: K >= 0, how many levels above the finest level present to merge
        (K = 0 returns `cells` unchanged).

    Returns Cells with the same fields and world frame; each merged cell's
    float32 value is the float64 mean of the input cells it replaces.  Order:
    for each level l < f + K the unmerged input cells of level l (in input
    order), then those merged into level l; then the input cells of levels
    >= f + K (in input order), then the cells merged into level f + K.
    meta: {"parameters": {"levels", "finest_level"}, "statistics":
    {"cells_before", "cells_after", "cells_per_level_before",
    "cells_per_level_after", "merged_groups_per_level"}}.
    Raises ExabricksError for K < 0 or when f + K exceeds MAX_LEVEL
    (f: the finest level present).
    Runs in O(N log N) (one sort per merged level).
    """
    levels = int(levels)
    if levels < 0:
        raise ExabricksError(f"the number of levels must be >= 0, got {levels}")
    n = cells.n_cells
    finest = int(cells.level.min()) if n else 0
    if finest + levels > MAX_LEVEL:
        raise ExabricksError(
            f"coarsening by {levels} levels above the finest level {finest} would make "
            f"cells of level {finest + levels}, above the largest level {MAX_LEVEL}"
        )
    before = _per_level(cells.level)
    if levels == 0 or n == 0:
        return cells.replace(meta=_meta(levels, finest, before, before, {}))

    lower_in = cells.lower_lattice.astype(np.int64)
    level_in = cells.level
    kept_lower, kept_level, kept_values = [], [], []
    # Merged cells of the current level: int64 corners and float64 means, so that the
    # sums of all K steps are rounded to float32 only once, at the end.
    carry_lower = np.empty((0, 3), np.int64)
    carry_values = np.empty((cells.n_fields, 0), np.float64)
    merged_groups = {}
    for lv in range(finest, finest + levels):
        at_level = np.flatnonzero(level_in == lv)
        lower = np.concatenate([lower_in[at_level], carry_lower])
        values = np.concatenate([cells.values[:, at_level].astype(np.float64), carry_values], axis=1)
        members = _complete_octets(lower, lv)
        merged_groups[lv] = len(members)
        stays = np.ones(len(lower), bool)
        stays[members.ravel()] = False
        kept_lower.append(lower[stays])
        kept_level.append(np.full(int(stays.sum()), lv, LEVEL_DTYPE))
        kept_values.append(values[:, stays])
        # The children's corners floored to the parent's width give the parent's corner.
        carry_lower = (lower[members[:, 0]] >> (lv + 1)) << (lv + 1)
        carry_values = values[:, members].mean(axis=2)
    top = finest + levels
    coarse = np.flatnonzero(level_in >= top)
    kept_lower += [lower_in[coarse], carry_lower]
    kept_level += [level_in[coarse], np.full(len(carry_lower), top, LEVEL_DTYPE)]
    kept_values += [cells.values[:, coarse], carry_values]

    level_out = np.concatenate(kept_level).astype(LEVEL_DTYPE)
    after = _per_level(level_out)
    return cells.replace(
        lower_lattice=np.concatenate(kept_lower).astype(LATTICE_DTYPE),
        level=level_out,
        values=np.concatenate(kept_values, axis=1).astype(VALUE_DTYPE),
        meta=_meta(levels, finest, before, after, merged_groups),
    )


def coarsen_plotfile(path: str | Path, *, levels: int, fields=(), mask: str | None = None,
                     auto_mask: bool = True, nan_policy: str = "error") -> Cells:
    """`coarsen_cells(ingest(path), levels=levels)` for an AMReX plotfile, with the
    plotfile's own covered data in place of averages wherever it has them.  (With
    holes -- a volFrac mask, dropped NaNs -- the two differ: octets with a hole stay
    fine in the leaf path, while a covered coarse cell is read as stored.)

    Let t = f + K (f: the lattice level of AMReX's finest level that has boxes).
    AMReX levels 0..C are read, C the coarsest AMReX level whose lattice level is
    <= t, so that every cell of levels <= t is either read as stored or merged from level
    C by `coarsen_cells` (only when t falls between two AMReX levels).  The data of
    levels finer than C is never read.  With ratio-2 hierarchies and data averaged
    down before the plotfile was written, the result equals `coarsen_cells` of the
    full read up to float32 rounding (docs/coarsen.md measures it).

    fields, mask, auto_mask, nan_policy: as for `stages.ingest.ingest`.
    Returns Cells with meta of `ingest` whose parameters gain "levels",
    "finest_level" and "covered_level" (the lattice level of AMReX level C) and
    whose statistics are those of the output cells plus "merged_groups_per_level".
    Raises ExabricksError as `ingest` and `coarsen_cells` do.
    """
    from ..readers import amrex
    from ..builders.cells import cell_statistics
    from .ingest import ingest

    levels = int(levels)
    if levels < 0:
        raise ExabricksError(f"the number of levels must be >= 0, got {levels}")
    header = amrex.read_header(Path(path))
    lattice_level = amrex.lattice_levels(header)
    present = [lv for lv, (_, boxes) in zip(lattice_level, header["level_paths"]) if boxes]
    finest = min(present) if present else 0
    target = finest + levels
    if target > MAX_LEVEL:
        raise ExabricksError(
            f"coarsening by {levels} levels above the finest level {finest} would make "
            f"cells of level {target}, above the largest level {MAX_LEVEL}"
        )
    cap = min(L for L, lv in enumerate(lattice_level) if lv <= target)
    cells = ingest(path, format="amrex", fields=fields, mask=mask, auto_mask=auto_mask,
                   nan_policy=nan_policy, level_cap=cap)
    rest = max(0, target - int(cells.level.min()))
    coarse = coarsen_cells(cells, levels=rest)
    meta = dict(cells.meta)
    meta["parameters"] = {**meta["parameters"], "levels": levels, "finest_level": finest,
                          "covered_level": lattice_level[cap]}
    meta["statistics"] = {**cell_statistics(coarse),
                          "merged_groups_per_level":
                              coarse.meta["statistics"]["merged_groups_per_level"]}
    return coarse.replace(meta=meta)


def _complete_octets(lower: np.ndarray, level: int) -> np.ndarray:
    """Indices (G, 8) of the complete groups of 8 siblings among level-`level` cells.

    lower: int64 (M, 3), lower corners of cells that all have level `level` and do
    not overlap; 8 of them with the same parent corner are therefore exactly the 8
    children of that parent.
    """
    if len(lower) < 8:
        return np.empty((0, 8), np.intp)
    parent = lower >> (level + 1)  # arithmetic shift: floor division, right for negatives
    key = _packed_key(parent)
    if key is None:  # spans too wide to pack into one int64: sort on three keys
        order = np.lexsort((parent[:, 0], parent[:, 1], parent[:, 2]))
        sorted_parent = parent[order]
        new_group = np.any(sorted_parent[1:] != sorted_parent[:-1], axis=1)
    else:
        order = np.argsort(key)
        sorted_key = key[order]
        new_group = sorted_key[1:] != sorted_key[:-1]
    starts = np.flatnonzero(np.concatenate([[True], new_group]))
    counts = np.diff(np.append(starts, len(lower)))
    full = starts[counts == 8]
    return order[full[:, None] + np.arange(8)]


def _packed_key(parent: np.ndarray) -> np.ndarray | None:
    """int64 (M,) key equal for equal rows of `parent` (int64 (M, 3)), or None when
    the three coordinate spans need more than 63 bits together."""
    columns = np.ascontiguousarray(parent.T)  # (3, M): fast reductions per axis
    low = columns.min(axis=1)
    bits = [int(span).bit_length() for span in columns.max(axis=1) - low]
    if sum(bits) > 63:
        return None
    x, y, z = columns - low[:, None]
    return (z << (bits[0] + bits[1])) | (y << bits[0]) | x

def _per_level(level: np.ndarray) -> dict[str, int]:
    counts = np.bincount(level.astype(np.int64)) if level.size else np.zeros(0, int)
    return {str(lv): int(c) for lv, c in enumerate(counts) if c}


def _meta(levels, finest, before, after, merged_groups) -> dict:
    return {
        "parameters": {"levels": levels, "finest_level": finest},
        "statistics": {
            "cells_before": sum(before.values()),
            "cells_after": sum(after.values()),
            "cells_per_level_before": before,
            "cells_per_level_after": after,
            "merged_groups_per_level": {str(k): int(v) for k, v in merged_groups.items()},
        },
    }
