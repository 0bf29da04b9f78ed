"""`exabricks regions BRICKS -o REGIONS`: Active Brick Regions (paper §3.2.3)."""

from __future__ import annotations

import click

from .. import schema
from ..util.errors import ExabricksError
from ..util.output import check_output
from .options import finite, input_path, output_option, piece_option


@click.command()
@input_path("bricks_path", metavar="BRICKS")
@output_option
@click.option("--exact", is_flag=True,
              help="The paper's exact Active Brick Regions: no merging (one set of active "
              "bricks per region).")
@click.option("--visit-cost", type=float, callback=finite, default=None, metavar="X",
              help="Merging: cost of entering a region, in samples [default: 20; 0: exact].")
@click.option("--brick-cost", type=float, callback=finite, default=None, metavar="X",
              help="Merging: cost of a listed brick per sample, in samples [default: 0.3].")
@click.option("--max-merged", type=int, default=None, metavar="N",
              help="Merging: a piece with more bricks is always split [default: 64].")
@click.option("--max-brick-cells", type=int, default=None, metavar="N",
              help="Merging: a piece with a brick of more cells is always split "
              "[default: 512].")
@piece_option
def regions(bricks_path, output, exact, visit_cost, brick_cost, max_merged, max_brick_cells,
            piece):
    """Partition the brick supports into Active Brick Regions.

    By default pieces of the partition whose rays would cost more split than
    whole are kept whole, with the union of their bricks (docs/design-structures.md
    "Merged regions"): far fewer, larger regions on octree-like data.
    """
    from ..builders.regions import EXACT, Merge
    from ..structures import regions_of

    check_output(output, [bricks_path])
    given = [name for name, v in (("--visit-cost", visit_cost), ("--brick-cost", brick_cost),
                                  ("--max-merged", max_merged),
                                  ("--max-brick-cells", max_brick_cells)) if v is not None]
    if exact and given:
        raise click.UsageError(f"--exact excludes {', '.join(given)}")
    default = Merge()
    try:
        merge = EXACT if exact else Merge(
            visit_cost=default.visit_cost if visit_cost is None else visit_cost,
            brick_cost=default.brick_cost if brick_cost is None else brick_cost,
            max_bricks=default.max_bricks if max_merged is None else max_merged,
            max_brick_cells=default.max_brick_cells if max_brick_cells is None
            else max_brick_cells,
        )
    except ExabricksError as e:
        raise click.UsageError(str(e)) from None
    # A piece checks every brick but reads the values of its own regions only
    # (docs/design-structures.md, "Builders by pieces"): no CRC of the whole values member.
    bricks = schema.load(bricks_path, "bricks", mapped=True, checked=piece.whole, digest=True)
    if not piece.whole:
        schema.validate(bricks, str(bricks_path))
    regions = regions_of(bricks, [bricks_path], where=bricks_path, merge=merge, piece=piece)
    schema.save(output, regions, inputs=[bricks_path])
