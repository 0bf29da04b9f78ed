"""Ingest stage: read any AMR source into checked leaf cells, and turn a uniform
volume into AMR.

- `ingest` is the stage (DESIGN.md "The pipeline"): reader, derived fields, the
  embedded-boundary mask, field selection, the checks, and the provenance meta;
  `exabricks ingest` only parses options, calls it and saves the result.
- `validate_cells` enforces the cell contract of DESIGN.md ("Cells and
  coordinates"): at least one cell, levels in 0..MAX_LEVEL, lower corners that
  are multiples of the cell width, no two cells covering the same space, and a
  chosen treatment of non-finite values.
- `amr_from_uniform` merges homogeneous 2x2x2 groups of a uniform volume level
  by level, which is how scale-test inputs of tens of millions of cells are made
  from a raw volume.

`add_magnitude` derives a vector-magnitude field from component fields (a user
option, DESIGN.md "Fields"), `parse_expression` and `add_derived` a field given
by an expression over the others (evaluated by numexpr); `apply_mask` drops the
cells where a field is 0 (the body of an embedded-boundary plotfile, whose
`volFrac` is 0 there).
"""

from __future__ import annotations

import ast
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from .. import schema
from ..constants import AUTO_MASK_FIELD, LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, NAN_POLICIES, VALUE_DTYPE
from ..errors import ExabricksError
from ..schema import Cells, first_misaligned
from .piece_order import RUNS_KEY, order_cells

RAW_DEFAULTS = {"dims": None, "dtype": "float32", "byte_order": "little", "name": "value",
                "max_level": None, "threshold": 0.0}
_RAW_FLAGS = {"dims": "--dims", "max_level": "--max-level", "threshold": "--threshold",
              "dtype": "--dtype", "byte_order": "--byte-order", "name": "--name"}


# ---------------------------------------------------------------------------
# the stage


