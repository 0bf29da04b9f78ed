"""`exabricks render BRICKS REGIONS BVH -o IMAGE`: one frame of volumes, iso-surfaces
and slices (paper §4-5; docs/scene.md for the scene file and the flags). The
options are declared once in exabricks.scene.options; the job is
exabricks.stages.render."""

from __future__ import annotations

import time

import click

from ..scene.options import FLAGS, JOB_OPTIONS, SCENE_OPTIONS
from .options import declared, device_option, input_path, output_option


@click.command()
@input_path("bricks_path", metavar="BRICKS")
@input_path("regions_path", metavar="REGIONS")
@input_path("bvh_path", metavar="BVH")
@output_option
@declared(*JOB_OPTIONS[:2])
@declared(*SCENE_OPTIONS)
@declared(*JOB_OPTIONS[2:])
@device_option
def render(bricks_path, regions_path, bvh_path, output, device, **options):
    """Render BRICKS/REGIONS/BVH into an .exr (float RGBA) or .png image."""
    from ..errors import UsageError
    from ..stages.render import render_job

    started = time.perf_counter()
    flags = {name: options.pop(name) for name in FLAGS}
    try:
        render_job(bricks_path, regions_path, bvh_path, output, flags=flags, device=device,
                   started=started, **options)
    except UsageError as e:  # options that contradict each other: click's usage error
        raise click.UsageError(str(e)) from None
