"""`exabricks ingest INPUT -o cells.npz`: leaf cells of any AMR source, validated."""

from __future__ import annotations

from pathlib import Path

import click

from ..util import progress
from .. import schema
from ..util.output import check_output
from ..stages.ingest import ingest as ingest_stage
from .options import ingest_kwargs, ingest_options, output_option


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@output_option
@ingest_options("--field", "--fields")
def ingest(input_path, output, **options):
    """Read INPUT (ExaJet, AMReX, Athena++, raw volume, or anything yt loads), check
    its leaf cells and write them as an exabricks cells file."""
    kwargs = ingest_kwargs(options)
    scalars = list((kwargs.get("scalars") or {}).values())
    check_output(output, [input_path, *scalars])
    schema.prefetch_sha256([input_path, *scalars])
    with progress.bar(total=4, desc="ingest", unit="step") as bar:
        cells = ingest_stage(input_path, **kwargs, piece_order=True, on_step=bar.update)
        inputs = [entry["path"] for entry in cells.meta.get("inputs", [])]
        schema.save(output, cells, inputs=[input_path, *inputs])
        bar.update()