def ingest(
    path: str | Path,
    *,
    format: str = "auto",
    fields: Iterable[str] = (),
    scalars: Mapping[str, str | Path] | None = None,
    dims=None,
    dtype: str = "float32",
    byte_order: str = "little",
    name: str = "value",
    max_level: int | None = None,
    threshold: float = 0.0,
    magnitude: Iterable[tuple[str, str | Iterable[str]]] | Mapping = (),
    derive: Iterable[tuple[str, str]] | Mapping[str, str] = (),
    nan_policy: str = "error",
    mask: str | None = None,
    auto_mask: bool = True,
    level_cap: int | None = None,
    piece_order: bool = False,
    on_step: Callable[[], None] | None = None,
) -> Cells:
    """Leaf cells of `path`, checked, with their provenance meta (ready for schema.save).

    format: "auto" (`readers.detect_format`) or one of `readers.FORMATS`.
    fields: names to keep, in that order (empty: every field of the input, then the
            derived ones).
    scalars: exajet only: field name -> .scalars file.
    dims, dtype, byte_order, name, max_level, threshold: raw volumes only (see
            `readers.raw.read`); any of them away from its default for another format
            is an error.
    magnitude: (NAME, "A,B,C" or (A, B, C)) pairs, or a mapping: field NAME =
            sqrt(A² + B² + C²), appended before `fields` selects.
    derive: (NAME, EXPR) pairs, or a mapping: field NAME = EXPR, an expression in
            numexpr's language over the fields (`parse_expression`: its names, the
            functions it may call), evaluated per cell in float64 and stored as float32;
            appended after the magnitudes, in order, so each may use the magnitudes and
            the ones before it.  Like a magnitude's components, the fields it reads are
            read even when `fields` leaves them out.
    nan_policy: one of NAN_POLICIES.
    mask: drop the cells where this field is exactly 0 (compared as stored, float32);
          they become holes.  The field itself stays unless `fields` leaves it out.
    auto_mask: with no `mask`, use AUTO_MASK_FIELD as the mask when the input has it.
    level_cap: AMReX only: read levels 0..level_cap, using the covered data the
          plotfile stores for level `level_cap` (`readers.amrex.read`; `coarsen` uses it).
    piece_order: store the cells in the order of the top of their k-d partition, with
          the runs from which `brick --piece K/N` reads only its share
          (exabricks.stages.piece_order; what the `ingest` command writes).
    on_step: called after reading, after checking and, with `piece_order`, after
          ordering (for a progress bar).

    The order: read, magnitudes, derived expressions, mask, field selection,
    `validate_cells` (so an expression's inf or NaN, e.g. from a division by zero, meets
    `nan_policy`).  Expressions are parsed and checked before anything is read.
    meta: inputs with sha256, parameters (format, fields, nan, mask, mask_auto, magnitude,
    derive, and the format's own options), statistics (`cell_statistics`, dropped_nonfinite_cells,
    masked_cells), and the reader's source description.
    Raises ExabricksError naming `path` for bad input or options.
    """
    from .. import readers

    path = Path(path)
    source = str(path)
    fields = list(fields)
    step = on_step or (lambda: None)
    fmt = readers.detect_format(path, dims=dims) if format == "auto" else format
    raw = {"dims": dims, "dtype": dtype, "byte_order": byte_order, "name": name,
           "max_level": max_level, "threshold": threshold}
    options: dict = {}
    if fmt == "raw":
        options = dict(raw)
    else:
        given = [_RAW_FLAGS[k] for k in ("dims", "max_level", "threshold", "dtype",
                                         "byte_order", "name") if raw[k] != RAW_DEFAULTS[k]]
        if given:
            raise ExabricksError(f"{source}: {', '.join(given)} only apply to raw volumes, "
                                 f"not to {fmt} input")
    if level_cap is not None:
        if fmt != "amrex":
            raise ExabricksError(f"{source}: only AMReX plotfiles store covered coarse data, "
                                 f"not {fmt} input")
        options["level_cap"] = int(level_cap)
    if scalars:
        if fmt != "exajet":
            raise ExabricksError(f"{source}: --scalars is for exajet .cells files, not {fmt}")
        options["scalars"] = {k: Path(v) for k, v in scalars.items()}
    pairs = list(magnitude.items()) if isinstance(magnitude, Mapping) else list(magnitude)
    derived = [(k, tuple(c for c in v.split(",") if c) if isinstance(v, str) else tuple(v))
               for k, v in pairs]
    expressions = _expressions(derive, [k for k, _ in derived], source=source)
    derived_names = {k for k, _ in derived} | {e.name for e in expressions}
    if mask is not None and not mask:
        raise ExabricksError(f"{source}: --mask needs a field name")
    dataset = None
    if fmt == "yt":
        from ..readers import yt_bridge

        dataset = yt_bridge.load(path)  # once: its field names and its cells both come from it

    read_fields = [f for f in fields if f not in derived_names]
    if (derived or expressions) and fields:
        # what derived fields are made of must be read even if not kept
        made_of = [c for _, comps in derived for c in comps] + [n for e in expressions for n in e.fields]
        read_fields += [c for c in dict.fromkeys(made_of) if c not in read_fields
                        and c not in derived_names]
    mask_auto = False
    names = None
    helpers: list[str] = []  # fields yt derives that only expressions read: read, not kept
    if dataset is not None:
        # The index that yt reads anyway tells the on-disk fields, and which of the
        # "TYPE:NAME" fields asked for yt derives.
        refs = [n for e in expressions for n in e.fields]
        names = yt_bridge.field_names(dataset, also=[*read_fields, *refs, *([mask] if mask else [])])
        on_disk = yt_bridge.field_names(dataset)
        if not read_fields and len(names) > len(on_disk):  # all, and some yt derives
            read_fields = list(names)
            helpers = [n for n in names[len(on_disk):] if n != mask]
    elif (read_fields and (mask is not None or auto_mask)) or expressions:
        # A subset is read: the mask field must be part of it even if not kept, and the
        # automatic rule must know whether the input has AUTO_MASK_FIELD.  An
        # expression's unknown names are refused before anything is read.
        names = readers.field_names(path, format=fmt, **options)
    if names is not None:
        known = [*names, *(k for k, _ in derived)]
        for e in expressions:
            check_expression_fields(e, known, source=source)
            known.append(e.name)
    if read_fields and (mask is not None or auto_mask):
        if mask is None:
            if names is None:
                read_fields = []  # cannot tell cheaply: read all, decide below
            elif AUTO_MASK_FIELD in names:
                mask, mask_auto = AUTO_MASK_FIELD, True
        elif names is not None and mask not in names and mask not in derived_names:
            raise ExabricksError(
                f"{source}: no field {mask!r} for --mask (fields: {', '.join(names) or 'none'})"
            )
        if mask is not None and mask not in derived_names and read_fields \
                and mask not in read_fields:
            read_fields.append(mask)

    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # Readers turn out-of-range values into inf and refuse bad geometry with their
        # own messages; no RuntimeWarning may reach stderr ahead of an error line.
        if dataset is not None:
            cells = yt_bridge.cells_from_dataset(dataset, read_fields or None, source=source)
        else:
            cells = readers.read(path, format=fmt, fields=read_fields or None, **options)
        step()
        for mag_name, comps in derived:
            cells = add_magnitude(cells, mag_name, comps, source=source)
        for e in expressions:
            cells = add_derived(cells, e, source=source)
        if helpers:
            cells = readers.select_fields(cells, [f for f in cells.fields if f not in helpers],
                                          source=source)
        if mask is None and auto_mask and AUTO_MASK_FIELD in cells.fields:
            mask, mask_auto = AUTO_MASK_FIELD, True
        n_masked = 0
        if mask is not None:
            n_before = cells.n_cells
            cells = apply_mask(cells, mask, source=source)
            n_masked = n_before - cells.n_cells
        if fields:
            cells = readers.select_fields(cells, fields, source=source)
        n_read = cells.n_cells
        cells = validate_cells(cells, source=source, nan_policy=nan_policy)
        step()
        if piece_order:
            cells = order_cells(cells)
            step()

    inputs = cells.meta.get("inputs") or _input_files(path)
    parameters = {
        "format": fmt, "fields": fields, "nan": nan_policy,
        "mask": mask, "mask_auto": mask_auto,
        **({} if auto_mask else {"no_mask": True}),
        **({"scalars": {k: str(v) for k, v in options["scalars"].items()}}
           if "scalars" in options else {}),
        **({"dims": list(dims), "dtype": dtype, "byte_order": byte_order,
            "name": name, "max_level": max_level, "threshold": threshold}
           if fmt == "raw" else {}),
        **({"magnitude": {k: ",".join(c) for k, c in derived}} if derived else {}),
        **({"derive": {e.name: e.text for e in expressions}} if expressions else {}),
        **({"level_cap": int(level_cap)} if level_cap is not None else {}),
    }
    statistics = {**cell_statistics(cells), "dropped_nonfinite_cells": int(n_read - cells.n_cells),
                  "masked_cells": int(n_masked)}
    return cells.replace(meta=schema.make_meta(
        inputs=inputs, parameters=parameters, statistics=statistics,
        source={k: v for k, v in cells.meta.items() if k not in ("inputs", RUNS_KEY)},
        **({RUNS_KEY: cells.meta[RUNS_KEY]} if piece_order else {}),
    ))


