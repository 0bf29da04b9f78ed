"""`exabricks render BRICKS REGIONS BVH -o IMAGE`: one volume-rendered frame (paper §4-5)."""

from __future__ import annotations

import logging
from pathlib import Path

import click
import numpy as np

from .. import __version__, schema
from ..errors import ExabricksError
from ..output import check_output
from .options import device_option, field_option, input_path, output_option

log = logging.getLogger(__name__)


def _vector(name):
    return click.option(name, type=float, nargs=3, default=None, metavar="X Y Z")


def _alphas(ctx, param, text):
    if text is None:
        return None
    try:
        alphas = tuple(float(a) for a in text.split(","))
    except ValueError:
        raise click.BadParameter(f"{text!r} is not a comma-separated list of numbers") from None
    if not all(0.0 <= a <= 1.0 for a in alphas):
        raise click.BadParameter(f"alpha values must lie in [0, 1], got {text}")
    return alphas


def load_scene(bricks_path, regions_path, bvh_path):
    """The three structure files of one dataset, each checked for its kind."""
    return (schema.load(bricks_path, "bricks"), schema.load(regions_path, "regions"),
            schema.load(bvh_path, "bvh"))


def field_range(bricks: schema.Bricks, field: str | None) -> tuple[float, float]:
    """(min, max) of the finite values of `field`; ExabricksError if it has none."""
    values = bricks.values[bricks.field_index(field)]
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        raise ExabricksError(f"field {field or bricks.fields[0]!r} has no finite values")
    return float(finite.min()), float(finite.max())


def choose_transfer_function(bricks, field, preset, colormap, value_range, opacity):
    """The transfer function the options ask for (see `render --help`)."""
    from ..transfer_function import (
        TransferFunction, builtin_presets, default_transfer_function, preset_path,
        widen_degenerate_range,
    )

    if preset and colormap:
        raise click.UsageError("give --transfer-function or --colormap, not both")
    data_range = value_range or widen_degenerate_range(field_range(bricks, field))
    if colormap:
        return TransferFunction.from_colormap(colormap, data_range, opacity=opacity or (0.0, 1.0))
    if opacity:
        raise click.UsageError("--opacity goes with --colormap")
    if preset is None:
        return default_transfer_function(data_range)
    if not Path(preset).exists() and preset in builtin_presets():
        # Built-in presets are shapes over [0, 1]: stretch them over the data (ParaView's rescale).
        return TransferFunction.from_paraview(preset_path(preset)).rescaled(data_range)
    tf = TransferFunction.from_paraview(preset)
    return tf.rescaled(value_range) if value_range else tf


@click.command()
@input_path("bricks_path", metavar="BRICKS")
@input_path("regions_path", metavar="REGIONS")
@input_path("bvh_path", metavar="BVH")
@output_option
@click.option("--camera", "camera_path", type=click.Path(exists=True, dir_okay=False),
              help='Camera JSON {"position", "look_at", "up", "fovy"} (world units; default: '
                   "a three-quarter view of the whole dataset).")
@_vector("--position")
@_vector("--look-at")
@_vector("--up")
@click.option("--fovy", type=float, default=None, help="Full vertical field of view, degrees.")
@click.option("--transfer-function", "preset", metavar="PRESET",
              help="ParaView colour-map preset JSON, or a built-in name (default, inferno-shells; "
                   "built-ins are stretched over --range or the field's range).")
@click.option("--colormap", metavar="NAME", help="A matplotlib colormap over --range (default: the field's range).")
@click.option("--range", "value_range", type=float, nargs=2, default=None, metavar="LO HI",
              help="Data range of the colormap (and rescales a preset file to it).")
@click.option("--opacity", callback=_alphas, metavar="A0,A1,...",
              help="With --colormap: alpha knots spread evenly over the range (default 0,1: a ramp).")
@field_option
@click.option("--unit-distance", type=float, default=None,
              help="World thickness over which alpha is the opacity (default: the finest cell width).")
@click.option("--size", type=click.IntRange(1, 32768), nargs=2, default=(512, 512), metavar="W H",
              show_default=True)
@click.option("--spp", type=click.IntRange(1, 4096), default=1, show_default=True, help="Samples per pixel.")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=0, show_default=True,
              help="Seed of the interleaved jitter and sub-pixel positions.")
@click.option("--no-jitter", is_flag=True, help="No interleaved jitter (rho = 0.5): fully deterministic sample positions.")
@click.option("--sampling-rate", type=click.FloatRange(min=0, min_open=True), default=2.0, show_default=True,
              help="Samples per finest cell width of each region.")
@click.option("--max-opacity", type=click.FloatRange(0, 1, min_open=True), default=0.98, show_default=True,
              help="Early ray termination threshold (1 turns it off).")
@click.option("--shading", type=click.Choice(["headlight", "none"]), default="headlight", show_default=True,
              help="headlight: diffuse term from the analytic gradient; none: emission-absorption only.")
@click.option("--depth", is_flag=True, help="Add a depth channel Z (.exr only): distance where opacity reaches 0.5.")
@device_option
def render(bricks_path, regions_path, bvh_path, output, camera_path, position, look_at, up, fovy,
           preset, colormap, value_range, opacity, field, unit_distance, size, spp, seed,
           no_jitter, sampling_rate, max_opacity, shading, depth, device):
    """Volume-render BRICKS/REGIONS/BVH into an .exr (float RGBA) or .png image."""
    from ..camera import Camera, default_camera
    from ..image_io import write_image
    from ..stages.render import render as render_frame

    if Path(output).suffix.lower() not in (".exr", ".png"):
        raise click.BadParameter("the image must end in .exr or .png", param_hint="-o")
    inputs = [bricks_path, regions_path, bvh_path, camera_path, preset]
    check_output(output, inputs)
    bricks, regions, bvh = load_scene(bricks_path, regions_path, bvh_path)
    field = bricks.fields[bricks.field_index(field)]
    if camera_path:
        camera = Camera.from_json(camera_path)
    else:
        camera = default_camera(*schema.world_bounds(regions))
    camera = camera.with_overrides(position=position, look_at=look_at, up=up, fovy=fovy)
    tf = choose_transfer_function(bricks, field, preset, colormap, value_range, opacity)
    result = render_frame(
        bricks, regions, bvh, camera=camera, transfer_function=tf, field=field,
        width=size[0], height=size[1], sampling_rate=sampling_rate, spp=spp, seed=seed,
        jitter=not no_jitter, max_opacity=max_opacity, unit_distance=unit_distance,
        shading=shading, depth=depth, device=device)
    metadata = {
        "software": f"exabricks {__version__}",
        "camera": camera.to_dict(),
        "transfer_function": tf.to_paraview_dict(),
        "dataset": {"bricks": str(bricks_path), "regions": str(regions_path), "bvh": str(bvh_path),
                    "source": bricks.meta.get("inputs", [])},
        "settings": result.stats,
    }
    write_image(output, result.rgba, metadata=metadata, depth=result.depth, inputs=inputs)
    s = result.stats
    log.info("%s: %dx%d, %s samples, %.1f ms, %.1f M samples/s on %s", output, s["width"],
             s["height"], f"{s['samples']:,}", s["ms"], s["samples_per_second"] / 1e6, s["device"])
