"""Time series from Python (docs/time-series.md, "In Python"): `open_series`
takes the steps of a run, `render_series` draws them with one scene and makes
the movie.

    import exabricks as eb
    series = eb.open_series("run/plt*", fields=["phi"])
    eb.render_series(series, "frames", movie="phi.mp4", field="phi")

A step on the first step's hierarchy (the same leaf cells) is its values on the
first step's structures (`exabricks values`, made in memory); any other step is
built through the cache as `eb.open` builds it. Either way it draws what its own
`render SOURCE` draws (docs/time-series.md, "What render --values does").
"""

from __future__ import annotations

import glob
import os
from pathlib import Path

from .dataset import Dataset
from .util.errors import ExabricksError, quoted


class Series:
    """The steps of a time series, in natural order of their names; `series[i]`
    and iteration give each step's Dataset (module docstring).

    Parameters
    ----------
    steps
        The steps' paths, in their order (`open_series` finds them).
    fields, cache, **ingest_options
        As `eb.open`, for every step.

    Raises
    ------
    ExabricksError
        No step.
    """

    def __init__(self, steps, *, fields=None, cache=None, **ingest_options):
        self.steps = tuple(Path(s) for s in steps)
        if not self.steps:
            raise ExabricksError("a series needs at least one step")
        if fields is not None:
            fields = (fields,) if isinstance(fields, str) else tuple(fields)
        self._open = {"fields": fields, "cache": cache, **ingest_options}
        self._first: Dataset | None = None
        self._ranges: dict[str, tuple[float, float]] = {}

    def __len__(self) -> int:
        return len(self.steps)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __getitem__(self, i: int) -> Dataset:
        step = self.steps[i]  # IndexError beyond the last, as a sequence's
        first = self.first
        if step == self.steps[0]:
            return first
        from .dataset import source_cells
        from .builders.values import CellsDiffer
        from .structures import values_of

        options = {k: v for k, v in self._open.items() if k != "cache" and v is not None}
        try:
            cells = self._with_fields_of_first(source_cells(step, options), step)
            values = values_of(cells, first.bricks, [step], where=str(step),
                               bricks_where=str(self.steps[0]))
        except CellsDiffer:
            return self._opened(step)
        about = {"path": str(step), "on_hierarchy_of": str(self.steps[0])}
        if first.paths is None:
            from .builders.values import with_values

            return Dataset(with_values(*first.structures(), values, where=str(step),
                                       bricks_where=str(self.steps[0])), source=about)
        return Dataset(paths=first.paths, values=values, source=about)

    def _with_fields_of_first(self, cells, step: Path):
        """`cells` of `step` with the first step's fields, in its order; a field of
        the first step that `step` lacks is refused naming both (not --field, as
        step_values' message for `exabricks values` says)."""
        from .readers import select_fields

        fields = tuple(self.first.fields)
        missing = [f for f in fields if f not in cells.fields]
        if missing:
            raise ExabricksError(f"{step}: no field {quoted(missing[0])} (its fields: "
                                 f"{', '.join(cells.fields) or 'none'}), which the first step "
                                 f"{self.steps[0]} has")
        return select_fields(cells, fields, source=str(step))

    @property
    def first(self) -> Dataset:
        """The first step's dataset, whose structures serve every step on its hierarchy.

        Returns
        -------
        Dataset
            Opened (built through the cache) at the first use, as `eb.open` with the
            series' options, and kept.

        Raises
        ------
        ExabricksError
            As `eb.open`.
        """
        if self._first is None:
            self._first = self._opened(self.steps[0])
        return self._first

    def _opened(self, step: Path) -> Dataset:
        from .api import open as open_source

        return open_source(step, **{k: v for k, v in self._open.items() if v is not None})

    def field_range(self, field: str) -> tuple[float, float]:
        """(min, max) of the finite values of `field` over every step: the colour
        range that one movie of the series shares.

        Parameters
        ----------
        field
            A field of every step.

        Returns
        -------
        tuple of float
            (min, max), computed once per field (every step is opened) and kept.

        Raises
        ------
        ExabricksError
            A step has no such field, or none of its values finite.
        """
        if field not in self._ranges:
            from .picture.field_statistics import field_range

            lo, hi = float("inf"), float("-inf")
            for dataset in self:
                if field not in dataset.fields:
                    raise ExabricksError(f"{dataset.source.get('path')}: no field {field!r} "
                                         f"(fields: {', '.join(dataset.fields)})")
                a, b = field_range(dataset.bricks, field)
                lo, hi = min(lo, a), max(hi, b)
            self._ranges[field] = (lo, hi)
        return self._ranges[field]

    def __repr__(self) -> str:
        return f"<exabricks.Series of {len(self)} steps: {self.steps[0]} .. {self.steps[-1]}>"


