"""`exabricks ingest INPUT -o cells.npz`: leaf cells of any AMR source, validated."""

from __future__ import annotations

from pathlib import Path

import click

from .. import progress, readers, schema
from ..errors import ExabricksError
from ..readers.raw import BYTE_ORDERS, DTYPES
from ..stages.ingest import NAN_POLICIES, add_magnitude, cell_statistics, validate_cells
from .options import output_option


def _name_equals(kind: str):
    def convert(ctx, param, values):
        out = []
        for v in values:
            key, sep, rest = v.partition("=")
            if not sep or not key or not rest:
                raise click.BadParameter(f"{v!r} is not {kind}", ctx=ctx, param=param)
            out.append((key, rest))
        return tuple(out)
    return convert


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@output_option
@click.option("--format", "fmt", type=click.Choice(("auto", *readers.FORMATS)), default="auto",
              show_default=True, help="Input format; auto tells it from the path.")
@click.option("--field", "fields", multiple=True, metavar="NAME",
              help="Keep only this field (repeatable; default: all fields of the input).")
@click.option("--scalars", multiple=True, metavar="NAME=FILE", callback=_name_equals("NAME=FILE"),
              help="exajet: field NAME from FILE (repeatable; default: the STEM.NAME.scalars siblings).")
@click.option("--dims", nargs=3, type=click.IntRange(min=1), default=None, metavar="X Y Z",
              help="raw: voxels per axis, x fastest in the file.")
@click.option("--dtype", type=click.Choice(DTYPES), default="float32", show_default=True,
              help="raw: voxel type.")
@click.option("--byte-order", type=click.Choice(tuple(BYTE_ORDERS)), default="little",
              show_default=True, help="raw: byte order of the voxels.")
@click.option("--name", "raw_name", default="value", show_default=True, help="raw: field name.")
@click.option("--max-level", type=click.IntRange(min=0), default=None,
              help="raw: coarsest level to merge to [default: as coarse as the dims allow].")
@click.option("--threshold", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="raw: a 2x2x2 group merges when max - min of its voxels is at most this "
              "(absolute, in data units).")
@click.option("--magnitude", multiple=True, metavar="NAME=A,B,C",
              callback=_name_equals("NAME=A,B,C"),
              help="Add field NAME = |(A, B, C)| from component fields (repeatable).")
@click.option("--nan", "nan_policy", type=click.Choice(NAN_POLICIES), default="error",
              show_default=True,
              help="NaN/Inf values: error; zero (replace by 0); drop (remove those cells); "
              "keep (store unchanged).")
def ingest(input_path, output, fmt, fields, scalars, dims, dtype, byte_order, raw_name,
           max_level, threshold, magnitude, nan_policy):
    """Read INPUT (ExaJet, AMReX, Athena++, raw volume, or anything yt loads), check
    its leaf cells and write them as an exabricks cells file."""
    source = str(input_path)
    if fmt == "auto":
        fmt = readers.detect_format(input_path, dims=dims)
    options = {}
    raw_given = [flag for flag, given in (
        ("--dims", dims is not None), ("--max-level", max_level is not None),
        ("--threshold", threshold != 0.0), ("--dtype", dtype != "float32"),
        ("--byte-order", byte_order != "little"), ("--name", raw_name != "value")) if given]
    if fmt == "raw":
        options = dict(dims=dims, dtype=dtype, name=raw_name, max_level=max_level,
                       threshold=threshold, byte_order=byte_order)
    elif raw_given:
        raise ExabricksError(f"{source}: {', '.join(raw_given)} only apply to raw volumes, "
                             f"not to {fmt} input")
    if scalars:
        if fmt != "exajet":
            raise ExabricksError(f"{source}: --scalars is for exajet .cells files, not {fmt}")
        options["scalars"] = {k: Path(v) for k, v in scalars}
    derived = {name for name, _ in magnitude}
    read_fields = [f for f in fields if f not in derived]
    if magnitude and read_fields:
        # components of a derived field must be read even if not kept
        read_fields += [c for _, comps in magnitude for c in comps.split(",") if c not in read_fields]

    with progress.bar(total=3, desc="ingest", unit="step") as bar:
        cells = readers.read(input_path, format=fmt, fields=read_fields or None, **options)
        bar.update()
        for name, comps in magnitude:
            cells = add_magnitude(cells, name, tuple(c for c in comps.split(",") if c), source=source)
        if fields:
            cells = readers.select_fields(cells, fields, source=source)
        n_read = cells.n_cells
        cells = validate_cells(cells, source=source, nan_policy=nan_policy)
        bar.update()
        inputs = cells.meta.get("inputs") or _input_files(input_path)
        cells = cells.replace(meta=schema.make_meta(
            inputs=inputs,
            parameters={
                "format": fmt, "fields": list(fields), "nan": nan_policy,
                **({"scalars": {k: str(v) for k, v in options["scalars"].items()}}
                   if "scalars" in options else {}),
                **({"dims": list(dims), "dtype": dtype, "byte_order": byte_order,
                    "name": raw_name, "max_level": max_level, "threshold": threshold}
                   if fmt == "raw" else {}),
                **({"magnitude": {k: v for k, v in magnitude}} if magnitude else {}),
            },
            statistics=_statistics(cells, dropped=n_read - cells.n_cells),
            source={k: v for k, v in cells.meta.items() if k != "inputs"},
        ))
        schema.save(output, cells)
        bar.update()


def _input_files(path: Path) -> list[str]:
    if path.is_dir():
        return sorted(str(p) for p in path.rglob("*") if p.is_file())
    return [str(path)]


def _statistics(cells, dropped: int) -> dict:
    return {**cell_statistics(cells), "dropped_nonfinite_cells": int(dropped)}
