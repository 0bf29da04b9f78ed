"""`exabricks surface SOURCE|BRICKS REGIONS BVH --field F --value V -o body.ply`: an
iso-surface of the reconstructed field as a triangle mesh (exabricks.stages.surface,
docs/surface.md)."""

from __future__ import annotations

import logging

import click

from ..util import progress
from ..util.output import check_output
from .options import dataset_arguments, dataset_from, device_option, field_option, finite, output_option

log = logging.getLogger(__name__)


@click.command()
@field_option
@click.option("--value", type=float, required=True, callback=finite, help="The iso-value.")
@click.option("--level", type=click.IntRange(min=0), default=None,
              help="Sample the field on this level's grid of cell centres [default: the finest "
              "whose grid has at most --max-points points].")
@click.option("--max-points", type=click.IntRange(min=8), default=None,
              help="Most grid points to sample [default: 2^27, 512 MiB of samples].")
@click.option("--reconstruction", type=click.Choice(("basis", "nearest")), default="basis",
              show_default=True, help="The field sampled: the paper's continuous blend of cells, or "
              "the containing leaf cell's value.")
@output_option
@device_option
@dataset_arguments
def surface(inputs, field, value, level, max_points, reconstruction, output, device, **options):
    """Write the iso-surface FIELD = VALUE of a SOURCE (anything `ingest` reads, or a
    cells file; built and cached) or of BRICKS REGIONS BVH as a mesh: .ply, .obj or
    .stl (world units; normals toward lower values), for `render --mesh` and for
    other tools. Marching cubes (scikit-image) on the reconstructed field sampled
    at one level's cell centres."""
    from ..stages.surface import MAX_POINTS, iso_mesh, sampling_level, write_mesh

    check_output(output, list(inputs))
    dataset = dataset_from(inputs, options)
    check_output(output, dataset.inputs)
    bricks, regions, bvh = dataset.structures()
    limit = MAX_POINTS if max_points is None else max_points
    grid = sampling_level(bricks, limit, level)
    with progress.bar(total=grid[2][0] * grid[2][1] * grid[2][2], desc="surface", unit="point") as bar:
        mesh = iso_mesh(bricks, regions, bvh, field, value, level=level, max_points=limit,
                        reconstruction=reconstruction, device=device, on_slab=bar.update, grid=grid)
    write_mesh(output, mesh, inputs=dataset.inputs)
    log.info("%s: %s triangles, %s vertices (level %d, a %s grid)", output, f"{len(mesh.faces):,}",
             f"{len(mesh.vertices):,}", mesh.level, " x ".join(map(str, mesh.grid)))