def _input_files(path: Path) -> list[str]:
    if path.is_dir():
        return sorted(str(p) for p in path.rglob("*") if p.is_file())
    return [str(path)]


def apply_mask(cells: Cells, field: str, *, source: str) -> Cells:
    """`cells` without those where field `field` is exactly 0 (+0 or -0); NaN is kept.

    Raises ExabricksError naming `source` when the field is missing or every cell
    would go.
    """
    if field not in cells.fields:
        raise ExabricksError(
            f"{source}: no field {field!r} for --mask (fields: {', '.join(cells.fields) or 'none'})"
        )
    keep = cells.values[cells.fields.index(field)] != 0
    if keep.all():
        return cells
    if not keep.any():
        raise ExabricksError(
            f"{source}: every cell has {field} == 0: nothing is left after masking "
            f"(--mask {field}{'; --no-mask keeps them' if field == AUTO_MASK_FIELD else ''})"
        )
    return cells.replace(
        lower_lattice=np.ascontiguousarray(cells.lower_lattice[keep]),
        level=np.ascontiguousarray(cells.level[keep]),
        values=np.ascontiguousarray(cells.values[:, keep]),
    )


# ---------------------------------------------------------------------------
# validation


def validate_cells(cells: Cells, *, source: str, nan_policy: str = "error") -> Cells:
    """Check `cells` against the cell contract; return them (with non-finite values handled).

    cells.lower_lattice: int32 (N, 3), lower corners in finest-cell units.
    cells.level:         int8 (N,), 0 finest; width 2**level lattice units.
    cells.values:        float32 (F, N).
    source: the input's name, used in every message.
    nan_policy: one of NAN_POLICIES (see there).

    Raises ExabricksError naming `source`, the first offending cell index and its
    coordinates.  Overlap is found in O(N log N): aligned cells are octree nodes,
    so two overlap only if one contains the other; sorted by the Morton code of
    their lower corners, every cell occupies the code interval
    [code, code + 8**level), these intervals nest or are disjoint, and an
    overlap therefore shows up between two neighbours in that order.
    """
    if nan_policy not in NAN_POLICIES:
        raise ExabricksError(
            f"unknown NaN policy {nan_policy!r} (choose from {', '.join(NAN_POLICIES)})"
        )
    n = cells.n_cells
    if n == 0:
        raise ExabricksError(f"{source}: no cells (empty input)")
    lower = cells.lower_lattice
    level = cells.level
    if lower.dtype != LATTICE_DTYPE or lower.shape != (n, 3):
        raise ExabricksError(f"{source}: cell corners must be int32 (N, 3), got {lower.dtype} {lower.shape}")
    if level.dtype != LEVEL_DTYPE:
        raise ExabricksError(f"{source}: cell levels must be int8, got {level.dtype}")

    i = _first_bad_level(level, MAX_LEVEL)
    if i >= 0:
        raise ExabricksError(
            f"{source}: cell {i} at {lower[i].tolist()} has level {int(level[i])}, "
            f"outside 0..{MAX_LEVEL}"
        )
    i = first_misaligned(lower, level)
    if i >= 0:
        w = 1 << int(level[i])
        raise ExabricksError(
            f"{source}: cell {i} at {lower[i].tolist()} (level {int(level[i])}) is misaligned: "
            f"its corner must be a multiple of its width {w}"
        )

    cells = _handle_nonfinite(cells, source, nan_policy)
    if cells.n_cells == 0:
        raise ExabricksError(f"{source}: no cells left after dropping non-finite values")

    pair = find_overlap(cells.lower_lattice, cells.level)
    if pair is not None:
        a, b = pair
        lo, lv = cells.lower_lattice, cells.level
        what = "duplicates" if lv[a] == lv[b] else "overlaps"
        raise ExabricksError(
            f"{source}: cell {b} at {lo[b].tolist()} (level {int(lv[b])}) {what} "
            f"cell {a} at {lo[a].tolist()} (level {int(lv[a])})"
        )
    return cells


def _handle_nonfinite(cells: Cells, source: str, policy: str) -> Cells:
    values = cells.values
    if policy == "keep" or values.size == 0:
        return cells
    finite = np.isfinite(values)
    if finite.all():
        return cells
    if policy == "error":
        f = int(np.flatnonzero(~finite.all(axis=1))[0])
        i = int(np.flatnonzero(~finite[f])[0])
        raise ExabricksError(
            f"{source}: field {cells.fields[f]!r} is {values[f, i]} at cell {i} "
            f"(at {cells.lower_lattice[i].tolist()}, level {int(cells.level[i])}); "
            f"choose --nan zero, drop or keep to accept non-finite values"
        )
    if policy == "zero":
        return cells.replace(values=np.where(finite, values, np.float32(0)).astype(VALUE_DTYPE))
    keep = finite.all(axis=0)
    return cells.replace(
        lower_lattice=np.ascontiguousarray(cells.lower_lattice[keep]),
        level=np.ascontiguousarray(cells.level[keep]),
        values=np.ascontiguousarray(cells.values[:, keep]),
    )


@numba.njit(cache=True)
def _first_bad_level(level, max_level):
    for i in range(level.shape[0]):
        if level[i] < 0 or level[i] > max_level:
            return i
    return -1


