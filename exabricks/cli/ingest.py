"""`exabricks ingest INPUT -o cells.npz`: leaf cells of any AMR source, validated."""

from __future__ import annotations

from pathlib import Path

import click

from .. import progress, readers, schema
from ..output import check_output
from ..readers.raw import BYTE_ORDERS, DTYPES
from ..stages.ingest import AUTO_MASK_FIELD, NAN_POLICIES
from ..stages.ingest import ingest as ingest_stage
from .options import finite, output_option


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
@click.option("--threshold", type=click.FloatRange(min=0), callback=finite, default=0.0, show_default=True,
              help="raw: a 2x2x2 group merges when max - min of its voxels is at most this "
              "(absolute, in data units).")
@click.option("--magnitude", multiple=True, metavar="NAME=A,B,C",
              callback=_name_equals("NAME=A,B,C"),
              help="Add field NAME = |(A, B, C)| from component fields (repeatable).")
@click.option("--nan", "nan_policy", type=click.Choice(NAN_POLICIES), default="error",
              show_default=True,
              help="NaN/Inf values: error; zero (replace by 0); drop (remove those cells); "
              "keep (store unchanged).")
@click.option("--mask", "mask", default=None, metavar="FIELD",
              help="Drop the cells where FIELD == 0 (they become holes, e.g. the body of an "
              f"embedded-boundary plotfile). Default: {AUTO_MASK_FIELD} when the input has it.")
@click.option("--no-mask", "no_mask", is_flag=True,
              help=f"Keep every cell: no automatic --mask {AUTO_MASK_FIELD}.")
def ingest(input_path, output, fmt, fields, scalars, dims, dtype, byte_order, raw_name,
           max_level, threshold, magnitude, nan_policy, mask, no_mask):
    """Read INPUT (ExaJet, AMReX, Athena++, raw volume, or anything yt loads), check
    its leaf cells and write them as an exabricks cells file."""
    if mask is not None and no_mask:
        raise click.UsageError("--mask and --no-mask exclude each other")
    check_output(output, [input_path, *(path for _, path in scalars)])
    schema.prefetch_sha256([input_path, *(path for _, path in scalars)])
    with progress.bar(total=3, desc="ingest", unit="step") as bar:
        cells = ingest_stage(
            input_path, format=fmt, fields=fields, scalars=dict(scalars) or None,
            dims=dims, dtype=dtype, byte_order=byte_order, name=raw_name,
            max_level=max_level, threshold=threshold, magnitude=magnitude,
            nan_policy=nan_policy, mask=mask, auto_mask=not no_mask, on_step=bar.update,
        )
        inputs = [entry["path"] for entry in cells.meta.get("inputs", [])]
        schema.save(output, cells, inputs=[input_path, *inputs])
        bar.update()
