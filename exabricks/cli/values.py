"""`exabricks values SOURCE --bricks BRICKS -o STEP`: one step of a time series on a
fixed hierarchy, for `render BRICKS REGIONS BVH --values STEP` (docs/time-series.md)."""

from __future__ import annotations

from pathlib import Path

import click

from ..util import progress
from .. import schema
from ..util.output import check_output
from .options import ingest_given, ingest_kwargs, ingest_options, output_option


@click.command()
@click.argument("source", metavar="SOURCE", type=click.Path(exists=True, path_type=Path))
@click.option("--bricks", "bricks_path", metavar="BRICKS", required=True,
              type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="The bricks file of another step of the same leaf cells.")
@output_option
@ingest_options("--field", "--fields")
def values(source, bricks_path, output, **options):
    """Write the values of SOURCE (anything `ingest` reads, with its options, or a
    cells file) in the cell order of BRICKS, built from another step of the same
    leaf cells. A step whose cells differ from the bricks' is refused: build its
    structures instead."""
    from ..dataset import source_cells
    from ..structures import values_of

    kwargs = ingest_kwargs(options)
    scalars = list((kwargs.get("scalars") or {}).values())
    check_output(output, [source, bricks_path, *scalars])
    given = ingest_given(kwargs)
    schema.prefetch_sha256([source, bricks_path, *scalars])
    with progress.bar(total=4, desc="values", unit="step") as bar:
        bricks = schema.load(bricks_path, "bricks", mapped=True, checked=True)
        bar.update()
        cells = source_cells(source, given, on_step=bar.update)
        step = values_of(cells, bricks, [source, bricks_path], where=str(source),
                         bricks_where=str(bricks_path))
        schema.save(output, step, inputs=[source, bricks_path, *scalars])
        bar.update()

