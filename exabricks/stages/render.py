"""A render job: the frames of one `exabricks render` (or `eb.render`) from a
dataset (exabricks.dataset.Dataset: three structure files, or a source) to image
files, by the strategy the options choose (docs/design-scale.md, "Render jobs and
render options"):

- resident: the dataset uploaded once, each frame drawn whole (`Renderer`);
- memory-budgeted: the dataset cut into domains by space and streamed
  (exabricks.engine.streaming.Budgeted) when `budget` is given;
- tiled: the frame drawn a band of tiles at a time into the output file
  (`tile`), progressive rewrites (`progressive`) and a deadline (`time_limit`);
- MPI: when launched under mpiexec/srun with several ranks
  (exabricks.parallel.ParallelRenderer, `mpi_mode`).

`render_job` is the one entry; the command line parses its options and calls it.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from .. import parallel, schema
from ..film import denoise
from ..util.version import __version__
from ..util import progress
from ..util.errors import ExabricksError, UsageError
from ..util.output import check_output

log = logging.getLogger(__name__)

CAMERA_FLAGS = ("position", "look_at", "up", "fovy")
STEP_FLAGS = {"budget": "--memory-budget", "progressive": "--progressive",
              "time_limit": "--time-limit", "tile": "--tile"}


def render_job(dataset, output, *, flags: dict | None = None,
               scene_path=None, camera_path=None, path_file=None, frame=None, frames=None,
               mpi_mode: str = "data", budget: int | None = None, progressive: float | None = None,
               time_limit: float | None = None, tile=None, annotate: bool | None = None,
               title: str | None = None, device=None, started: float | None = None) -> None:
    """Render the frame(s) of the scene that `scene_path`, `camera_path` and `flags`
    (exabricks.scene.options.SCENE_OPTIONS by name) describe over `dataset`
    (exabricks.dataset.Dataset) into `output` (.exr or .png; with a camera path
    `path_file`, frame `frame` or frames `frames` named by a printf field of
    `output`). `budget` (bytes), `progressive` and `time_limit` (seconds),
    `tile` ((W, H) pixels) and `mpi_mode` choose the strategy (module
    docstring); `started` (perf_counter) is when the time limit's clock started.
    `annotate` draws a .png's colour bars, time, scale bar and axes beside the
    frame (exabricks.film.annotate), with `title`.
    UsageError for options that contradict each other, ExabricksError for bad
    data."""
    from ..scene import check_flags
    from ..scene.options import normalised_flags

    started = time.perf_counter() if started is None else started
    flags = normalised_flags(flags)
    if Path(output).suffix.lower() not in (".exr", ".png"):
        raise UsageError("-o: the image must end in .exr or .png")
    try:
        check_flags(flags)
    except ExabricksError as e:
        raise UsageError(str(e)) from None
    _check_path_flags(path_file, frame, frames, camera_path, flags)
    _check_annotate(output, annotate, title, tile)
    comm = parallel.world()
    steps = {"budget": budget, "progressive": progressive, "time_limit": time_limit, "tile": tile}
    renderer, scene, jobs, inputs, described = parallel.agree(
        comm, _prepare, dataset, output, scene_path, camera_path,
        path_file, frame, frames, flags, device, mpi_mode, comm, steps)
    if scene.settings.denoise:
        if tile is not None:
            raise UsageError("--denoise needs the whole frame, not --tile")
        denoise.check()
    root = comm is None or comm.Get_rank() == 0
    with progress.bar(total=len(jobs), desc="render", unit="frame", disable=not root) as bar:
        for index, cam, image in jobs:
            log.debug("%s: rendering", image)
            frame_scene = scene if cam is None else scene.replace(camera=cam)

            def describe(stats, frame_scene=frame_scene, index=index):
                return frame_metadata(frame_scene, described, path_file, index, stats)

            def write(result, image=image, describe=describe, frame_scene=frame_scene):
                finish = _annotated(frame_scene, dataset, title) if annotate else None
                return _write(image, result, describe, inputs, finish, frame_scene)

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


def _render_tiled(domains, scene, started, image, describe, inputs, budget, progressive,
                  time_limit, tile):
    """One frame tile by tile (exabricks.engine.streaming.render_tiled) into a
    FrameFile beside `image`, rewriting the output every `progressive` seconds
    (after the band that passes them) and stopping after `time_limit`."""
    from ..film.annotate import png_backdrop
    from ..engine.streaming import render_tiled
    from ..film.image_io import FrameFile

    s = scene.settings
    now = time.perf_counter()
    deadline = None if time_limit is None else (started or now) + time_limit
    last = [now]
    with FrameFile(image, s.width, s.height, depth=s.depth, background=scene.background,
                   backdrop=png_backdrop(scene)) as out:

        def on_band(progress):
            if time.perf_counter() - last[0] >= progressive:
                so_far = {"width": s.width, "height": s.height, "samples": 0,
                          "progress": progress}
                out.write(metadata=describe(so_far), inputs=inputs)
                _log_written(image, so_far)
                last[0] = time.perf_counter()

        stats = render_tiled(domains, scene, tile, out.put, deadline=deadline,
                             on_band=on_band if progressive is not None else None)
        out.write(metadata=describe(stats), inputs=inputs)
    _log_written(image, stats)


def _render_steps(domains, scene, started, write, budget, progressive, time_limit, tile):
    """One frame by steps (exabricks.engine.streaming.render_steps), rewriting the
    output every `progressive` seconds and stopping after `time_limit`."""
    from ..engine.renderer import RenderResult
    from ..engine.streaming import render_steps

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

    return render_steps(domains, scene, deadline=deadline,
                        on_image=on_image if progressive is not None else None)


def _prepare(dataset, output, scene_path, camera_path, path_file,
             frame, frames, flags, device, mpi_mode, comm, steps):
    """Check the outputs, load the dataset and make the renderer (this rank's share
    under MPI; the domains of exabricks.engine.streaming for frames by `steps`):
    (renderer, scene, frame jobs, input files, dataset metadata)."""
    from ..scene import scene_file_references, scene_from_options

    inputs = [*dataset.inputs, camera_path, flags["transfer_function"],
              None if isinstance(scene_path, dict) else scene_path, path_file]
    if scene_path:
        inputs += scene_file_references(scene_path)
    jobs = _frame_jobs(output, path_file, frame, frames)
    for _, _, image in jobs:
        check_output(image, inputs)
    given = [STEP_FLAGS[k] for k, v in steps.items() if v is not None]
    if comm is not None and given:
        raise ExabricksError(f"{', '.join(given)}: not under MPI (the ranks already share the "
                             "data and the frame)")
    if (steps["budget"] is not None or comm is not None) and dataset.paths is None:
        raise ExabricksError(f"{'--memory-budget' if comm is None else 'MPI'}: reads the structures "
                             "from files by parts: render a source through the cache (not --no-cache)")
    paths = dataset.paths
    if steps["budget"] is not None:
        from ..engine.streaming import Budgeted

        bricks, regions, _ = dataset.load("data")
        scene = scene_from_options(bricks, scene_path=scene_path, camera_path=camera_path,
                                   flags=flags)
        schema.release(bricks)  # the default camera and range read every brick's pages
        _check_depth(scene, output)
        domains = Budgeted(bricks, regions, scene, steps["budget"], device=device,
                          where=paths[:2], tile=steps["tile"])
        log.info("%s: a memory budget of %s bytes: %d domain(s)", output,
                 f"{steps['budget']:,}", domains.n_domains)
        return domains, scene, jobs, inputs, dataset.describe()
    if comm is None:
        bricks, regions, bvh = dataset.structures()
    else:
        from ..engine.partition import needs_image_mode

        bricks, regions, bvh = dataset.load(mpi_mode)
    scene = scene_from_options(bricks, scene_path=scene_path, camera_path=camera_path, flags=flags)
    if comm is not None and mpi_mode == "data" and needs_image_mode(scene):
        bricks, regions, bvh = dataset.load("image")
    _check_depth(scene, output)
    described = dataset.describe()
    if comm is None:
        from ..engine.renderer import Renderer

        renderer = Renderer(bricks, regions, bvh, fields=scene.fields(), device=device)
        if given:
            from ..engine.streaming import Resident

            renderer = Resident(renderer)
    else:
        from ..parallel import ParallelRenderer

        renderer = ParallelRenderer(comm, bricks, regions, bvh, scene, device=device,
                                    mode=mpi_mode, where=paths[:2])
        if renderer.reason and comm.Get_rank() == 0:
            log.info("%s: %s need the whole dataset on every rank: image-parallel (--mpi-mode "
                     "image)", output, renderer.reason)
    return renderer, scene, jobs, inputs, described


def _check_annotate(output, annotate, title, tile) -> None:
    from ..film.layout import checked_title

    if title is not None and not annotate:
        raise UsageError("--title goes with --annotate")
    try:
        checked_title(title)  # now, not after the frame is drawn
    except ExabricksError as e:
        raise UsageError(f"--{e}") from None
    if annotate and Path(output).suffix.lower() != ".png":
        raise UsageError("--annotate draws on a .png; an .exr stays the raw integration")
    if annotate and tile is not None:
        raise UsageError("--annotate draws beside the whole frame, not with --tile")


def _annotated(scene, dataset, title):
    """The frame's pixels -> the annotated picture's (eb.Image.annotated)."""
    from ..film.layout import facts_from_meta
    from ..film.image import Image

    facts = facts_from_meta(dataset.meta)
    return lambda rgba: Image(rgba, scene=scene, facts=facts).annotated(title=title).rgba


def _check_depth(scene, output) -> None:
    if scene.settings.depth and Path(output).suffix.lower() == ".png":
        raise ExabricksError(f"{output}: a depth image needs .exr output (PNG has no depth channel)")


def frame_metadata(scene, dataset, path_file, index, stats) -> dict:
    """The metadata of a frame: software, camera, dataset (Dataset.describe()),
    settings (`stats`), scene, and the camera path's file and frame `index`."""
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