def find_overlap(lower: np.ndarray, level: np.ndarray) -> tuple[int, int] | None:
    """A pair (a, b), a < b, of overlapping cells, or None if all cells are disjoint.

    lower: int32 (N, 3) lower corners, aligned to their level (checked before).
    level: int8 (N,) levels >= 0.
    Among the overlaps found between Morton-order neighbours, the one with the
    smallest b is returned, so a cell that repeats an earlier one is named.
    """
    n = level.shape[0]
    if n < 2:
        return None
    lmin = int(level.min())
    lmax = int(level.max())
    cmin, cmax = _corner_range(lower)
    # Corners relative to a base that is a multiple of the coarsest width, so that every
    # cell stays aligned to its own level (the Morton intervals then nest), in units
    # of the finest width present (exact: every corner is a multiple of 2**lmin).
    cmin = (cmin >> lmax) << lmax
    bits = max(int(((cmax - cmin) >> lmin).max()).bit_length(), 1)
    index_bits = max(int(n - 1).bit_length(), 1)
    if 3 * bits + index_bits <= 64:
        # Morton code and cell index packed in one uint64: np.sort of plain keys is
        # several times faster than np.argsort, and ties stay in index order.
        keys = _packed_morton(lower, cmin, lmin, np.uint64(index_bits))
        keys.sort()
        a, b = neighbour_overlap_keys(keys, np.uint64(index_bits), level, lmin)
    else:
        hi, lo = _morton96(lower, cmin, lmin)
        order = np.lexsort((np.arange(n), lo, hi))
        a, b = _neighbour_overlap(order, lower, level)
    return None if a < 0 else (int(a), int(b))


@numba.njit(cache=True)
def _corner_range(lower):
    """Per-axis min and max of the corners, int64 (3,) each."""
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for a in range(3):
        lo[a] = lower[0, a]
        hi[a] = lower[0, a]
    for i in range(lower.shape[0]):
        for a in range(3):
            v = np.int64(lower[i, a])
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
    return lo, hi


@numba.njit(cache=True, inline="always")
def spread3(v):
    """Bits 0..20 of v moved to positions 0, 3, 6, ... (uint64)."""
    x = v & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@numba.njit(cache=True, inline="always")
def _rel(lower, i, a, cmin, lmin):
    return np.uint64((np.int64(lower[i, a]) - cmin[a]) >> lmin)


@numba.njit(cache=True)
def _packed_morton(lower, cmin, lmin, index_bits):
    """(Morton code of the relative corner << index_bits) | cell index, uint64 (N,)."""
    n = lower.shape[0]
    out = np.empty(n, np.uint64)
    for i in range(n):
        m = (spread3(_rel(lower, i, 0, cmin, lmin))
             | (spread3(_rel(lower, i, 1, cmin, lmin)) << np.uint64(1))
             | (spread3(_rel(lower, i, 2, cmin, lmin)) << np.uint64(2)))
        out[i] = (m << index_bits) | np.uint64(i)
    return out


@numba.njit(cache=True)
def _morton96(lower, cmin, lmin):
    """Morton codes of up to 32-bit relative corners as (high 33 bits, low 63 bits)."""
    n = lower.shape[0]
    hi = np.empty(n, np.uint64)
    lo = np.empty(n, np.uint64)
    s = np.uint64(21)
    for i in range(n):
        x = _rel(lower, i, 0, cmin, lmin)
        y = _rel(lower, i, 1, cmin, lmin)
        z = _rel(lower, i, 2, cmin, lmin)
        lo[i] = spread3(x) | (spread3(y) << np.uint64(1)) | (spread3(z) << np.uint64(2))
        hi[i] = (spread3(x >> s) | (spread3(y >> s) << np.uint64(1))
                 | (spread3(z >> s) << np.uint64(2)))
    return hi, lo


@numba.njit(cache=True)
def neighbour_overlap_keys(keys, index_bits, level, lmin):
    """`_neighbour_overlap` on sorted packed keys: a cell of level l spans 8**(l - lmin) codes."""
    best_a, best_b = -1, -1
    mask = (np.uint64(1) << index_bits) - np.uint64(1)
    for t in range(keys.shape[0] - 1):
        p = np.int64(keys[t] & mask)
        q = np.int64(keys[t + 1] & mask)
        span = np.uint64(1) << np.uint64(3 * (level[p] - lmin))
        if (keys[t + 1] >> index_bits) - (keys[t] >> index_bits) < span:
            a, b = min(p, q), max(p, q)
            if best_b < 0 or b < best_b or (b == best_b and a < best_a):
                best_a, best_b = a, b
    return best_a, best_b


@numba.njit(cache=True)
def _neighbour_overlap(order, lower, level):
    """(a, b) with a < b: the Morton neighbours whose boxes intersect, smallest b first."""
    best_a, best_b = -1, -1
    for t in range(order.shape[0] - 1):
        p, q = order[t], order[t + 1]
        # p comes first in Morton order, so it either contains q's corner or they are
        # disjoint (a container never sorts after a cell it contains, except at an
        # equal corner, where q's corner is p's corner).
        w = np.int64(1) << np.int64(level[p])
        inside = True
        for ax in range(3):
            d = np.int64(lower[q, ax]) - np.int64(lower[p, ax])
            if d < 0 or d >= w:
                inside = False
                break
        if inside:
            a, b = min(p, q), max(p, q)
            if best_b < 0 or b < best_b or (b == best_b and a < best_a):
                best_a, best_b = a, b
    return best_a, best_b


