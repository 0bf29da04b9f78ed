"""`exabricks render BRICKS REGIONS BVH -o IMAGE`: one frame of volumes, iso-surfaces
and slices (paper §4-5; docs/scene.md for the scene file and the flags)."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .. import __version__, schema
from ..errors import ExabricksError
from ..output import check_output
from ..scene import GRADIENTS, MAX_AO_SAMPLES, RECONSTRUCTIONS, SHADING_MODES
from .options import device_option, field_option, finite, input_path, numbers, output_option, size

log = logging.getLogger(__name__)


def _vector(name, nargs=3, metavar="X Y Z", check_finite=True, **kw):
    return click.option(name, type=float, nargs=nargs, default=None, metavar=metavar,
                        callback=finite if check_finite else None, **kw)


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
@_vector("--position", check_finite=False)
@_vector("--look-at", check_finite=False)
@_vector("--up", check_finite=False)
@click.option("--fovy", type=float, callback=finite, default=None, help="Full vertical field of view, degrees.")
@field_option
@click.option("--transfer-function", metavar="PRESET",
              help="ParaView colour-map preset JSON, or a built-in name (default, inferno-shells; "
                   "built-ins are stretched over --range or the field's range).")
@click.option("--colormap", metavar="NAME", help="A matplotlib colormap over --range (default: the field's range).")
@click.option("--range", type=float, callback=finite, nargs=2, default=None, metavar="LO HI",
              help="Data range of the colormap (and rescales a preset file to it).")
@click.option("--opacity", callback=numbers(), metavar="A0,A1,...",
              help="With --colormap: alpha knots spread evenly over the range (default 0,1: a ramp).")
@click.option("--volume/--no-volume", default=None,
              help="Draw the volume layers (default) or none. --field, --transfer-function, --colormap, "
                   "--range, --opacity replace the scene's layers by the one they describe.")
@click.option("--iso", type=float, multiple=True, callback=finite, metavar="VALUE",
              help="Iso-surface of --field (default: the first volume field) at VALUE; repeatable; "
                   "replaces the scene's iso-surfaces.")
@click.option("--iso-color", callback=numbers((3,)), metavar="R,G,B",
              help="Colour of the iso-surfaces, in [0, 1] (default 0.9,0.9,0.9).")
@click.option("--iso-opacity", type=click.FloatRange(0, 1), callback=finite, default=None, metavar="A",
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
@click.option("--lod", type=click.FloatRange(min=0), default=None, callback=finite,
              metavar="PIXELS",
              help="Level of detail: sample each region at the coarsest level whose cells "
                   "project to at most PIXELS pixels (default 0: full resolution).")
@click.option("--gradient", type=click.Choice(GRADIENTS), default=None,
              help="Normals from the analytic gradient (default) or central differences.")
@click.option("--specular", type=click.FloatRange(min=0), default=None, callback=finite,
              help="Blinn-Phong specular weight on surfaces (default 0).")
@click.option("--shininess", type=POSITIVE, default=None, callback=finite,
              help="Blinn-Phong exponent (default 32).")
@click.option("--ao-samples", type=click.IntRange(0, MAX_AO_SAMPLES), default=None,
              help="Ambient-occlusion rays per surface hit (default 0: off).")
@click.option("--ao-distance", type=POSITIVE, default=None, callback=finite,
              help="Length of the ambient-occlusion rays, world units (default: 10 finest cell widths).")
@click.option("--background", callback=numbers((3, 4)), metavar="R,G,B[,A]",
              help="Background colour in [0, 1] (RGB is opaque; default transparent).")
@click.option("--unit-distance", type=float, callback=finite, default=None,
              help="World thickness over which alpha is the opacity (default: the finest cell width).")
@click.option("--size", type=click.IntRange(1, 32768), nargs=2, default=None, metavar="W H",
              help="Image size in pixels (default 512 512).")
@click.option("--spp", type=click.IntRange(1, 4096), default=None, help="Samples per pixel (default 1).")
@click.option("--seed", type=click.IntRange(0, 2**32 - 1), default=None,
              help="Seed of the interleaved jitter and sub-pixel positions (default 0).")
@click.option("--jitter/--no-jitter", default=None,
              help="--no-jitter: no interleaved jitter (rho = 0.5): fully deterministic sample positions.")
@click.option("--sampling-rate", type=POSITIVE, callback=finite, default=None,
              help="Samples per finest cell width of each region (default 2).")
@click.option("--max-opacity", type=click.FloatRange(0, 1, min_open=True), callback=finite, default=None,
              help="Early ray termination threshold (default 0.98; 1 turns it off).")
@click.option("--depth/--no-depth", default=None,
              help="Add a depth channel Z (.exr only): distance to the first opaque surface, else "
                   "where the opacity reaches 0.5.")
@click.option("--camera-path", "path_file", type=click.Path(exists=True, dir_okay=False),
              help="Camera-path JSON (`exabricks camera orbit|path`): draw its frame(s) given by "
                   "--frame or --frames; -o then names frame I by a printf field, e.g. frame_%05d.png.")
@click.option("--frame", "frame", metavar="I", default=None,
              help="With --camera-path: frame I (from 0; negative counts from the end).")
@click.option("--frames", "frames", metavar="A:B", default=None,
              help="With --camera-path: frames A to B-1 (Python slice; 'A:' to the end), one "
                   "upload, one image each.")
@click.option("--mpi-mode", type=click.Choice(("data", "image")), default="data", show_default=True,
              help="Under mpiexec/srun with several ranks: data splits the dataset by space (each "
                   "rank holds a piece; sort-last compositing), image replicates it and splits "
                   "the frame (faster for data that fits every rank).")
@click.option("--memory-budget", "budget", envvar="EXABRICKS_MEMORY_BUDGET", callback=size,
              metavar="SIZE",
              help="Render within SIZE bytes of memory, host and device (e.g. 2G, 512MiB, "
                   "1500000000; K/M/G/T and KiB..TiB are powers of 1024, kB/MB/GB/TB of 1000; "
                   "also $EXABRICKS_MEMORY_BUDGET): data that does not fit is cut into pieces by "
                   "space and streamed from the files, one piece at a time, for the same image.")
@click.option("--progressive", type=POSITIVE, default=None, callback=finite, metavar="SECONDS",
              help="Rewrite the output every SECONDS with the image so far (pieces front to "
                   "back, then more samples per pixel); each rewrite is a whole image.")
@click.option("--time-limit", type=POSITIVE, default=None, callback=finite, metavar="SECONDS",
              help="Stop refining a frame after SECONDS (the first frame counts from the "
                   "start of the command) and write the best image so far; its metadata "
                   "(settings.progress) says what it covers.")
@click.option("--tile", type=click.IntRange(1, 32768), nargs=2, default=None, metavar="W H",
              help="Draw the frame in tiles of W x H pixels, a row of tiles at a time, each "
                   "written to the output file as it is done: only a band of H rows is ever "
                   "in memory (posters far larger than memory; with --memory-budget the "
                   "budget counts the band, not the frame).")
@device_option
def render(bricks_path, regions_path, bvh_path, output, scene_path, camera_path, path_file, frame,
           frames, mpi_mode, budget, progressive, time_limit, tile, device, **flags):
    """Render BRICKS/REGIONS/BVH into an .exr (float RGBA) or .png image."""
    import time

    from ..scene import check_flags

    started = time.perf_counter()

    suffix = Path(output).suffix.lower()
    if suffix not in (".exr", ".png"):
        raise click.BadParameter("the image must end in .exr or .png", param_hint="-o")
    try:
        check_flags(flags)
    except ExabricksError as e:
        raise click.UsageError(str(e)) from None
    _check_path_flags(path_file, frame, frames, camera_path, flags)
    from .. import parallel

    comm = parallel.world()
    steps = {"budget": budget, "progressive": progressive, "time_limit": time_limit,
             "tile": tile}
    job = parallel.agree(comm, _prepare, bricks_path, regions_path, bvh_path, output, scene_path,
                         camera_path, path_file, frame, frames, flags, device, mpi_mode, comm,
                         steps)
    renderer, scene, jobs, inputs, dataset = job
    from .. import progress

    root = comm is None or comm.Get_rank() == 0
    with progress.bar(total=len(jobs), desc="render", unit="frame", disable=not root) as bar:
        for index, cam, image in jobs:
            log.debug("%s: rendering", image)
            frame_scene = scene if cam is None else scene.replace(camera=cam)
            def describe(stats, frame_scene=frame_scene, index=index):
                return _metadata(frame_scene, dataset, path_file, index, stats)

            def write(result, image=image, describe=describe):
                return _write(image, result, describe, inputs)

            if comm is None and tile is not None:
                _render_tiled(renderer, frame_scene, started, image, describe, inputs, **steps)
                started = None  # later frames count their time from their own start
                result = None
            elif comm is None and any(v is not None for v in steps.values()):
                result = _render_steps(renderer, frame_scene, started, write, **steps)
                started = None
            else:
                result = renderer.render_scene(frame_scene)  # None on ranks other than 0
            parallel.agree(comm, write, result)
            bar.update()


def _render_tiled(pieces, scene, started, image, describe, inputs, budget, progressive,
                  time_limit, tile):
    """One frame tile by tile (exabricks.stages.streaming.render_tiled) into a
    FrameFile beside `image`, rewriting the output every `progressive` seconds
    (after the band that passes them) and stopping after `time_limit`."""
    import time

    from ..image_io import FrameFile
    from ..stages.streaming import render_tiled

    s = scene.settings
    now = time.perf_counter()
    deadline = None if time_limit is None else (started or now) + time_limit
    last = [now]
    with FrameFile(image, s.width, s.height, depth=s.depth, background=scene.background) as out:

        def on_band(progress):
            if time.perf_counter() - last[0] >= progressive:
                so_far = {"width": s.width, "height": s.height, "samples": 0,
                          "progress": progress}
                out.write(metadata=describe(so_far), inputs=inputs)
                _log_written(image, so_far)
                last[0] = time.perf_counter()

        stats = render_tiled(pieces, scene, tile, out.put, deadline=deadline,
                             on_band=on_band if progressive is not None else None)
        out.write(metadata=describe(stats), inputs=inputs)
    _log_written(image, stats)


def _render_steps(pieces, scene, started, write, budget, progressive, time_limit, tile):
    """One frame by steps (exabricks.stages.streaming.render_steps), rewriting the
    output every `progressive` seconds and stopping after `time_limit`."""
    import time

    from ..stages.render import RenderResult
    from ..stages.streaming import render_steps

    now = time.perf_counter()
    deadline = None if time_limit is None else (started or now) + time_limit
    last = [now]

    def on_image(rgba, progress):
        if progressive is not None and time.perf_counter() - last[0] >= progressive:
            s = scene.settings
            write(RenderResult(rgba, None, {"width": s.width, "height": s.height, "samples": 0,
                                            "ms": 0.0, "samples_per_second": 0.0,
                                            "device": "", "progress": progress}))
            last[0] = time.perf_counter()

    return render_steps(pieces, scene, deadline=deadline,
                        on_image=on_image if progressive is not None else None)


def _prepare(bricks_path, regions_path, bvh_path, output, scene_path, camera_path, path_file,
             frame, frames, flags, device, mpi_mode, comm, steps):
    """Check the outputs, load the dataset and make the renderer (this rank's share
    under MPI; the pieces of exabricks.stages.streaming for frames by `steps`):
    (renderer, scene, frame jobs, input files, dataset metadata)."""
    from ..scene import scene_file_references, scene_from_options

    inputs = [bricks_path, regions_path, bvh_path, camera_path, flags["transfer_function"], scene_path,
              path_file]
    if scene_path:
        inputs += scene_file_references(scene_path)
    jobs = _frame_jobs(output, path_file, frame, frames)
    for _, _, image in jobs:
        check_output(image, inputs)
    given = [STEP_FLAGS[k] for k, v in steps.items() if v is not None]
    if comm is not None and given:
        raise ExabricksError(f"{', '.join(given)}: not under MPI (the ranks already share the "
                             "data and the frame)")
    if steps["budget"] is not None:
        from ..parallel import load_for
        from ..stages.streaming import Budgeted

        bricks, regions, _ = load_for("data", bricks_path, regions_path, bvh_path)
        scene = scene_from_options(bricks, scene_path=scene_path, camera_path=camera_path,
                                   flags=flags)
        schema.release(bricks)  # the default camera and range read every brick's pages
        _check_depth(scene, output)
        pieces = Budgeted(bricks, regions, scene, steps["budget"], device=device,
                          where=(bricks_path, regions_path), tile=steps["tile"])
        log.info("%s: a memory budget of %s bytes: %d piece(s)", output,
                 f"{steps['budget']:,}", pieces.n_pieces)
        return pieces, scene, jobs, inputs, _dataset(bricks, bricks_path, regions_path, bvh_path)
    if comm is None:
        from ..stages.device_data import load_structures

        bricks, regions, bvh = load_structures(bricks_path, regions_path, bvh_path)
    else:
        from ..parallel import load_for, needs_image_mode

        bricks, regions, bvh = load_for(mpi_mode, bricks_path, regions_path, bvh_path)
    scene = scene_from_options(bricks, scene_path=scene_path, camera_path=camera_path, flags=flags)
    if comm is not None and mpi_mode == "data" and needs_image_mode(scene):
        bricks, regions, bvh = load_for("image", bricks_path, regions_path, bvh_path)
    _check_depth(scene, output)
    dataset = _dataset(bricks, bricks_path, regions_path, bvh_path)
    if comm is None:
        from ..stages.render import Renderer

        renderer = Renderer(bricks, regions, bvh, fields=scene.fields(), device=device)
        if given:
            from ..stages.streaming import Resident

            renderer = Resident(renderer)
    else:
        from ..parallel import ParallelRenderer

        renderer = ParallelRenderer(comm, bricks, regions, bvh, scene, device=device,
                                    mode=mpi_mode, where=(bricks_path, regions_path))
        if renderer.reason and comm.Get_rank() == 0:
            log.info("%s: %s need the whole dataset on every rank: image-parallel (--mpi-mode "
                     "image)", output, renderer.reason)
    return renderer, scene, jobs, inputs, dataset


def _check_depth(scene, output) -> None:
    if scene.settings.depth and Path(output).suffix.lower() == ".png":
        raise ExabricksError(f"{output}: a depth image needs .exr output (PNG has no depth channel)")


def _dataset(bricks, bricks_path, regions_path, bvh_path) -> dict:
    """The metadata's dataset: the three files and the sources of the bricks."""
    return {"bricks": str(bricks_path), "regions": str(regions_path), "bvh": str(bvh_path),
            "source": bricks.meta.get("inputs", [])}


