"""`exabricks camera orbit|path … -o path.json`: camera paths for movies
(exabricks/picture/camera_path.py; docs/workflows.md, "Camera paths")."""

from __future__ import annotations

import click

from ..picture import camera_path
from .. import schema
from ..util.errors import ExabricksError
from ..util.output import check_output, write_output
from ..scene import DEFAULT_FOVY
from .options import finite, input_path, output_option

FRAMES = click.IntRange(1, camera_path.MAX_FRAMES)
FOVY = click.FloatRange(0, 180, min_open=True, max_open=True)


def _write(output, doc, inputs) -> None:
    text = camera_path.dumps(doc)

    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    write_output(output, write, inputs=inputs)


@click.group()
def camera():
    """Write camera paths (JSON) that `render --camera-path` draws frame by frame."""


@camera.command()
@input_path("dataset", metavar="DATASET.npz")
@output_option
@click.option("--frames", "n_frames", type=FRAMES, required=True, help="Number of frames.")
@click.option("--look-at", type=float, callback=finite, nargs=3, default=None, metavar="X Y Z",
              help="The point turned about and looked at (default: the centre of the data).")
@click.option("--axis", type=float, callback=finite, nargs=3, default=None, metavar="X Y Z",
              help="Axis of the turn, also the cameras' up (default 0 1 0, render's default up).")
@click.option("--elevation", type=float, callback=finite, default=None, metavar="DEG",
              help="Angle above the plane perpendicular to the axis (default: that of render's "
                   "default three-quarter view, about 20.8).")
@click.option("--fovy", type=FOVY, callback=finite, default=DEFAULT_FOVY, show_default=True,
              help="Full vertical field of view, degrees (the distance shows the whole data).")
@click.option("--degrees", type=float, callback=finite, default=360.0, show_default=True,
              help="Angle turned over the path (a full turn leaves out its end, which is its start).")
def orbit(dataset, output, n_frames, look_at, axis, elevation, fovy, degrees):
    """N frames turning round DATASET (any exabricks .npz) from render's default view."""
    check_output(output, [dataset])
    lower, upper = schema.world_bounds(schema.load(dataset))
    if not lower:
        raise click.UsageError(f"{dataset}: the dataset is empty: no bounds to orbit")
    frames = camera_path.orbit(lower, upper, n_frames, look_at=look_at, axis=axis,
                               elevation=elevation, fovy=fovy, degrees=degrees)
    source = {"orbit": {"dataset": dataset, "axis": list(axis or (0.0, 1.0, 0.0)),
                        "elevation": elevation, "degrees": degrees}}
    _write(output, camera_path.to_dict(frames, source=source), [dataset])


@camera.command()
@input_path("keyframes_path", metavar="KEYFRAMES.json")
@output_option
@click.option("--frames", "n_frames", type=FRAMES, required=True, help="Number of frames.")
@click.option("--loop/--no-loop", default=None,
              help="Close the path (back to the first keyframe; default: the file's 'loop', else no).")
def path(keyframes_path, output, n_frames, loop):
    """N frames along KEYFRAMES.json: cameras (position, look_at, up, fovy, optional time)
    interpolated by Catmull-Rom splines, up vectors by slerp."""
    check_output(output, [keyframes_path])
    keys, times, file_loop = camera_path.read_keyframes(keyframes_path)
    loop = file_loop if loop is None else loop
    try:
        frames = camera_path.interpolate(keys, times, n_frames, loop=loop)
    except ExabricksError as e:
        raise ExabricksError(f"{keyframes_path}: {e}") from None
    _write(output, camera_path.to_dict(frames, keyframes=keys, times=times, loop=loop,
                                       source={"keyframes": keyframes_path}), [keyframes_path])
