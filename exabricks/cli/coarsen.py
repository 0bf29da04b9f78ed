"""`exabricks coarsen CELLS --levels K -o COARSE`: merge fine cells for previews."""

from __future__ import annotations

import click

from .. import schema
from ..errors import ExabricksError
from ..output import check_output
from .options import input_path, output_option


@click.command()
@input_path("cells_path", metavar="CELLS")
@output_option
@click.option("--levels", "levels", type=click.IntRange(min=0), required=True, metavar="K",
              help="Merge cells up to K levels above the finest level present (0: copy unchanged).")
def coarsen(cells_path, output, levels):
    """Merge every complete octet of leaf cells of CELLS into its parent, bottom-up,
    K times: a cells file for fast previews and small test cases.

    A merged cell holds the mean of its 8 children (volume-weighted average), so
    the covered volume and each field's volume integral stay the same; groups
    with a hole or a finer child stay as they are (docs/coarsen.md).
    """
    from ..stages.coarsen import coarsen_cells

    check_output(output, [cells_path])
    cells = schema.load(cells_path, "cells")
    try:
        coarse = coarsen_cells(cells, levels=levels)
    except ExabricksError as e:
        raise ExabricksError(f"{cells_path}: {e}") from e
    meta = schema.make_meta(
        inputs=[cells_path],
        parameters=coarse.meta["parameters"],
        statistics=coarse.meta["statistics"],
    )
    schema.save(output, coarse.replace(meta=meta), inputs=[cells_path])