def cell_statistics(cells: Cells) -> dict:
    """Counts for the provenance record: cells, cells per level, levels, lattice bounds.

    One pass over the cells (vectorised NumPy with int64 temporaries takes seconds
    at 2e7 cells).  bounds_lattice: [[x, y, z] lower, [x, y, z] upper], upper exclusive.
    """
    counts, lo, hi = _level_counts_bounds(cells.lower_lattice, cells.level, MAX_LEVEL)
    return {
        "cells": cells.n_cells,
        "cells_per_level": {str(l): int(c) for l, c in enumerate(counts) if c},
        "levels": int(np.count_nonzero(counts)),
        "bounds_lattice": [lo.tolist(), hi.tolist()] if cells.n_cells else [],
    }


@numba.njit(cache=True)
def _level_counts_bounds(lower, level, max_level):
    counts = np.zeros(max_level + 1, np.int64)
    lo = np.full(3, np.iinfo(np.int64).max, np.int64)
    hi = np.full(3, np.iinfo(np.int64).min, np.int64)
    for i in range(level.shape[0]):
        counts[level[i]] += 1
        w = np.int64(1) << np.int64(level[i])
        for a in range(3):
            c = np.int64(lower[i, a])
            lo[a] = min(lo[a], c)
            hi[a] = max(hi[a], c + w)
    return counts, lo, hi


# ---------------------------------------------------------------------------
# derived fields


def add_magnitude(cells: Cells, name: str, components: tuple[str, ...], *, source: str) -> Cells:
    """Append field `name` = sqrt(sum of squares of `components`), computed in float64.

    values: float32 (F + 1, N); the new row is last.
    """
    if name in cells.fields:
        raise ExabricksError(f"{source}: a field named {name!r} exists already")
    if not components:
        raise ExabricksError(f"{source}: magnitude {name!r} needs at least one component")
    rows = []
    for c in components:
        if c not in cells.fields:
            raise ExabricksError(
                f"{source}: no field {c!r} for magnitude {name!r} (fields: {', '.join(cells.fields)})"
            )
        rows.append(cells.values[cells.fields.index(c)].astype(np.float64))
    mag = np.sqrt(sum(r * r for r in rows)).astype(VALUE_DTYPE)
    return cells.replace(fields=(*cells.fields, name), values=np.vstack([cells.values, mag[None]]))


FUNCTIONS = {
    **dict.fromkeys(("abs", "arccos", "arccosh", "arcsin", "arcsinh", "arctan", "arctanh",
                     "ceil", "cos", "cosh", "exp", "expm1", "floor", "isfinite", "isinf",
                     "isnan", "log", "log10", "log1p", "log2", "ones_like", "round", "sign",
                     "signbit", "sin", "sinh", "sqrt", "tan", "tanh", "trunc"), 1),
    **dict.fromkeys(("arctan2", "copysign", "fmod", "hypot", "maximum", "minimum",
                     "nextafter"), 2),
    "where": 3,
}
"""The functions a derived field's expression may call, with their argument counts:
numexpr's element-wise real functions.  Its reductions (sum, prod, min, max) give one
value for all cells, and its complex and string functions no real value per cell, so
they are refused as unknown functions."""

_OPERATORS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**",
              ast.Mod: "%", ast.BitAnd: "&", ast.BitOr: "|", ast.BitXor: "^",
              ast.FloorDiv: "//", ast.LShift: "<<", ast.RShift: ">>", ast.MatMult: "@",
              ast.USub: "-", ast.UAdd: "+", ast.Invert: "~", ast.Not: "not",
              ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==",
              ast.NotEq: "!=", ast.In: "in", ast.NotIn: "not in", ast.Is: "is",
              ast.IsNot: "is not"}
# numexpr's `^` is a boolean xor and its `//` a true division: refused, as are the
# operators numexpr lacks.
_REFUSED = {"^": " (** is the power)", "//": " (use floor(a / b))", "not": " (use ~)"}
_ALLOWED = {"+", "-", "*", "/", "**", "%", "&", "|", "~", "<", "<=", ">", ">=", "==", "!="}
_QUOTED = re.compile(r"`([^`]*)`")


@dataclass(frozen=True)
class Expression:
    """A derived field NAME = TEXT, parsed and checked by `parse_expression`.

    fields: the field names the expression reads, in order of first use.
    constants: its numbers (as float64) and truth values, in order.
    program: the numexpr source that computes it: field i renamed `_v{i}`, constant j
             `_c{j}`.  numexpr gets the constants as 0-d arrays, not as literals, so
             that it folds none of them in Python: T / 0 is then inf at every cell (as
             0 / 0 is NaN) instead of a ZeroDivisionError, and no integer overflows.
    """

    name: str
    text: str
    fields: tuple[str, ...]
    constants: tuple[float | bool, ...]
    program: str

    def operands(self, rows: Iterable[np.ndarray]) -> dict[str, np.ndarray]:
        """numexpr's local_dict: `rows` (one float64 (N,) array per field) and the constants."""
        named = {f"_v{i}": row for i, row in enumerate(rows)}
        for j, c in enumerate(self.constants):
            named[f"_c{j}"] = np.array(c, np.bool_ if isinstance(c, bool) else np.float64)
        return named


