"""`exabricks regions BRICKS -o REGIONS`: Active Brick Regions (paper §3.2.3)."""

from __future__ import annotations

import click

from .. import schema
from ..output import check_output
from ..errors import ExabricksError
from .options import input_path, output_option


@click.command()
@input_path("bricks_path", metavar="BRICKS")
@output_option
def regions(bricks_path, output):
    """Partition the brick supports into Active Brick Regions."""
    from ..stages.regions import build_regions

    check_output(output, [bricks_path])
    bricks = schema.load(bricks_path, "bricks")
    try:
        result = build_regions(bricks)
    except ExabricksError as e:
        raise ExabricksError(f"{bricks_path}: {e}") from e
    stats = result.meta["statistics"]
    meta = schema.make_meta(
        inputs=[bricks_path],
        statistics=stats,
        # Lets bvh/render/probe check that bricks, regions and BVH belong together.
        consistency={"n_bricks": bricks.n_bricks, "n_regions": result.n_regions},
    )
    schema.save(output, result.replace(meta=meta), inputs=[bricks_path])
