"""`exabricks coarsen INPUT --levels K -o COARSE`: merge fine cells for previews."""

from __future__ import annotations

from pathlib import Path

import click

from ..util import progress
from .. import schema
from ..util.errors import ExabricksError
from ..util.output import check_output
from .options import output_option


@click.command()
@click.argument("input_path", metavar="INPUT", type=click.Path(exists=True, path_type=Path))
@output_option
@click.option("--levels", "levels", type=click.IntRange(min=0), required=True, metavar="K",
              help="Merge cells up to K levels above the finest level present (0: copy unchanged).")
@click.option("--field", "fields", multiple=True, metavar="NAME",
              help="AMReX plotfile INPUT: keep only this field (repeatable; default: all).")
def coarsen(input_path, output, levels, fields):
    """Merge every complete octet of leaf cells of INPUT into its parent, bottom-up,
    K times: a cells file for fast previews and small test cases.

    INPUT is a cells file, or an AMReX plotfile directory, whose stored covered
    data is then used as it is (the finer levels are not read).  A merged cell
    holds the mean of its 8 children (volume-weighted average), so the covered
    volume and each field's volume integral stay the same; groups with a hole or a
    finer child stay as they are (docs/coarsen.md).
    """
    from ..stages.coarsen import coarsen_cells, coarsen_plotfile

    check_output(output, [input_path])
    plotfile = input_path.is_dir()  # the reader refuses a directory that is not one
    if fields and not plotfile:
        raise click.UsageError("--field applies to an AMReX plotfile INPUT; a cells file "
                               "keeps its fields")
    try:
        if plotfile:
            with progress.bar(total=1, desc="coarsen", unit="step") as bar:
                coarse = coarsen_plotfile(input_path, levels=levels, fields=fields)
                bar.update()
            schema.save(output, coarse, inputs=[input_path])
            return
        cells = schema.load(input_path, "cells", digest=True)
        coarse = coarsen_cells(cells, levels=levels)
    except ExabricksError as e:
        if str(e).startswith(str(input_path)):
            raise
        raise ExabricksError(f"{input_path}: {e}") from e
    meta = schema.make_meta(
        inputs=[input_path],
        parameters=coarse.meta["parameters"],
        statistics=coarse.meta["statistics"],
        upstream=cells,
    )
    schema.save(output, coarse.replace(meta=meta), inputs=[input_path])
