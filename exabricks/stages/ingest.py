"""Ingest stage: read any AMR source into checked leaf cells (DESIGN.md "The
pipeline"): the reader, derived fields, the embedded-boundary mask, field
selection, the checks, and the provenance meta.  `exabricks ingest` only parses
options, calls it and saves the result.  What it applies to the cells is in
exabricks.builders: the cell contract (`cells`), derived fields and the mask
(`derived`), the piece order (`piece_order`); a raw volume's AMR is made by
`builders.uniform`, called by its reader.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import schema
from ..util.constants import AUTO_MASK_FIELD
from ..util.errors import ExabricksError
from ..builders.cells import cell_statistics, validate_cells
from ..builders.derived import add_derived, add_magnitude, apply_mask, check_expression_fields, derived_expressions
from ..builders.piece_order import RUNS_KEY, order_cells
from ..schema import Cells

RAW_DEFAULTS = {"dims": None, "dtype": "float32", "byte_order": "little", "name": "value",
                "max_level": None, "threshold": 0.0}
_RAW_FLAGS = {"dims": "--dims", "max_level": "--max-level", "threshold": "--threshold",
              "dtype": "--dtype", "byte_order": "--byte-order", "name": "--name"}


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
          (exabricks.builders.piece_order; what the `ingest` command writes).
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
    options = _format_options(fmt, source, raw, level_cap, scalars)
    pairs = list(magnitude.items()) if isinstance(magnitude, Mapping) else list(magnitude)
    derived = [(k, tuple(c for c in v.split(",") if c) if isinstance(v, str) else tuple(v))
               for k, v in pairs]
    expressions = derived_expressions(derive, [k for k, _ in derived], source=source)
    if mask is not None and not mask:
        raise ExabricksError(f"{source}: --mask needs a field name")
    _check_names(source, fields, name if fmt == "raw" else None, derived, expressions)
    reads = _Reads.plan(path, fmt, options, fields, derived, expressions, mask, auto_mask)

    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # Readers turn out-of-range values into inf and refuse bad geometry with their
        # own messages; no RuntimeWarning may reach stderr ahead of an error line.
        cells = reads.read(path, fmt, options)
        step()
        cells, n_masked = _fields_made(cells, reads, derived, expressions, fields, auto_mask)
        n_read = cells.n_cells
        cells = validate_cells(cells, source=source, nan_policy=nan_policy)
        step()
        if piece_order:
            cells = order_cells(cells)
            step()

    parameters = _parameters(fmt, fields, nan_policy, reads, auto_mask, options, derived, expressions)
    statistics = {**cell_statistics(cells), "dropped_nonfinite_cells": int(n_read - cells.n_cells),
                  "masked_cells": int(n_masked)}
    return cells.replace(meta=schema.make_meta(
        inputs=cells.meta.get("inputs") or _input_files(path), parameters=parameters,
        statistics=statistics,
        source={k: v for k, v in cells.meta.items() if k not in ("inputs", RUNS_KEY)},
        **({RUNS_KEY: cells.meta[RUNS_KEY]} if piece_order else {}),
    ))


def _fields_made(cells: Cells, reads: _Reads, derived, expressions, fields: list,
                 auto_mask: bool) -> tuple[Cells, int]:
    """`cells` as read, with the magnitudes and derived fields made, the mask
    applied and `fields` selected: (cells, how many the mask dropped)."""
    from .. import readers

    source = reads.source
    for mag_name, comps in derived:
        cells = add_magnitude(cells, mag_name, comps, source=source)
    for e in expressions:
        cells = add_derived(cells, e, source=source)
    if reads.helpers:
        cells = readers.select_fields(cells, [f for f in cells.fields if f not in reads.helpers],
                                      source=source)
    if reads.mask is None and auto_mask and AUTO_MASK_FIELD in cells.fields:
        reads.mask, reads.mask_auto = AUTO_MASK_FIELD, True
    n_masked = 0
    if reads.mask is not None:
        n_before = cells.n_cells
        cells = apply_mask(cells, reads.mask, source=source)
        n_masked = n_before - cells.n_cells
    if fields:
        cells = readers.select_fields(cells, fields, source=source)
    return cells, n_masked


def _check_names(source: str, fields: list, name: str | None, derived, expressions) -> None:
    """The field names given (schema.field_names_problem), each refused naming its
    option before anything is read; a reader's own names are checked with the cells."""
    given = [("--fields", fields), ("--name", [] if name is None else [name]),
             ("--magnitude", [k for k, _ in derived]), ("--derive", [e.name for e in expressions])]
    for flag, names in given:
        schema.check_field_names(names, f"{source}: {flag}")