def _metadata(scene, dataset, path_file, index, stats) -> dict:
    """The metadata of a frame: software, camera, dataset, settings (`stats`), scene."""
    from ..scene import scene_to_dict

    metadata = {
        "software": f"exabricks {__version__}",
        "camera": scene.camera.to_dict(),
        "dataset": dataset,
        "settings": stats,
        "scene": scene_to_dict(scene),
    }
    if index is not None:
        metadata["camera_path"] = {"file": str(path_file), "frame": index}
    if scene.volumes:
        metadata["transfer_function"] = scene.volumes[0].transfer_function.to_paraview_dict()
    return metadata


def _write(image, result, describe, inputs) -> None:
    """Write one frame with its metadata, describe(stats) (rank 0: the others have
    no result)."""
    from ..image_io import write_image

    if result is None:
        return
    write_image(image, result.rgba, metadata=describe(result.stats), depth=result.depth,
                inputs=inputs)
    _log_written(image, result.stats)


def _log_written(image, s) -> None:
    progress = s.get("progress")
    if progress and not progress["complete"]:
        log.info("%s: so far %s", image, progress)
        if not s["samples"]:  # a progressive rewrite
            return
    log.info("%s: %dx%d, %s samples, %.1f ms, %.1f M samples/s on %s", image, s["width"],
             s["height"], f"{s['samples']:,}", s["ms"], s["samples_per_second"] / 1e6, s["device"])