def parse_expression(name: str, text: str, *, source: str) -> Expression:
    """The checked expression of derived field `name` = `text` (no field is looked at yet).

    The language is numexpr's: numbers, field names, + - * / ** %, comparisons
    (< <= > >= == !=, one per pair of operands), & | ~ on comparisons, parentheses and
    calls of FUNCTIONS.  A field whose name is not a Python identifier (x-velocity,
    gas:density) is written between backticks: `x-velocity`.  Everything else
    (attributes, indexing, strings, keywords such as lambda or if, Python's and/or/not)
    is refused.  The text is parsed with `ast` and rewritten, never evaluated by
    Python; numexpr then compiles the rewritten program on a one-cell probe, so a type
    error (& between numbers) is found here too.

    Raises ExabricksError naming `source`, the field and its expression.
    """
    where = _where(source, name, text)
    if not name:
        raise ExabricksError(f"{where}: the field needs a name")
    if "`" in name:
        raise ExabricksError(f"{where}: a field name cannot hold a backtick")
    if not text.strip():
        raise ExabricksError(f"{where}: empty expression")
    prefix = "_q"
    while prefix in text:  # placeholders that no identifier of the text can equal
        prefix += "_"
    quoted: dict[str, str] = {}

    def placeholder(match):
        if not match.group(1):
            raise ExabricksError(f"{where}: empty field name between backticks")
        return " " + quoted.setdefault(match.group(1), f"{prefix}{len(quoted)}") + " "

    body = _QUOTED.sub(placeholder, text).strip()
    if "`" in body:
        raise ExabricksError(f"{where}: unmatched backtick")
    unquote = {v: k for k, v in quoted.items()}
    fields: dict[str, str] = {}
    constants: list[float | bool] = []
    try:
        tree = ast.parse(body, mode="eval")
        program = ast.unparse(_rewrite(tree.body, fields, constants, unquote, where))
    except SyntaxError as e:
        raise ExabricksError(f"{where}: syntax error ({e.msg})") from None
    except (RecursionError, MemoryError, ValueError) as e:
        raise ExabricksError(f"{where}: cannot be parsed ({type(e).__name__}: too long, "
                             "too deeply nested or not text)") from None

    import numexpr

    expression = Expression(name=name, text=text, fields=tuple(fields),
                            constants=tuple(constants), program=program)
    probe = expression.operands(np.zeros(1) for _ in fields)
    problem = numexpr.validate(program, local_dict=probe, global_dict={})
    if problem is not None:
        raise ExabricksError(
            f"{where}: numexpr cannot evaluate it ({type(problem).__name__}: {problem}; "
            "&, |, ~ and where's condition take comparisons, the rest numbers)"
        )
    return expression


def _where(source: str, name: str, text: str) -> str:
    """The start of every message about derived field `name` = `text` (a long text cut)."""
    return f"{source}: derived field {name!r} = {text if len(text) <= 80 else text[:77] + '...'!r}"


def _rewrite(node: ast.expr, fields: dict[str, str], constants: list, unquote: dict[str, str],
             where: str):
    """`node` checked against the language of `parse_expression`, its field names
    renamed `_v{i}` (recorded in `fields`, name -> variable) and its constants `_c{j}`
    (their values appended to `constants`, numbers as floats)."""
    def again(child):
        return _rewrite(child, fields, constants, unquote, where)

    def operator(op):
        text = _OPERATORS.get(type(op), type(op).__name__)
        if text not in _ALLOWED:
            raise ExabricksError(f"{where}: operator {text!r} is not supported"
                                 f"{_REFUSED.get(text, '')}")
        return op

    if isinstance(node, ast.Name):
        field = unquote.get(node.id, node.id)
        return ast.Name(fields.setdefault(field, f"_v{len(fields)}"), ast.Load())
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                value = float(value)
            except OverflowError:
                raise ExabricksError(f"{where}: a number is too large for float64") from None
        if isinstance(value, (bool, float)):
            constants.append(value)
            return ast.Name(f"_c{len(constants) - 1}", ast.Load())
        raise ExabricksError(f"{where}: only real numbers can be constants, not {ast.unparse(node)}")
    if isinstance(node, ast.BinOp):
        return ast.BinOp(again(node.left), operator(node.op), again(node.right))
    if isinstance(node, ast.UnaryOp):
        return ast.UnaryOp(operator(node.op), again(node.operand))
    if isinstance(node, ast.Compare):
        if len(node.ops) != 1:
            raise ExabricksError(f"{where}: chained comparisons are not supported "
                                 "(write (a < b) & (b < c))")
        return ast.Compare(again(node.left), [operator(node.ops[0])], [again(node.comparators[0])])
    if isinstance(node, ast.BoolOp):
        raise ExabricksError(f"{where}: 'and' and 'or' are not supported (use & and | "
                             "between comparisons)")
    if isinstance(node, ast.Call):
        func = node.func
        if isinstance(func, ast.Attribute):
            raise ExabricksError(f"{where}: attribute access {ast.unparse(func)!r} is not allowed")
        if not isinstance(func, ast.Name):
            raise ExabricksError(f"{where}: only functions can be called, not {ast.unparse(func)!r}")
        arity = FUNCTIONS.get(func.id)
        if func.id in ("sum", "prod", "min", "max"):
            raise ExabricksError(f"{where}: {func.id} is a reduction over all cells, not one value "
                                 "per cell (maximum and minimum compare two values per cell)")
        if arity is None:
            raise ExabricksError(f"{where}: unknown function {func.id!r} "
                                 f"(functions: {', '.join(sorted(FUNCTIONS))})")
        if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
            raise ExabricksError(f"{where}: {func.id} takes plain positional arguments")
        if len(node.args) != arity:
            raise ExabricksError(f"{where}: {func.id} takes {arity} argument"
                                 f"{'s' * (arity > 1)}, not {len(node.args)}")
        return ast.Call(ast.Name(func.id, ast.Load()), [again(a) for a in node.args], [])
    if isinstance(node, ast.Attribute):
        raise ExabricksError(f"{where}: attribute access {ast.unparse(node)!r} is not allowed")
    if isinstance(node, ast.Subscript):
        raise ExabricksError(f"{where}: indexing {ast.unparse(node)!r} is not allowed")
    if isinstance(node, ast.IfExp):
        raise ExabricksError(f"{where}: 'if ... else' is not supported (use where(condition, a, b))")
    raise ExabricksError(f"{where}: {ast.unparse(node)!r} ({type(node).__name__}) is not allowed")