def open_series(steps, *, fields=None, cache=None, **ingest_options) -> Series:
    """The steps of a series: a glob pattern (`"run/plt*"`, matches in natural order
    of their names: plt10 after plt9), a path, or a list of them (each pattern's
    matches in that order), each step anything `eb.open` takes as a source, read
    with the same `fields`, `cache` and ingest options.

    Parameters
    ----------
    steps
        A glob pattern, a path, or a list of them.
    fields, cache, **ingest_options
        As `eb.open`, for every step.

    Returns
    -------
    Series
        No step is opened yet.

    Raises
    ------
    ExabricksError
        A pattern matches nothing, or a path does not exist.
    """
    from .stages.movie import natural_sorted

    found = []
    for given in [steps] if isinstance(steps, (str, os.PathLike)) else list(steps):
        text = os.fspath(given)
        if glob.has_magic(text):
            matched = natural_sorted(glob.glob(text))
            if not matched:
                raise ExabricksError(f"{text}: no steps match")
            found += matched
        elif os.path.lexists(text):
            found.append(text)
        else:
            raise ExabricksError(f"{text}: no such file or directory")
    return Series(found, fields=fields, cache=cache, **ingest_options)


def render_series(series, directory, *, movie=None, fps: float = 10.0, suffix: str = ".png",
                  device: str | None = None, **options) -> list[Path]:
    """Every step of `series` (a Series, or what `open_series` takes) drawn with one
    scene into `directory` (made if missing, also where a dangling symbolic link
    names it) as STEPNAME + `suffix`, and with `movie` (.mp4 or .gif) the movie of
    the frames at `fps`; returns the frames.

    The scene is the first step's, with `options` (eb.render's), its colours over
    the series' range of the field (`Series.field_range`) unless `range` or a
    transfer function is given, one exposure (the first frame's automatic
    exposure, where the scene has one, made fixed), and one camera for every
    step, so that the frames differ by the data alone: unless `position` and
    `look_at` are given, the default view framing what is visible at any step. It is written as
    `directory/scene.json`: `exabricks render STEP --scene scene.json -o FRAME`
    draws each frame again. The range and the framing are passes over every
    step before the frames: `range` and `position` with `look_at` save them.

    Parameters
    ----------
    series
        A Series, or what `open_series` takes (opened with its defaults).
    directory
        The folder of the frames and scene.json. Two steps of one name (run1/plt10,
        run2/plt10) make every frame NNNN-STEPNAME, NNNN its place in the series.
    movie
        The movie's path, .mp4 or .gif (default: no movie).
    fps
        The movie's frames per second (0.01 to 1000).
    suffix
        The frames' format, ".png" or ".exr".
    device
        As `eb.render`.
    **options
        The render flags by their keyword, `-` as `_`, and the scene file's keys, as
        `eb.render` takes them (docs/reference/scene-options.md).

    Returns
    -------
    list of pathlib.Path
        The frames, in the series' order.

    Raises
    ------
    ExabricksError
        `movie` or `fps` is not valid (before any frame is drawn); `directory` is
        not a folder or cannot be made; an output would replace a step's file; a
        step cannot be opened or drawn; an option is not valid.
    TypeError
        An option that is no render flag.
    """
    from .util import progress
    from .api import Renderer
    from .util.output import Inputs, check_output, write_json
    from .scene import scene_to_dict
    from .film.exposure import fixed_exposure
    from .scene.build import default_field
    from .stages.movie import check_fps, make_movie, movie_format

    if movie is not None:  # before any frame is drawn
        movie_format(movie)
        check_fps(fps)
    if not isinstance(series, Series):
        series = open_series(series)
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ExabricksError(f"{directory}: not a directory")
    try:
        # A dangling symbolic link is followed, as exabricks.util.output follows one to
        # a file: the folder it names is made (mkdir of the link itself: FileExistsError).
        Path(os.path.realpath(directory)).mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ExabricksError(f"{directory}: cannot make the folder ({e.strerror or e})") from None
    first = Renderer(series.first, device=device)
    placed = options.get("position") is not None and options.get("look_at") is not None
    if not placed:  # the first step's framing is replaced below: none made
        options = {**options, **_whole_view(series.first)}
    if not any(options.get(k) is not None for k in ("range", "transfer_function")):
        field = options.get("field") or default_field(series.first.fields)
        options = {**options, "range": series.field_range(field)}
    frames = frame_paths(series.steps, directory, suffix)
    steps = Inputs(series.steps)  # every step's files listed once for every output
    for out in [directory / "scene.json", *frames, *([movie] if movie is not None else [])]:
        check_output(out, steps)
    scene = first.scene(**options)
    if not placed and not scene.instances:
        scene = scene.replace(camera=_framed_over(series, scene, options))
    with progress.bar(total=len(series), desc="series", unit="step") as bar:
        for i, dataset in enumerate(series):
            image = (first if i == 0 else Renderer(dataset, device=device)).render(scene)
            if i == 0:  # one exposure for every frame: the first frame's, made fixed
                if scene.settings.auto_exposure:
                    scene = fixed_exposure(scene, image.metadata["settings"]["metered_exposure"])
                write_json(directory / "scene.json", scene_to_dict(scene), inputs=steps)
            image.save(frames[i])
            bar.update()
    if movie is not None:
        make_movie(frames, movie, fps=fps)
    return frames


