"""`exabricks series 'run/plt*' -o frames [--movie movie.mp4]`: every step of a time
series drawn with one scene, and the movie (exabricks.series.render_series; the
scene options are render's, declared once in exabricks.scene.options)."""

from __future__ import annotations

import click

from ..scene.options import SCENE_OPTIONS
from .options import (cache_option, declared, device_option, fps_option, ingest_given, ingest_kwargs,
                      ingest_options)


@click.command()
@click.argument("steps", nargs=-1, required=True, metavar="STEPS...")
@click.option("-o", "--output", "directory", required=True, type=click.Path(file_okay=False),
              help="Folder of the frames (STEPNAME.png) and of scene.json, the scene they share.")
@click.option("--movie", default=None, metavar="FILE", type=click.Path(dir_okay=False),
              help="Also the movie of the frames: .mp4 or .gif.")
@fps_option(10.0)
@click.option("--exr", is_flag=True, help="Frames as .exr (float RGBA) instead of .png.")
@declared(*SCENE_OPTIONS)
@device_option
@cache_option
@ingest_options("--fields")
def series(steps, directory, movie, fps, exr, device, cache, **options):
    """Render every step of a time series with one scene: STEPS are sources (anything
    `ingest` reads) or quoted glob patterns ('run/plt*'), taken in natural order.
    A step on the first step's hierarchy (the same leaf cells) is drawn as its
    values on the first step's structures; any other is built through the cache.
    The colours span the field's range over the whole series unless --range or a
    transfer function is given, and one camera (framing what is visible at any
    step, unless --position and --look-at) serves every frame (docs/time-series.md)."""
    from ..series import open_series, render_series

    ingest = ingest_given(ingest_kwargs(options))
    chosen = {name: value for name, value in options.items() if value not in (None, ())}
    render_series(open_series(steps, cache=cache, **ingest), directory, movie=movie, fps=fps,
                  suffix=".exr" if exr else ".png", device=device, **chosen)
