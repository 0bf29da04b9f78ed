"""`exabricks render BRICKS REGIONS BVH -o IMAGE`: one frame of volumes, iso-surfaces
and slices (paper §4-5; docs/scene.md for the scene file and the flags)."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import click

from .. import __version__, schema
from ..errors import ExabricksError
from ..output import check_output
from ..scene import GRADIENTS, MAX_AO_SAMPLES, RECONSTRUCTIONS, SHADING_MODES
from .options import device_option, field_option, input_path, output_option

log = logging.getLogger(__name__)


def _vector(name, nargs=3, metavar="X Y Z", finite=True, **kw):
    return click.option(name, type=float, nargs=nargs, default=None, metavar=metavar,
                        callback=_finite if finite else None, **kw)


def _finite(ctx, param, value):
    """Refuse NaN and infinities in float options (single, nargs or repeatable)."""
    flat = value if isinstance(value, tuple) else (value,)
    flat = [x for v in flat for x in (v if isinstance(v, tuple) else (v,))]
    if any(isinstance(x, float) and not math.isfinite(x) for x in flat):
        raise click.BadParameter("values must be finite numbers")
    return value


def _numbers(counts=None, low=0.0, high=1.0):
    """Callback: comma-separated numbers in [low, high], as many as one of `counts`
    (None: any number)."""
    def parse(ctx, param, text):
        if text is None:
            return None
        try:
            values = tuple(float(a) for a in text.split(","))
        except ValueError:
            raise click.BadParameter(f"{text!r} is not a comma-separated list of numbers") from None
        if counts is not None and len(values) not in counts:
            raise click.BadParameter(f"expected {' or '.join(map(str, counts))} numbers, got {text!r}")
        if not all(low <= a <= high for a in values):
            raise click.BadParameter(f"values must lie in [{low:g}, {high:g}], got {text}")
        return values
    return parse


def load_scene(bricks_path, regions_path, bvh_path):
    """The three structure files of one dataset, each checked for its kind."""
    return (schema.load(bricks_path, "bricks"), schema.load(regions_path, "regions"),
            schema.load(bvh_path, "bvh"))


POSITIVE = click.FloatRange(min=0, min_open=True)


@click.command()
@input_path("bricks_path", metavar="BRICKS")
@input_path("regions_path", metavar="REGIONS")
@input_path("bvh_path", metavar="BVH")
@output_option
@click.option("--scene", "scene_path", type=click.Path(exists=True, dir_okay=False),
              help="Scene JSON (docs/scene.md): camera, volumes, iso-surfaces, slices, clipping, "
                   "lighting, background and settings. Flags override it.")
@click.option("--camera", "camera_path", type=click.Path(exists=True, dir_okay=False),
              help='Camera JSON {"position", "look_at", "up", "fovy"} (world units; default: the '
                   "scene's, else a three-quarter view of the whole dataset).")
# (the camera itself names a non-finite position, look-at or up vector)
@_vector("--position", finite=False)
@_vector("--look-at", finite=False)
@_vector("--up", finite=False)
@click.option("--fovy", type=float, default=None, help="Full vertical field of view, degrees.")
@field_option
@click.option("--transfer-function", metavar="PRESET",
              help="ParaView colour-map preset JSON, or a built-in name (default, inferno-shells; "
                   "built-ins are stretched over --range or the field's range).")
@click.option("--colormap", metavar="NAME", help="A matplotlib colormap over --range (default: the field's range).")
@click.option("--range", type=float, nargs=2, default=None, metavar="LO HI",
              help="Data range of the colormap (and rescales a preset file to it).")
@click.option("--opacity", callback=_numbers(), metavar="A0,A1,...",
              help="With --colormap: alpha knots spread evenly over the range (default 0,1: a ramp).")
@click.option("--volume/--no-volume", default=None,
              help="Draw the volume layers (default) or none. --field, --transfer-function, --colormap, "
                   "--range, --opacity replace the scene's layers by the one they describe.")
@click.option("--iso", type=float, multiple=True, callback=_finite, metavar="VALUE",
              help="Iso-surface of --field (default: the first volume field) at VALUE; repeatable; "
                   "replaces the scene's iso-surfaces.")
@click.option("--iso-color", callback=_numbers((3,)), metavar="R,G,B",
              help="Colour of the iso-surfaces, in [0, 1] (default 0.9,0.9,0.9).")
@click.option("--iso-opacity", type=click.FloatRange(0, 1), default=None, metavar="A",
              help="Opacity of the iso-surfaces (default 1).")
@click.option("--iso-color-field", metavar="NAME", help="Colour the iso-surfaces by this field.")
@click.option("--iso-colormap", metavar="NAME", help="Colormap of --iso-color-field (default viridis).")
@_vector("--iso-range", nargs=2, metavar="LO HI",
         help="Data range of --iso-colormap (default: the colour field's range).")
@_vector("--slice", nargs=6, metavar="PX PY PZ NX NY NZ", multiple=True,
         help="A slice of --field through point P with normal N (world units); repeatable; "
              "replaces the scene's slices.")
@click.option("--slice-colormap", metavar="NAME", help="Colormap of the slices (default viridis).")
@_vector("--slice-range", nargs=2, metavar="LO HI",
         help="Data range of --slice-colormap (default: the slice field's range).")
@_vector("--clip-box", nargs=6, metavar="X0 Y0 Z0 X1 Y1 Z1", help="Keep only the inside of this box.")
@_vector("--clip-plane", nargs=6, metavar="PX PY PZ NX NY NZ", multiple=True,
         help="Keep only the half-space (p - P).N >= 0; repeatable; replaces the scene's planes.")
@click.option("--shading", type=click.Choice(SHADING_MODES), default=None,
              help="headlight (default): diffuse (+ --specular) light from the camera; none: "
                   "emission-absorption only.")
@click.option("--reconstruction", type=click.Choice(RECONSTRUCTIONS), default=None,
              help="basis (default): the paper's continuous blend of cells; nearest: the value "
                   "of the containing leaf cell; vertex: trilinear in stitched vertex values.")
@click.option("--lod", type=click.FloatRange(min=0), default=None, callback=_finite,
              metavar="PIXELS",
              help="Level of detail: sample each region at the coarsest level whose cells "
                   "project to at most PIXELS pixels (default 0: full resolution).")
@click.option("--gradient", type=click.Choice(GRADIENTS), default=None,
              help="Normals from the analytic gradient (default) or central differences.")
@click.option("--specular", type=click.FloatRange(min=0), default=None, callback=_finite,
              help="Blinn-Phong specular weight on surfaces (default 0).")
@click.option("--shininess", type=POSITIVE, default=None, callback=_finite,
              help="Blinn-Phong exponent (default 32).")
@click.option("--ao-samples", type=click.IntRange(0, MAX_AO_SAMPLES), default=None,
              help="Ambient-occlusion rays per surface hit (default 0: off).")
@click.option("--ao-distance", type=POSITIVE, default=None, callback=_finite,
              help="Length of the ambient-occlusion rays, world units (default: 10 finest cell widths).")
@click.option("--background", callback=_numbers((3, 4)), metavar="R,G,B[,A]",
              help="Background colour in [0, 1] (RGB is opaque; default transparent).")
@click.option("--unit-distance", type=float, default=None,
              help="World thickness over which alpha is the opacity (default: the finest cell width).")
@click.option("--size", type=click.IntRange(1, 32768), nargs=2, default=None, metavar="W H",
              help="Image size in pixels (default 512 512).")
@click.option("--spp", type=click.IntRange(1, 4096), default=None, help="Samples per pixel (default 1).")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=None,
              help="Seed of the interleaved jitter and sub-pixel positions (default 0).")
@click.option("--jitter/--no-jitter", default=None,
              help="--no-jitter: no interleaved jitter (rho = 0.5): fully deterministic sample positions.")
@click.option("--sampling-rate", type=POSITIVE, default=None,
              help="Samples per finest cell width of each region (default 2).")
@click.option("--max-opacity", type=click.FloatRange(0, 1, min_open=True), default=None,
              help="Early ray termination threshold (default 0.98; 1 turns it off).")
@click.option("--depth/--no-depth", default=None,
              help="Add a depth channel Z (.exr only): distance to the first opaque surface, else "
                   "where the opacity reaches 0.5.")
@device_option
def render(bricks_path, regions_path, bvh_path, output, scene_path, camera_path, device, **flags):
    """Render BRICKS/REGIONS/BVH into an .exr (float RGBA) or .png image."""
    from ..image_io import write_image
    from ..scene import check_flags, scene_file_references, scene_from_options, scene_to_dict

    suffix = Path(output).suffix.lower()
    if suffix not in (".exr", ".png"):
        raise click.BadParameter("the image must end in .exr or .png", param_hint="-o")
    try:
        check_flags(flags)
    except ExabricksError as e:
        raise click.UsageError(str(e)) from None
    inputs = [bricks_path, regions_path, bvh_path, camera_path, flags["transfer_function"], scene_path]
    if scene_path:
        inputs += scene_file_references(scene_path)
    check_output(output, inputs)
    bricks, regions, bvh = load_scene(bricks_path, regions_path, bvh_path)
    scene = scene_from_options(bricks, scene_path=scene_path, camera_path=camera_path, flags=flags)
    if scene.settings.depth and suffix == ".png":
        raise ExabricksError(f"{output}: a depth image needs .exr output (PNG has no depth channel)")

    from ..stages.render import render_scene

    result = render_scene(bricks, regions, bvh, scene, device=device)
    metadata = {
        "software": f"exabricks {__version__}",
        "camera": scene.camera.to_dict(),
        "dataset": {"bricks": str(bricks_path), "regions": str(regions_path), "bvh": str(bvh_path),
                    "source": bricks.meta.get("inputs", [])},
        "settings": result.stats,
        "scene": scene_to_dict(scene),
    }
    if scene.volumes:
        metadata["transfer_function"] = scene.volumes[0].transfer_function.to_paraview_dict()
    write_image(output, result.rgba, metadata=metadata, depth=result.depth, inputs=inputs)
    s = result.stats
    log.info("%s: %dx%d, %s samples, %.1f ms, %.1f M samples/s on %s", output, s["width"],
             s["height"], f"{s['samples']:,}", s["ms"], s["samples_per_second"] / 1e6, s["device"])
