"""`exabricks bvh REGIONS -o BVH`: BVH over the Active Brick Regions (paper §3.3)."""

from __future__ import annotations

import click

from .. import schema
from ..output import check_output
from ..errors import ExabricksError
from .options import input_path, output_option, piece_option


@click.command()
@input_path("regions_path", metavar="REGIONS")
@output_option
@click.option("--leaf-size", default=4, show_default=True, type=click.IntRange(min=1),
              help="Most regions per BVH leaf.")
@click.option("--bins", default=16, show_default=True, type=click.IntRange(min=2),
              help="SAH bins per axis.")
@piece_option
def bvh(regions_path, output, leaf_size, bins, piece):
    """Build a bounding-volume hierarchy with per-node value ranges over the regions."""
    from ..stages.bvh import build_bvh

    check_output(output, [regions_path])
    regions = schema.load(regions_path, "regions", mapped=True, checked=True, digest=True)
    check_regions(regions, regions_path)
    try:
        result = build_bvh(regions, leaf_size=leaf_size, bins=bins, piece=piece)
    except ExabricksError as e:
        raise ExabricksError(f"{regions_path}: {e}") from e
    upstream = regions.meta.get("consistency") or {}
    meta = schema.make_meta(
        inputs=[regions_path],
        parameters={"leaf_size": leaf_size, "bins": bins},
        statistics=result.meta["statistics"],
        upstream=regions,
        consistency={
            "n_regions": regions.n_regions,
            "n_bricks": upstream.get("n_bricks"),
            # The bricks file the regions were built from (sha256 chain).
            "bricks_inputs": regions.meta.get("inputs", []),
        },
        **{k: v for k, v in result.meta.items() if k == "piece"},
    )
    schema.save(output, result.replace(meta=meta), inputs=[regions_path])


def check_regions(regions: schema.Regions, path) -> None:
    """Refuse a regions file whose counts disagree with its own provenance."""
    upstream = regions.meta.get("consistency")
    if not isinstance(upstream, dict) or "n_bricks" not in upstream:
        raise ExabricksError(
            f"{path}: regions file has no meta['consistency']['n_bricks']; "
            "rebuild it with `exabricks regions`"
        )
    n_bricks = upstream["n_bricks"]
    if upstream.get("n_regions") != regions.n_regions:
        raise ExabricksError(
            f"{path}: holds {regions.n_regions} regions but its meta records "
            f"{upstream.get('n_regions')}; the file is inconsistent"
        )
    # negative ids are refused by the load already
    ids = regions.brick_ids
    top = schema.reduce_chunks(ids, lambda a: int(a.max()) if a.size else -1, max)
    if top >= n_bricks:
        raise ExabricksError(f"{path}: brick ids reach {top}, beyond the {n_bricks} bricks "
                             "its meta records")