CAMERA_FLAGS = ("position", "look_at", "up", "fovy")
STEP_FLAGS = {"budget": "--memory-budget", "progressive": "--progressive",
              "time_limit": "--time-limit", "tile": "--tile"}


def _check_path_flags(path_file, frame, frames, camera_path, flags) -> None:
    """--camera-path takes exactly one of --frame/--frames and no other camera."""
    if path_file is None:
        if frame is not None or frames is not None:
            raise click.UsageError("--frame and --frames need --camera-path")
        return
    if (frame is None) == (frames is None):
        raise click.UsageError("--camera-path needs one of --frame I or --frames A:B")
    given = [f"--{k.replace('_', '-')}" for k in CAMERA_FLAGS if flags.get(k) is not None]
    if camera_path is not None:
        given.insert(0, "--camera")
    if given:
        raise click.UsageError(f"--camera-path sets the camera: drop {', '.join(given)}")


def _frame_jobs(output, path_file, frame, frames):
    """(frame index, camera, image path) of every image to write: one (None, None,
    output) without a camera path."""
    if path_file is None:
        return [(None, None, output)]
    from ..camera_path import parse_frame_range, read_frames

    cameras = read_frames(path_file)
    chosen = parse_frame_range(frame if frame is not None else frames, len(cameras),
                               "--frame" if frame is not None else "--frames")
    named = _numbered(output)
    if named is None and len(chosen) > 1:
        raise click.UsageError(f"{output}: --frames writes {len(chosen)} images: name them by a "
                               "printf field in -o, e.g. frames/frame_%05d.png")
    return [(i, cameras[i], named(i) if named else output) for i in chosen]


def _numbered(output: str):
    """A function frame index -> file name when `output` holds one printf integer field
    (%d, %05d, ...), else None."""
    if "%" not in output:
        return None
    try:
        a, b = output % 0, output % 1
    except (TypeError, ValueError):
        raise click.BadParameter(f"{output!r}: the only printf field allowed is one integer "
                                 "(%d, %05d); write %% for a percent sign", param_hint="-o") from None
    return (lambda i: output % i) if a != b else None
