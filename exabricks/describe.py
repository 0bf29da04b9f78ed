"""What `exabricks info` says of a file: an exabricks .npz file's summary
(`schema.summary`, docs/file-formats.md), or the summary of a source, anything
that `render SOURCE` takes (AMReX plotfile, Athena++ .athdf, ExaJet .cells, a raw
volume, whatever yt loads), much as yt's `ds.print_stats()` and `ds.field_list`
show a dataset: its format, simulation time, levels, cells per level, fields with
their ranges and the world bounds.

A source is read into its leaf cells by `ingest`, with the options a source-taking
render takes, exactly as that render reads it (the reader, derived fields, the
mask, the cell checks); no bricks, regions or BVH are built. Unlike render, its
non-finite values are kept and counted (`nan_policy` "keep" unless given).

`describe` is one file's summary, ready for strict JSON (a non-finite number is
None); `field_range` the range of one field over several files, a time series'
fixed transfer-function range.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from . import readers, schema
from .util.errors import ExabricksError

ZIP_MAGIC = b"PK\x03\x04"


def describe(path: str | os.PathLike, options: dict | None = None, *, fields=None) -> dict[str, Any]:
    """The summary of `path`: an exabricks file's (`schema.summary`, with "path"),
    or a source's (kind "source", read with ingest `options`; `fields`: read only
    these). Raises ExabricksError naming `path` for bad input."""
    options = dict(options or {})
    p = Path(path)
    auto = options.get("format", "auto") == "auto"
    if auto and p.suffix.lower() == ".npz":
        return _file_summary(path, options)
    if not p.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    if not (p.is_file() or p.is_dir()):
        from .util.jsonfile import kind_of

        raise ExabricksError(f"{path}: {kind_of(p.stat().st_mode)}, not a regular file or a "
                             "directory (a source is a file or a plotfile directory)")
    if auto:
        fmt = readers.guess_format(p, dims=options.get("dims"), ask_yt=False)
        if fmt is None and p.is_file() and _starts_with(p, ZIP_MAGIC):
            return _file_summary(path, options)  # an exabricks file under another name
        if fmt is None:
            fmt = readers.guess_format(p, dims=options.get("dims"))  # asks yt's front ends
        if fmt is None and p.is_dir():
            raise readers.unknown_format(path)
        if fmt is None:
            try:
                return _file_summary(path, options)
            except ExabricksError as e:
                raise ExabricksError(f"{e}, nor a source that ingest reads (no format claims it; "
                                     "use --format)") from None
        options["format"] = fmt
    return _source_summary(p, str(path), options, fields)


def field_range(paths, field: str, options: dict | None = None) -> tuple[float, float]:
    """(min, max) of `field` over the finite values of every file or source of `paths`
    (sources read with ingest `options`, only that field)."""
    lo, hi = float("inf"), float("-inf")
    for path in paths:
        s = describe(path, options, fields=(field,))
        entry = next((f for f in s["fields"] if f["name"] == field), None)
        if entry is None:
            names = ", ".join(f["name"] for f in s["fields"]) or "none"
            raise ExabricksError(f"{path}: no field {field!r} (fields: {names})")
        if entry["min"] is not None:
            lo, hi = min(lo, entry["min"]), max(hi, entry["max"])
    if lo > hi:
        raise ExabricksError(f"{paths[0]}: field {field!r} has no finite value in any file")
    return lo, hi


def _file_summary(path, options: dict) -> dict[str, Any]:
    if options:
        raise ExabricksError(f"{path}: an exabricks file takes no ingest options "
                             f"({', '.join(sorted(options))}); they are for a source")
    s = schema.summary(schema.load(path))
    s["path"] = str(path)
    return strict_json(s)


def _source_summary(path: Path, where: str, options: dict, fields) -> dict[str, Any]:
    from .stages.ingest import ingest

    if fields:
        options["fields"] = tuple(fields)
    cells = ingest(path, **{"nan_policy": "keep", **options})
    meta = cells.meta
    source = (meta.get("source") or {}).get("source") or {}  # the reader's, under ingest's
    statistics = meta.get("statistics") or {}
    parameters = meta.get("parameters") or {}
    units = source.get("units") or {}
    entries = []
    for name, v in zip(cells.fields, cells.values):
        finite = v[np.isfinite(v)]
        entries.append({
            "name": name,
            "min": float(finite.min()) if finite.size else None,
            "max": float(finite.max()) if finite.size else None,
            "nonfinite": int(v.size - finite.size),
            **({"units": units[name]} if name in units else {}),
        })
    per_level = statistics.get("cells_per_level") or {}
    spacing = cells.spacing_world.astype(np.float64)
    lo, hi = schema.world_bounds(cells)
    mask = parameters.get("mask")
    return strict_json({
        "path": where,
        "kind": "source",
        "format": parameters.get("format"),
        "source": source,
        "time": source.get("time"),
        "levels": int(statistics.get("levels", len(per_level))),
        "counts": {"cells": cells.n_cells, "cells_per_level": per_level},
        "cell_width_per_level": {L: (spacing * 2.0 ** int(L)).tolist() for L in per_level},
        "fields": entries,
        "world_bounds": {"lower": lo, "upper": hi},
        "origin": cells.origin_world.tolist(),
        "spacing": cells.spacing_world.tolist(),
        "masked": ({"field": mask, "cells": int(statistics.get("masked_cells", 0))}
                   if mask is not None else None),
    })


def strict_json(doc):
    """`doc` with every non-finite float as None (strict JSON has no NaN or Infinity)."""
    if isinstance(doc, float):
        return doc if math.isfinite(doc) else None
    if isinstance(doc, dict):
        return {k: strict_json(v) for k, v in doc.items()}
    if isinstance(doc, (list, tuple)):
        return [strict_json(v) for v in doc]
    return doc


def _starts_with(path: Path, magic: bytes) -> bool:
    from .util.jsonfile import open_regular

    try:
        with open_regular(path, "a file") as f:
            return f.read(len(magic)) == magic
    except ExabricksError:
        return False
