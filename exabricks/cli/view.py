"""`exabricks view SOURCE|BRICKS REGIONS BVH [render options]`: a progressive viewer
in the browser (docs/view.md; exabricks.viewer)."""

from __future__ import annotations

import click

from ..scene.options import FLAGS, JOB_OPTIONS, SCENE_OPTIONS
from .options import dataset_arguments, dataset_from, declared, device_option


@click.command()
@declared(*JOB_OPTIONS[:2], *(o for o in JOB_OPTIONS if o.name == "memory_budget"))
@declared(*SCENE_OPTIONS)
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on (loopback only by default; the token still guards it).")
@click.option("--port", type=click.IntRange(0, 65535), default=0, show_default=True,
              help="Port to listen on (0: a free one).")
@click.option("--scene-out", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Where the page's \"Save scene\" writes the scene file on this machine "
              "(the page also downloads it).")
@click.option("--open", "open_browser", is_flag=True, help="Open the page in a browser here.")
@device_option
@dataset_arguments
def view(inputs, device, host, port, scene_out, open_browser, **options):
    """Look at a dataset in the browser: orbit, pick the field, colour map, opacity,
    iso-values, slices and clipping, watch frames refine, and save the scene that
    `render --scene` draws the same. Prints the URL (with its access token) and runs
    until interrupted."""
    import asyncio

    from ..util.output import check_output
    from ..viewer.server import Viewer, serve
    from ..viewer.session import Session

    flags = {name: options.pop(name) for name in FLAGS}
    scene_path, camera_path = options.pop("scene_path"), options.pop("camera_path")
    budget = options.pop("budget")
    dataset = dataset_from(inputs, options)
    if scene_out is not None:
        check_output(scene_out, [*dataset.inputs, scene_path, camera_path])
    given = {k: v for k, v in flags.items() if v is not None and v != ()}
    if camera_path is not None:
        given["camera"] = camera_path
    session = Session(dataset, device=device, scene=scene_path, options=given, budget=budget)
    viewer = Viewer(session, host=host, port=port, scene_out=scene_out)

    def announce(url):
        click.echo(f"exabricks view: {url}", err=True)
        if viewer.warning:
            click.echo(f"exabricks view: warning: {viewer.warning}", err=True)
        click.echo("  (Ctrl-C stops it)", err=True)
        import sys

        sys.stderr.flush()
        if open_browser:
            import webbrowser

            webbrowser.open(url)

    import signal

    from ..util.interrupt import Interrupted

    signum = asyncio.run(serve(viewer, announce))
    if signum != signal.SIGINT:  # Ctrl-C is how one stops it; SIGTERM and SIGHUP say so
        raise Interrupted(signum)
    click.echo("exabricks view: stopped", err=True)
