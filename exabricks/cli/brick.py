"""`exabricks brick CELLS -o BRICKS`: same-level, fully filled bricks (paper §3.1)."""

from __future__ import annotations

import click

from .. import schema
from ..util.constants import MAX_BRICK_WIDTH
from ..util.errors import ExabricksError
from ..util.output import check_output
from .options import input_path, output_option, piece_option


@click.command()
@input_path("cells_path", metavar="CELLS")
@output_option
@click.option("--max-brick-width", type=click.IntRange(min=1), default=MAX_BRICK_WIDTH, show_default=True,
              help="Most cells per axis of a brick (smaller bricks skip space more finely).")
@piece_option
def brick(cells_path, output, max_brick_width, piece):
    """Group the leaf cells of CELLS into bricks of same-level cells (paper §3.1).

    A brick is a full box of cells of one level, at most --max-brick-width cells
    wide per axis; the bricks file holds every cell's values, brick by brick.
    """
    from ..builders.piece_order import reads_share
    from ..structures import bricks_of  # numba import only when the command runs

    check_output(output, [cells_path])
    # A piece of cells in piece order reads and checks only its share.
    share = reads_share(schema.peek(cells_path)[2], piece, max_brick_width)
    cells = schema.load(cells_path, "cells", mapped=True, checked=not share, digest=True)
    if share != reads_share(cells.meta, piece, max_brick_width):
        raise ExabricksError(f"{cells_path}: was replaced while it was read")
    bricks = bricks_of(cells, [cells_path], where=cells_path, max_brick_width=max_brick_width,
                       piece=piece)
    schema.save(output, bricks, inputs=[cells_path])
