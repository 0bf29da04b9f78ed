"""`exabricks render SOURCE|BRICKS REGIONS BVH -o IMAGE`: one frame of volumes, iso-surfaces
and slices (paper §4-5; docs/scene.md for the scene file and the flags). The
options are declared once in exabricks.scene.options; the job is
exabricks.stages.render."""

from __future__ import annotations

import time

import click

from ..scene.options import FLAGS, JOB_OPTIONS, SCENE_OPTIONS
from .options import dataset_arguments, dataset_from, declared, device_option, output_option


@click.command()
@output_option
@declared(*JOB_OPTIONS[:2])
@declared(*SCENE_OPTIONS)
@declared(*JOB_OPTIONS[2:])
@device_option
@dataset_arguments
def render(inputs, output, device, **options):
    """Render a dataset into an .exr (float RGBA) or .png image: a SOURCE (anything
    `ingest` reads, with its options, or a cells file; its structures are built and
    cached) or the three structure files BRICKS REGIONS BVH."""
    from ..util.errors import UsageError
    from ..stages.render import render_job

    started = time.perf_counter()
    flags = {name: options.pop(name) for name in FLAGS}
    try:
        dataset = dataset_from(inputs, options)
        render_job(dataset, output, flags=flags, device=device, started=started, **options)
    except UsageError as e:  # options that contradict each other: click's usage error
        raise click.UsageError(str(e)) from None
