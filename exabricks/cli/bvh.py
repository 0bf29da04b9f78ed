"""`exabricks bvh REGIONS -o BVH`: BVH over the Active Brick Regions (paper §3.3)."""

from __future__ import annotations

import click

from .. import schema
from ..util.output import check_output
from ..structures import BINS, LEAF_SIZE
from .options import input_path, output_option, piece_option


@click.command()
@input_path("regions_path", metavar="REGIONS")
@output_option
@click.option("--leaf-size", default=LEAF_SIZE, show_default=True, type=click.IntRange(min=1),
              help="Most regions per BVH leaf.")
@click.option("--bins", default=BINS, show_default=True, type=click.IntRange(min=2),
              help="SAH bins per axis.")
@piece_option
def bvh(regions_path, output, leaf_size, bins, piece):
    """Build a bounding-volume hierarchy with per-node value ranges over the regions."""
    from ..structures import bvh_of

    check_output(output, [regions_path])
    regions = schema.load(regions_path, "regions", mapped=True, checked=True, digest=True)
    bvh = bvh_of(regions, [regions_path], where=regions_path, leaf_size=leaf_size, bins=bins,
                 piece=piece)
    schema.save(output, bvh, inputs=[regions_path])
