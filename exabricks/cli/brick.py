"""`exabricks brick CELLS -o BRICKS`: same-level, fully filled bricks (paper §3.1)."""

from __future__ import annotations

import click

from .. import schema
from ..output import check_output
from ..errors import ExabricksError
from .options import input_path, output_option, piece_option


@click.command()
@input_path("cells_path", metavar="CELLS")
@output_option
@click.option("--max-brick-width", type=click.IntRange(min=1), default=32, show_default=True,
              help="Most cells per axis of a brick (smaller bricks skip space more finely).")
@piece_option
def brick(cells_path, output, max_brick_width, piece):
    """Group the leaf cells of CELLS into bricks of same-level cells (paper §3.1).

    A brick is a full box of cells of one level, at most --max-brick-width cells
    wide per axis; the bricks file holds every cell's values, brick by brick.
    """
    from ..stages.brick import build_bricks  # numba import only when the command runs

    check_output(output, [cells_path])
    cells = schema.load(cells_path, "cells", mapped=True, checked=True, digest=True)
    try:
        bricks = build_bricks(cells, max_brick_width=max_brick_width, piece=piece)
    except ExabricksError as e:
        raise ExabricksError(f"{cells_path}: {e}") from e
    meta = schema.make_meta(
        inputs=[cells_path],
        parameters={"max_brick_width": max_brick_width},
        statistics=bricks.meta["statistics"],
        upstream=cells,
        **{k: v for k, v in bricks.meta.items() if k == "piece"},
    )
    schema.save(output, bricks.replace(meta=meta), inputs=[cells_path])