def _parameters(fmt, fields, nan_policy, reads, auto_mask, options, derived, expressions) -> dict:
    """The ingest parameters recorded in the cells' meta."""
    return {
        "format": fmt, "fields": fields, "nan": nan_policy,
        "mask": reads.mask, "mask_auto": reads.mask_auto,
        **({} if auto_mask else {"no_mask": True}),
        **({"scalars": {k: str(v) for k, v in options["scalars"].items()}}
           if "scalars" in options else {}),
        **({**options, "dims": list(options["dims"])} if fmt == "raw" else {}),
        **({"magnitude": {k: ",".join(c) for k, c in derived}} if derived else {}),
        **({"derive": {e.name: e.text for e in expressions}} if expressions else {}),
        **({"level_cap": options["level_cap"]} if "level_cap" in options else {}),
    }


def _format_options(fmt: str, source: str, raw: dict, level_cap, scalars) -> dict:
    """The reader's own options for format `fmt`; a raw volume's given to another
    format, a level cap to a format other than AMReX's, or scalars to one other than
    ExaJet's are refused."""
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
    return options


@dataclass
class _Reads:
    """What ingest reads of a source: its fields (None: all), the mask field and
    whether the automatic rule chose it, the fields yt derives that only
    expressions read (read, not kept), and a yt dataset loaded once."""

    fields: list | None
    mask: str | None
    mask_auto: bool = False
    helpers: list = field(default_factory=list)
    dataset: object = None
    source: str = ""

    @classmethod
    def plan(cls, path: Path, fmt: str, options: dict, fields: list, derived, expressions,
             mask: str | None, auto_mask: bool) -> _Reads:
        """The reads of `fields` with the magnitudes `derived`, the `expressions` and
        the mask (expressions' unknown names and an unknown mask refused before
        anything is read)."""
        from .. import readers

        source = str(path)
        reads = cls(fields=None, mask=mask, source=source)
        derived_names = {k for k, _ in derived} | {e.name for e in expressions}
        if fmt == "yt":
            from ..readers import yt_bridge

            reads.dataset = yt_bridge.load(path)  # once: its field names and its cells both come from it
        read_fields = [f for f in fields if f not in derived_names]
        if (derived or expressions) and fields:
            # what derived fields are made of must be read even if not kept
            made_of = [c for _, comps in derived for c in comps] + [n for e in expressions for n in e.fields]
            read_fields += [c for c in dict.fromkeys(made_of) if c not in read_fields
                            and c not in derived_names]
        names = None
        if reads.dataset is not None:
            # The index that yt reads anyway tells the on-disk fields, and which of the
            # "TYPE:NAME" fields asked for yt derives.
            refs = [n for e in expressions for n in e.fields]
            names = yt_bridge.field_names(reads.dataset, also=[*read_fields, *refs, *([mask] if mask else [])])
            on_disk = yt_bridge.field_names(reads.dataset)
            if not read_fields and len(names) > len(on_disk):  # all, and some yt derives
                read_fields = list(names)
                reads.helpers = [n for n in names[len(on_disk):] if n != mask]
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
                    reads.mask, reads.mask_auto = AUTO_MASK_FIELD, True
            elif names is not None and mask not in names and mask not in derived_names:
                raise ExabricksError(
                    f"{source}: no field {mask!r} for --mask (fields: {', '.join(names) or 'none'})"
                )
            if reads.mask is not None and reads.mask not in derived_names and read_fields \
                    and reads.mask not in read_fields:
                read_fields.append(reads.mask)
        reads.fields = read_fields or None
        return reads

    def read(self, path: Path, fmt: str, options: dict) -> Cells:
        from .. import readers

        if self.dataset is not None:
            from ..readers import yt_bridge

            return yt_bridge.cells_from_dataset(self.dataset, self.fields, source=self.source)
        return readers.read(path, format=fmt, fields=self.fields, **options)


def _input_files(path: Path) -> list[str]:
    if path.is_dir():
        return sorted(str(p) for p in path.rglob("*") if p.is_file())
    return [str(path)]
