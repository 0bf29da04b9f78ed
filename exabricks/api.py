"""The Python library (DESIGN.md "The Python library"; docs/python.md): the engine
of the commands, with the same names.

    import exabricks as eb
    ds = eb.open("plt00020")                       # a source, three files, or a yt dataset
    image = eb.render(ds, field="phi", colormap="inferno", size=(512, 512))
    image.save("phi.png")                          # or display it in a notebook

Options are the render flags' names with `_` for `-` (`field`, `colormap`,
`range`, `opacity`, `iso`, `size`, `spp`, ...) and the scene file's keys
(`camera`, `volumes`, `isosurfaces`, `slices`, `clip`, `lighting`); they are
checked as the command line checks them and override `scene` as flags override
a scene file, so a scene gives the same pixels as `render --scene`. Errors are
`ExabricksError` with the commands' one-line messages.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .dataset import Dataset
from .util.errors import ExabricksError
from .film.image import Image
from .scene import Scene

# The scene file's keys that are not also render flags: they go into the scene object.
SCENE_KEYS = ("camera", "volumes", "isosurfaces", "slices", "clip", "lighting")


def open(source, *, fields: Sequence | None = None, cache: str | os.PathLike | bool | None = None,
         values: str | os.PathLike | None = None, **ingest_options) -> Dataset:
    """A dataset to render or probe.

    Parameters
    ----------
    source
        A path that `ingest` reads (AMReX plotfile directory, Athena++ .athdf,
        Enzo, FLASH, ExaJet .cells, raw volume, ...) or a cells file, built with
        `ingest`'s options (`format`, `scalars`, `magnitude`, `derive`, `mask`,
        `auto_mask`, `nan_policy`, `dims`, ...) and the builders' defaults; a
        `(bricks, regions, bvh)` triple of structure files; a yt dataset object
        (`yt.load(...)`), whose `fields` may name yt's derived fields
        (`("gas", "vorticity_magnitude")`); or a Dataset (returned as it is).
    fields
        The fields to keep (default: all).
    cache
        Where built structures are kept (default: $EXABRICKS_CACHE, else
        $XDG_CACHE_HOME/exabricks, else ~/.cache/exabricks); False builds in memory.
    values
        With three structure files, a values file of another step of the same
        cells (`exabricks values`; docs/time-series.md), drawn instead of the
        bricks' own values.
    **ingest_options
        `ingest`'s options, by their keyword (`format="amrex"`, `mask=False`, ...).

    Returns
    -------
    Dataset
        Built structures are read from the cache where it holds them.

    Raises
    ------
    ExabricksError
        The source cannot be read, or the options do not go with it.

    Examples
    --------
    >>> ds = eb.open("exabricks/data/gerris-plume/plume7-1.cells")
    >>> ds.fields
    ('P', 'T', 'U', 'V', 'W')
    """
    if isinstance(source, Dataset):
        return source
    if _is_yt(source):
        return _open_yt(source, fields, ingest_options)
    if isinstance(source, (tuple, list)):
        if fields is not None or ingest_options or cache is not None:
            raise ExabricksError("fields, cache and ingest options apply to a source, not to "
                                 "three structure files")
        from .dataset import open_dataset

        return open_dataset(tuple(source), values=values)
    if values is not None:
        raise ExabricksError("values: goes with the three structure files it was made for")
    from .dataset import open_source

    if not isinstance(source, (str, os.PathLike)):
        raise ExabricksError(f"cannot open a {type(source).__name__}: give a path, three structure "
                             "files or a yt dataset")
    options = dict(ingest_options)
    if fields is not None:
        options["fields"] = (fields,) if isinstance(fields, str) else tuple(fields)
    return open_source(source, options, cache=cache)


def _is_yt(source) -> bool:
    return type(source).__module__.startswith("yt.") and hasattr(source, "all_data")


def _open_yt(ds, fields, options) -> Dataset:
    from . import structures
    from .readers.yt_bridge import cells_from_dataset
    from .builders.cells import validate_cells

    if options:
        raise ExabricksError(f"{ds}: a yt dataset takes `fields` only, not {', '.join(options)}")
    cells = validate_cells(cells_from_dataset(ds, fields), source=str(ds))
    return Dataset(structures.build(cells, where=str(ds)), source={"yt": str(ds)})


def render(dataset, scene=None, *, device: str | None = None, **options) -> Image:
    """One frame of `dataset` as an Image.

    Parameters
    ----------
    dataset
        A Dataset, or anything `open` takes.
    scene
        A scene file path, a dict in the scene-file format, or an eb.Scene
        (`Renderer.scene`); options override it (module docstring).
    device
        An OpenCL device ('P:D' or a name substring; default: $EXABRICKS_DEVICE,
        else the first GPU, else the first CPU).
    **options
        The render flags by their keyword, `-` as `_` (`field="T"`, `colormap="inferno"`,
        `range=(0, 0.6)`, `size=(512, 512)`, `iso=0.45`, ...): docs/reference/scene-options.md.

    Returns
    -------
    Image
        The frame: `.save(path)` writes it, a notebook shows it.

    Notes
    -----
    A render job's strategies (memory budget, tiles, progressive, MPI) write files:
    `render_job`.

    Examples
    --------
    >>> ds = eb.open("exabricks/data/gerris-plume/plume7-1.cells")
    >>> image = eb.render(ds, field="T", colormap="inferno", size=(64, 48))
    >>> image.rgba.shape
    (48, 64, 4)
    """
    return Renderer(dataset, device=device).render(scene, **options)


def render_job(dataset, output: str | os.PathLike, scene=None, *, device: str | None = None,
               **options) -> None:
    """What `exabricks render ... -o output` does, every strategy included.

    Parameters
    ----------
    dataset
        A Dataset, or anything `open` takes.
    output
        The image file (.png or .exr); with `camera_path` and `frames`, a printf
        field in it numbers the frames (`frame_%05d.png`).
    scene, device
        As `render`.
    **options
        The render flags (as `render`), and the job's: `memory_budget` (bytes or
        "2G"), `tile` ((W, H)), `progressive` and `time_limit` (seconds),
        `camera_path` with `frame` or `frames`, `mpi_mode` ("data" or "image")
        when the process was started by mpiexec or srun.
    """
    from .scene.options import JOB_OPTIONS
    from .stages.render import render_job as job

    dataset = open(dataset)
    # the job's own options; `camera` (a file or an object) is the scene's, as in `render`
    job_options = {o.keyword: o.coerce(options.pop(o.name)) for o in JOB_OPTIONS
                   if o.name in options and o.name not in SCENE_KEYS}
    doc, camera, flags = _scene_options(scene, options)
    if camera is not None:
        job_options["camera_path"] = camera
    job(dataset, os.fspath(output), flags=flags, scene_path=doc, device=device,
        **{k: v for k, v in job_options.items() if v is not None})


def probe(dataset, points, field: str | None = None, *, reconstruction: str = "basis",
          device: str | None = None) -> np.ndarray:
    """The reconstructed field at world points.

    Parameters
    ----------
    dataset
        A Dataset, or anything `open` takes.
    points
        World points, an (N, 3) array of numbers (a .npy file: numpy.load it first).
    field
        The field (default: the first).
    reconstruction
        "basis" (the paper's continuous blend), "nearest" (the containing leaf
        cell's value) or "vertex" (trilinear in stitched vertex values).
    device
        As `render`.

    Returns
    -------
    numpy.ndarray
        (N,) float32, NaN where no cell has support.
    """
    from .scene import RECONSTRUCTIONS
    from .stages.probe import probe as probe_points
    from .stages.probe import world_points

    if reconstruction not in RECONSTRUCTIONS:
        raise ExabricksError(f"reconstruction: expected one of {', '.join(RECONSTRUCTIONS)}, "
                             f"got {reconstruction!r}")
    points = world_points(points)  # before the dataset is opened (and perhaps built)
    dataset = open(dataset)
    bricks, regions, bvh = dataset.structures()
    if field is not None and field not in bricks.fields:
        raise ExabricksError(f"no field {field!r} (fields: {', '.join(bricks.fields)})")
    return probe_points(bricks, regions, bvh, points, field=field, device=device,
                        reconstruction=reconstruction)


class Renderer:
    """A dataset kept on an OpenCL device for many frames: a new camera, transfer
    function or iso-value costs only the frame; a field not yet on the device is
    uploaded with those already there.

    Parameters
    ----------
    dataset
        A Dataset, or anything `open` takes (opened, and built if need be, here).
    device
        As `render`; the device is taken at the first frame, not here.

    Raises
    ------
    ExabricksError
        As `open`, for a dataset that cannot be opened.
    """

    def __init__(self, dataset, *, device: str | None = None):
        self.dataset = open(dataset)
        self.device = device
        self._renderer = None
        self._fields: tuple[str, ...] = ()

    def scene(self, scene=None, **options) -> Scene:
        """The eb.Scene that `scene` and `options` describe over this dataset, with
        every default resolved (the camera that frames the data, the ranges of the
        fields); `Scene.replace(...)` changes parts of it.

        Parameters
        ----------
        scene
            As `render`: a scene file path, a dict in the scene-file format or an
            eb.Scene (returned as it is when no option is given).
        **options
            The render flags by their keyword, `-` as `_`, and the scene file's keys,
            overriding `scene` (docs/reference/scene-options.md).

        Returns
        -------
        Scene
            Nothing is drawn and nothing goes to the device.

        Raises
        ------
        ExabricksError
            The scene or an option's value is not valid for this dataset.
        TypeError
            An option that is no render flag (the message names those of `render_job`).
        """
        from .scene import scene_from_options

        if isinstance(scene, Scene) and not options:
            return scene
        doc, camera, flags = _scene_options(scene, options)
        return scene_from_options(self.dataset.bricks, scene_path=doc, camera_path=camera,
                                  flags=flags)

    def render(self, scene=None, **options) -> Image:
        """One frame (`render`'s scene and options) as an Image.

        Parameters
        ----------
        scene
            As `scene`.
        **options
            The render flags by their keyword, `-` as `_`, and the scene file's keys,
            as `scene` (docs/reference/scene-options.md).

        Returns
        -------
        Image
            The frame, with its scene and metadata. The fields it reads are uploaded
            with those already on the device, which stay there for the next frame.

        Raises
        ------
        ExabricksError
            The scene or an option is not valid, no OpenCL device matches `device`,
            or the process runs under MPI (`render_job` draws with every rank).
        TypeError
            An option that is no render flag.
        """
        from . import parallel
        from .stages.render import frame_metadata

        if parallel.world() is not None:
            raise ExabricksError("under MPI a frame is drawn by every rank together: use "
                                 "eb.render_job(dataset, output, ...)")
        chosen = self.scene(scene, **options)
        result = self._on_device(chosen.fields()).render_scene(chosen)
        from .film.layout import facts_from_meta

        metadata = frame_metadata(chosen, self.dataset.describe(), None, None, result.stats)
        return Image(result.rgba, result.depth, metadata, scene=chosen,
                     facts=facts_from_meta(self.dataset.meta), inputs=self.dataset.inputs)

    def release(self) -> None:
        """Free the dataset's copy on the device (the next frame uploads it again):
        a viewer no view shows holds none."""
        self._renderer = None
        self._fields = ()

    def _on_device(self, fields):
        from .engine.renderer import Renderer as DeviceRenderer

        if self._renderer is None or not set(fields) <= set(self._fields):
            wanted = tuple(dict.fromkeys((*self._fields, *fields)))
            bricks, regions, bvh = self.dataset.structures()
            self._renderer = None  # the old upload goes before the new one comes
            self._renderer = DeviceRenderer(bricks, regions, bvh, fields=wanted, device=self.device)
            self._fields = wanted
        return self._renderer

    def __repr__(self) -> str:
        return f"<exabricks.Renderer of {self.dataset!r}>"


def _scene_options(scene, options: dict):
    """(scene object or path for scene_from_options, camera file, flags) from eb.render's
    `scene` and keyword options; ExabricksError naming a bad option, TypeError for an
    unknown one."""
    from .scene import SCENE_OPTIONS, scene_to_dict
    from .scene.options import JOB_OPTIONS

    declared = {o.name: o for o in SCENE_OPTIONS}
    unknown = [n for n in options if n not in declared and n not in SCENE_KEYS]
    if unknown:
        jobs = [n for n in unknown if n in {o.name for o in JOB_OPTIONS}]
        where = "; use eb.render_job for " + ", ".join(jobs) if jobs else ""
        raise TypeError(f"unknown option(s) {', '.join(unknown)}{where} (options: "
                        f"{', '.join([*declared, *SCENE_KEYS])})")
    if isinstance(scene, Scene):
        doc = scene_to_dict(scene)
    elif isinstance(scene, dict):
        doc = dict(scene)
    elif scene is None:
        doc = None
    elif isinstance(scene, (str, os.PathLike)):
        doc = Path(scene)
    else:
        raise ExabricksError(f"scene: expected a scene file, a dict or an eb.Scene, got "
                             f"{type(scene).__name__}")
    camera = None
    parts = {k: options.pop(k) for k in SCENE_KEYS if k in options and k not in declared}
    if isinstance(parts.get("camera"), (str, os.PathLike)):
        camera = os.fspath(parts.pop("camera"))
    if parts:
        if isinstance(doc, Path):
            raise ExabricksError(f"{doc}: a scene file's {', '.join(parts)} change through a "
                                 "scene dict or an eb.Scene, not a path")
        doc = {**(doc or {}), **parts}
    flags = {name: declared[name].coerce(value) for name, value in options.items()}
    return doc, camera, flags