def _expressions(derive, taken: list[str], *, source: str) -> list[Expression]:
    """The parsed (NAME, EXPR) pairs or mapping `derive`; `taken`: the names that the
    magnitudes take first."""
    pairs = list(derive.items()) if isinstance(derive, Mapping) else list(derive)
    out: list[Expression] = []
    taken = list(taken)
    for pair in pairs:
        if isinstance(pair, (str, bytes)) or len(pair) != 2 \
                or not all(isinstance(p, str) for p in pair):
            raise ExabricksError(f"{source}: a derived field is a (NAME, EXPRESSION) pair of "
                                 f"strings, not {pair!r}")
        e = parse_expression(*pair, source=source)
        if e.name in taken:
            raise ExabricksError(f"{_where(source, e.name, e.text)}: a field named {e.name!r} "
                                 "exists already")
        taken.append(e.name)
        out.append(e)
    return out


def check_expression_fields(expression: Expression, known: Iterable[str], *, source: str) -> None:
    """Refuse `expression` when its name is one of the fields `known` (at that point) or it
    reads one that is not; the message lists `known`."""
    known = list(known)
    where = _where(source, expression.name, expression.text)
    if expression.name in known:
        raise ExabricksError(f"{where}: a field named {expression.name!r} exists already")
    missing = [f for f in expression.fields if f not in known]
    if missing:
        raise ExabricksError(f"{where}: unknown field {missing[0]!r} "
                             f"(fields: {', '.join(known) or 'none'})")


def add_derived(cells: Cells, expression: Expression, *, source: str) -> Cells:
    """Append field expression.name = the expression at every cell, computed in float64.

    values: float32 (F + 1, N); the new row is last.  A comparison gives 1.0 or 0.0, an
    expression that reads no field (a constant) the same value at every cell; inf and
    NaN (a division by zero, the log of a negative) are stored as they are, for
    `validate_cells`'s NaN policy to handle.
    """
    import numexpr

    check_expression_fields(expression, cells.fields, source=source)
    local = expression.operands(cells.values[cells.fields.index(f)].astype(np.float64)
                                for f in expression.fields)
    where = _where(source, expression.name, expression.text)
    try:
        result = np.asarray(numexpr.evaluate(expression.program, local_dict=local, global_dict={}))
    except Exception as e:  # parse_expression's probe passed; what is left is e.g. memory
        raise ExabricksError(f"{where}: numexpr failed ({type(e).__name__}: {e})") from e
    if result.shape not in ((), (cells.n_cells,)) or result.dtype.kind not in "biuf":
        raise ExabricksError(f"{where}: {result.dtype} of shape {result.shape}, not one real "
                             "value per cell")
    with np.errstate(over="ignore"):  # beyond float32: inf, like the readers
        row = np.broadcast_to(result.astype(np.float64), (cells.n_cells,)).astype(VALUE_DTYPE)
    return cells.replace(fields=(*cells.fields, expression.name),
                         values=np.vstack([cells.values, row[None]]))


# ---------------------------------------------------------------------------
# uniform volume -> AMR