def _write(image, result, describe, inputs, finish=None, scene=None) -> None:
    """Write one frame with its metadata, describe(stats), its pixels through
    `finish` when given (rank 0: the others have no result); a .png over the
    backdrop of `scene` (annotate.png_backdrop)."""
    from ..film.annotate import png_backdrop
    from ..film.image_io import write_image

    if result is None:
        return
    rgba = result.rgba if finish is None else finish(result.rgba)
    write_image(image, rgba, metadata=describe(result.stats), depth=result.depth, inputs=inputs,
                backdrop=png_backdrop(scene))
    _log_written(image, result.stats)


def _log_written(image, s) -> None:
    progress = s.get("progress")
    if progress and not progress["complete"]:
        log.info("%s: so far %s", image, progress)
        if not s["samples"]:  # a progressive rewrite
            return
    log.info("%s: %dx%d, %s samples, %.1f ms, %.1f M samples/s on %s", image, s["width"],
             s["height"], f"{s['samples']:,}", s["ms"], s["samples_per_second"] / 1e6, s["device"])


def _check_path_flags(path_file, frame, frames, camera_path, flags) -> None:
    """--camera-path takes exactly one of --frame/--frames and no other camera."""
    if path_file is None:
        if frame is not None or frames is not None:
            raise UsageError("--frame and --frames need --camera-path")
        return
    if (frame is None) == (frames is None):
        raise UsageError("--camera-path needs one of --frame I or --frames A:B")
    given = [f"--{k.replace('_', '-')}" for k in CAMERA_FLAGS if flags.get(k) is not None]
    if camera_path is not None:
        given.insert(0, "--camera")
    if given:
        raise UsageError(f"--camera-path sets the camera: drop {', '.join(given)}")


def _frame_jobs(output, path_file, frame, frames):
    """(frame index, camera, image path) of every image to write: one (None, None,
    output) without a camera path."""
    if path_file is None:
        return [(None, None, output)]
    from ..picture.camera_path import parse_frame_range, read_frames

    cameras = read_frames(path_file)
    chosen = parse_frame_range(frame if frame is not None else frames, len(cameras),
                               "--frame" if frame is not None else "--frames")
    named = _numbered(output)
    if named is None and len(chosen) > 1:
        raise UsageError(f"{output}: --frames writes {len(chosen)} images: name them by a "
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
        raise UsageError(f"-o {output!r}: the only printf field allowed is one integer "
                         "(%d, %05d); write %% for a percent sign") from None
    return (lambda i: output % i) if a != b else None