def frame_paths(steps, directory, suffix: str) -> list[Path]:
    """The frame of each step: DIRECTORY/STEPNAME + `suffix`, or, where two steps
    share a name (run1/plt00010 and run2/plt00010), DIRECTORY/NNNN-STEPNAME for
    every step (NNNN its place in the series), so that no frame replaces another."""
    names = [Path(s).name for s in steps]
    if len(set(names)) < len(names):
        width = max(4, len(str(len(names) - 1)))
        names = [f"{i:0{width}d}-{n}" for i, n in enumerate(names)]
    return [Path(directory) / (n + suffix) for n in names]


def _whole_view(dataset) -> dict:
    """`position` and `look_at` of the default view of the whole domain."""
    from .picture.camera import box_corners
    from .picture.framing import framed_camera

    camera = framed_camera(box_corners(*dataset.bounds))
    return {"position": camera.position, "look_at": camera.look_at}


def _framed_over(series, scene, options):
    """The default three-quarter view framing what the volume layers of `scene`
    make visible at any step of `series` (exabricks.picture.framing), with the `up` and
    `fovy` of `options`."""
    import numpy as np

    from .picture.framing import framed_camera, view_axes, visible_points

    corners = np.concatenate([visible_points(dataset.bricks, scene.volumes, axes=view_axes())
                              for dataset in series])
    s = scene.settings
    camera = framed_camera(corners, aspect=s.width / s.height, fovy=scene.camera.fovy)
    return camera.with_overrides(up=options.get("up"))