def amr_from_uniform(
    volume: np.ndarray, *, max_level: int | None = None, threshold: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge homogeneous 2x2x2 groups of a uniform volume into coarser cells, level by level.

    volume: (Z, Y, X) array (x fastest, C order) of float32 or float64 voxel values;
            voxel (i, j, k) = volume[k, j, i] becomes the level-0 cell at lattice (i, j, k).
    max_level: the coarsest level to create (None: as coarse as the dims allow).
    threshold: absolute; an aligned group of 8 cells of level l becomes one cell of
            level l + 1 when all 8 are themselves merged cells (or voxels) and
            max - min over all voxels they cover is <= threshold.  Non-finite
            voxels never merge.  Cells at a ragged edge (dims not multiples of
            2**(l+1)) that cannot form a full aligned group stay at level l.
    Returns lower_lattice int32 (N, 3), level int8 (N,), values float32 (N,): each
    value is the mean of the voxels the cell covers (computed in float64).  Cells
    come coarsest level first, each level in z, y, x order.
    """
    volume = np.asarray(volume)
    if volume.ndim != 3 or min(volume.shape) < 1:
        raise ExabricksError(f"a uniform volume must be 3-D and non-empty, got shape {volume.shape}")
    if volume.dtype not in (np.float32, np.float64):
        volume = volume.astype(np.float32)
    volume = np.ascontiguousarray(volume)
    possible = int(min(volume.shape)).bit_length() - 1
    top = possible if max_level is None else min(int(max_level), possible)
    if max_level is not None and max_level < 0:
        raise ExabricksError(f"max level must be >= 0, got {max_level}")
    top = min(top, MAX_LEVEL)
    threshold = float(threshold)
    if not threshold >= 0:
        raise ExabricksError(f"threshold must be >= 0, got {threshold}")

    # Level by level: mean, min, max of covered voxels and whether the cell exists
    # as one merged block.  Level 0 is the volume itself (exists where finite).
    means, mins, maxs, merged = [volume], [None], [None], [None]
    for l in range(1, top + 1):
        if l == 1:
            m, lo, hi, ok = _merge_first(volume, threshold)
        else:
            m, lo, hi, ok = _merge_next(means[-1], mins[-1], maxs[-1], merged[-1], threshold)
        if not ok.any():
            break
        means.append(m)
        mins.append(lo)
        maxs.append(hi)
        merged.append(ok)
    top = len(means) - 1

    counts = np.zeros(top + 1, np.int64)
    for l in range(top + 1):
        parent = merged[l + 1] if l < top else np.zeros((0, 0, 0), np.bool_)
        if l == 0:
            counts[l] = _count_leaves_first(volume.shape, parent)
        else:
            counts[l] = _count_leaves(merged[l], parent)
    n = int(counts.sum())
    lower = np.empty((n, 3), LATTICE_DTYPE)
    level = np.empty(n, LEVEL_DTYPE)
    values = np.empty(n, VALUE_DTYPE)
    start = 0
    for l in range(top, -1, -1):
        parent = merged[l + 1] if l < top else np.zeros((0, 0, 0), np.bool_)
        ok = merged[l] if l > 0 else np.ones((0, 0, 0), np.bool_)
        _emit_leaves(means[l], ok, l == 0, parent, l, start, lower, level, values)
        start += int(counts[l])
    return lower, level, values


@numba.njit(cache=True)
def _merge_first(vol, threshold):
    nz, ny, nx = vol.shape[0] // 2, vol.shape[1] // 2, vol.shape[2] // 2
    mean = np.empty((nz, ny, nx), np.float64)
    vmin = np.empty((nz, ny, nx), vol.dtype)
    vmax = np.empty((nz, ny, nx), vol.dtype)
    ok = np.zeros((nz, ny, nx), np.bool_)
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                s = 0.0
                lo = vol[2 * k, 2 * j, 2 * i]
                hi = lo
                good = True
                for c in range(8):
                    v = vol[2 * k + (c >> 2), 2 * j + ((c >> 1) & 1), 2 * i + (c & 1)]
                    if not np.isfinite(v):
                        good = False
                    s += v
                    lo = min(lo, v)
                    hi = max(hi, v)
                mean[k, j, i] = s / 8.0
                vmin[k, j, i] = lo
                vmax[k, j, i] = hi
                ok[k, j, i] = good and (np.float64(hi) - np.float64(lo) <= threshold)
    return mean, vmin, vmax, ok


@numba.njit(cache=True)
def _merge_next(mean0, min0, max0, ok0, threshold):
    nz, ny, nx = mean0.shape[0] // 2, mean0.shape[1] // 2, mean0.shape[2] // 2
    mean = np.empty((nz, ny, nx), np.float64)
    vmin = np.empty((nz, ny, nx), min0.dtype)
    vmax = np.empty((nz, ny, nx), max0.dtype)
    ok = np.zeros((nz, ny, nx), np.bool_)
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                good = True
                s = 0.0
                lo = min0[2 * k, 2 * j, 2 * i]
                hi = max0[2 * k, 2 * j, 2 * i]
                for c in range(8):
                    a, b, d = 2 * k + (c >> 2), 2 * j + ((c >> 1) & 1), 2 * i + (c & 1)
                    if not ok0[a, b, d]:
                        good = False
                    s += mean0[a, b, d]
                    lo = min(lo, min0[a, b, d])
                    hi = max(hi, max0[a, b, d])
                mean[k, j, i] = s / 8.0
                vmin[k, j, i] = lo
                vmax[k, j, i] = hi
                ok[k, j, i] = good and (np.float64(hi) - np.float64(lo) <= threshold)
    return mean, vmin, vmax, ok


@numba.njit(cache=True, inline="always")
def _parent_merged(parent, k, j, i):
    pk, pj, pi = k >> 1, j >> 1, i >> 1
    if pk < parent.shape[0] and pj < parent.shape[1] and pi < parent.shape[2]:
        return parent[pk, pj, pi]
    return False


@numba.njit(cache=True)
def _count_leaves_first(shape, parent):
    n = 0
    for k in range(shape[0]):
        for j in range(shape[1]):
            for i in range(shape[2]):
                if not _parent_merged(parent, k, j, i):
                    n += 1
    return n


@numba.njit(cache=True)
def _count_leaves(ok, parent):
    n = 0
    for k in range(ok.shape[0]):
        for j in range(ok.shape[1]):
            for i in range(ok.shape[2]):
                if ok[k, j, i] and not _parent_merged(parent, k, j, i):
                    n += 1
    return n


@numba.njit(cache=True)
def _emit_leaves(mean, ok, all_ok, parent, lev, start, lower, level, values):
    """Write the cells of level `lev` that exist and whose parent was not merged."""
    t = start
    w = 1 << lev
    for k in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            for i in range(mean.shape[2]):
                if (all_ok or ok[k, j, i]) and not _parent_merged(parent, k, j, i):
                    lower[t, 0] = i * w
                    lower[t, 1] = j * w
                    lower[t, 2] = k * w
                    level[t] = lev
                    values[t] = mean[k, j, i]
                    t += 1
    return t
