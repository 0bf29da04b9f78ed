"""A dataset ready to render or probe: its three structures (bricks, regions, BVH),
from three structure files, from a source built with the builders' defaults
(and kept in exabricks.cache), or from objects built in memory.

`open_source` is what a source-taking `render`/`probe` and `eb.open` share
(DESIGN.md "The pipeline"): a source is anything `ingest` reads, with
`ingest`'s options, or a cells file. Structures come out bit for bit as the
staged pipeline writes them, so the image is the staged pipeline's.
"""

from __future__ import annotations

import inspect
import logging
import os
from pathlib import Path

from .util import progress
from . import schema
from .util.errors import ExabricksError

log = logging.getLogger(__name__)


class Dataset:
    """The three structures of one dataset. Those from files are loaded (mapped and
    checked) when first used; `paths` are the files, where there are any, which the
    memory-budgeted and MPI renders read by parts.

    Usually made by `eb.open` or `Dataset.from_files`.

    Parameters
    ----------
    structures
        (bricks, regions, bvh) built in memory (exabricks.structures.build), or None
        to load them from `paths`.
    paths
        The three structure files (bricks, regions, bvh); with `structures`, the
        files they were loaded from.
    source
        What the structures were built from (`describe`'s "built_from"), as `source`.
    values
        With `paths`: a values file of another step of the same cells (or a
        schema.Values made in memory), drawn instead of the bricks' own.
    lease
        A cache entry's lease, held while the dataset is in use.

    Raises
    ------
    ValueError
        Neither `structures` nor `paths`.
    ExabricksError
        `values` without `paths`.
    """

    def __init__(self, structures=None, *, paths=None, source: dict | None = None, values=None,
                 lease=None):
        if structures is None and paths is None:
            raise ValueError("a dataset needs its structures or their files")
        if values is not None and paths is None:
            raise ExabricksError("a values file goes with the three structure files it was made for")
        self._structures = structures
        self.paths = None if paths is None else tuple(Path(p) for p in paths)
        self.source = source or {}
        # a values file, or a step's values made in memory (exabricks.series)
        self.values = values if values is None or isinstance(values, schema.Values) else Path(values)
        self._lease = lease  # a cache entry's, held while the dataset is in use

    @classmethod
    def from_files(cls, bricks_path, regions_path, bvh_path, *, values=None) -> Dataset:
        """The dataset of three structure files; `values`: a values file of another
        step of the same cells (exabricks values), drawn instead of the bricks' own.

        Parameters
        ----------
        bricks_path
            The bricks file.
        regions_path
            The regions file, built from those bricks.
        bvh_path
            The BVH file, built over those regions.
        values
            A values file, or None.

        Returns
        -------
        Dataset
            Nothing is read until the structures are first used.
        """
        return cls(paths=(bricks_path, regions_path, bvh_path), values=values)

    def structures(self) -> tuple[schema.Bricks, schema.Regions, schema.Bvh]:
        """(bricks, regions, bvh), loaded and checked as render loads them.

        Returns
        -------
        tuple
            (schema.Bricks, schema.Regions, schema.Bvh): files are mapped, loaded at
            the first call and kept; a values file's values replace the bricks' own.

        Raises
        ------
        ExabricksError
            A file fails its checks, the three were not built together, or the values
            file was not made for these cells.
        """
        if self._structures is None:
            from .engine.device_data import load_structures

            self._structures = self._step(*load_structures(*self.paths))
        return self._structures

    def load(self, mode: str) -> tuple[schema.Bricks, schema.Regions, schema.Bvh]:
        """The structures as a memory-budgeted or an MPI render in `mode` reads them
        (mapped, by parts: exabricks.parallel.load_for).

        Parameters
        ----------
        mode
            "data": the bricks and regions mapped unchecked (a part reads its own
            pages) and the BVH checked to go with them; anything else ("image"):
            loaded as `structures` loads them. Only for a dataset with `paths`.

        Returns
        -------
        tuple
            (schema.Bricks, schema.Regions, schema.Bvh), with the values file's step
            where there is one; loaded anew at each call.

        Raises
        ------
        ExabricksError
            As `structures`.
        """
        from .parallel import load_for

        return self._step(*load_for(mode, *self.paths))

    def _step(self, bricks, regions, bvh):
        """The structures with the values file's step, when there is one."""
        if self.values is None:
            return bricks, regions, bvh
        from .builders.values import with_values

        step = self.values
        if not isinstance(step, schema.Values):
            step = schema.load(self.values, "values", mapped=True, checked=True)
        return with_values(bricks, regions, bvh, step, where=self._values_where,
                           bricks_where=str(self.paths[0]))

    @property
    def _values_where(self) -> str:
        """The values file, or the source whose step was made in memory."""
        return self.source.get("path", "the step") if isinstance(self.values, schema.Values) \
            else str(self.values)

    @property
    def bricks(self) -> schema.Bricks:
        return self.structures()[0]

    @property
    def meta(self) -> dict:
        """The bricks' meta (provenance, and the reader's word on the source: its time
        and units), read from the file's header alone where the dataset is files."""
        if self._structures is not None:
            return self._structures[0].meta
        meta = schema.peek(self.paths[0])[2]
        if self.values is not None:  # the step's own time (with_values does the same)
            step = self.values.meta if isinstance(self.values, schema.Values) \
                else schema.peek(self.values)[2]
            meta = {**meta, **({"source": step["source"]} if "source" in step else {})}
        return meta

    @property
    def fields(self) -> tuple[str, ...]:
        """The field names, in file order."""
        return tuple(self.bricks.fields)

    @property
    def bounds(self):
        """The world box of the cells: ((x0, y0, z0), (x1, y1, z1))."""
        lo, hi = schema.world_bounds(self.bricks)
        return tuple(lo), tuple(hi)

    @property
    def levels(self) -> int:
        """How many refinement levels hold cells."""
        import numpy as np

        return int(np.unique(self.bricks.level).size)

    @property
    def inputs(self) -> list:
        """The files an output must not replace."""
        files = [self.source["path"]] if "path" in self.source else []
        step = [self.values] if isinstance(self.values, Path) else []
        return files + list(self.paths or ()) + step

    def describe(self) -> dict:
        """The image metadata's dataset: the three files (where there are), the source
        (where built from one) and the inputs the bricks record.

        Returns
        -------
        dict
            "bricks", "regions", "bvh" (paths, where there are files), "values" (a
            values file's path), "built_from" (`source`, such as the path and the
            ingest options) and "source" (the bricks' meta "inputs", [] when none).
        """
        out = {}
        if self.paths is not None:
            out.update(zip(("bricks", "regions", "bvh"), map(str, self.paths)))
        if isinstance(self.values, Path):
            out["values"] = str(self.values)
        if self.source:
            out["built_from"] = self.source
        out["source"] = self.meta.get("inputs", [])
        return out

    def __repr__(self) -> str:
        where = self.source.get("path") or (self.paths[0].parent if self.paths else "memory")
        return f"<exabricks.Dataset {where}: fields {', '.join(self.fields)}>"


def ingest_defaults() -> dict:
    """The ingest options a source takes, with their defaults (the stage's own)."""
    from .stages.ingest import ingest

    return {name: p.default for name, p in inspect.signature(ingest).parameters.items()
            if p.kind is p.KEYWORD_ONLY and name not in ("level_cap", "piece_order", "on_step")}


def open_dataset(inputs, options: dict | None = None, *, cache=None, desc: str = "build",
                 values=None) -> Dataset:
    """The dataset of `inputs`: three structure files (BRICKS, REGIONS, BVH), with a
    `values` file of another step if given, or one source (`open_source`). Under
    MPI rank 0 builds a source into the cache first and the other ranks then load
    that entry."""
    from . import parallel

    if len(inputs) == 3:
        if options:
            raise ExabricksError(f"{', '.join(options)}: only with a source, not with three "
                                 "structure files")
        return Dataset.from_files(*inputs, values=values)
    if values is not None:
        raise ExabricksError("--values: goes with the three structure files BRICKS REGIONS BVH that "
                             "it was made for, not with a source (render that step's source)")
    if len(inputs) != 1:
        raise ExabricksError(f"give one source or three structure files, not {len(inputs)} inputs")
    comm = parallel.world()
    if comm is not None:
        if cache is False:
            raise ExabricksError("--no-cache: under MPI the ranks share a source's structures "
                                 "through the cache")
        parallel.agree(comm, lambda: open_source(inputs[0], options, cache=cache, desc=desc)
                       if comm.Get_rank() == 0 else None)
    return open_source(inputs[0], options, cache=cache, desc=desc)


def open_source(path, options: dict | None = None, *, cache: str | os.PathLike | bool | None = None,
                desc: str = "build") -> Dataset:
    """The dataset of source `path` (anything `ingest` reads, or a cells file) built
    with ingest `options` and the builders' defaults. `cache`: a directory, None
    for the default (exabricks.cache.default_root), False to build in memory only.
    A cached entry that fails its checks is built again."""
    from . import cache as cache_mod

    given = dict(options or {})
    defaults = ingest_defaults()
    unknown = sorted(set(given) - set(defaults))
    if unknown:
        raise ExabricksError(f"{path}: unknown ingest option(s) {', '.join(unknown)} "
                             f"(ingest takes {', '.join(defaults)})")
    from .readers import given_path

    if not given_path(path).exists():
        raise ExabricksError(f"{path}: no such file or directory")
    if not (Path(path).is_file() or Path(path).is_dir()):
        raise ExabricksError(f"{path}: not a regular file or a directory (a source is a file or "
                             "a plotfile directory)")
    cells_file = _is_cells_file(path, given)
    chosen = _normalised({**defaults, **given})
    about = {"path": str(path), "options": _normalised(given)}
    if cache is False:
        structures = _build(path, given, desc)
        return Dataset(structures, source=about)
    store = cache_mod.Cache(Path(cache) if cache not in (None, True) else cache_mod.default_root())
    digest = cache_mod.source_digest(path)
    k = cache_mod.key(path, {"cells_file": cells_file, **chosen}, digest)
    lease = store.lease(k) if store.paths(k) is not None else None
    paths = store.paths(k) if lease is not None else None
    if paths is not None:
        try:
            from .engine.device_data import load_structures

            log.debug("%s: structures from the cache (%s)", path, paths[0].parent)
            structures = load_structures(*paths)
            cache_mod.check(structures, paths, k, digest)
            return Dataset(structures, paths=paths, source=about, lease=lease)
        except ExabricksError as e:
            log.warning("%s: a damaged cache entry (%s): building it again", path, e)
            lease.release()
            store.drop(k)
    elif store.paths(k) is None and os.path.lexists(store.root / k):
        log.warning("%s: a broken cache entry (%s: not whole): building it again", path,
                    store.root / k)
    structures = _build(path, given, desc)
    record = cache_mod.record(k, digest)
    structures = tuple(s.replace(meta={**s.meta, "cache": record}) for s in structures)

    def write(directory):
        for name, obj in zip(cache_mod.FILES, structures):
            schema.save(directory / name, obj)

    try:
        paths = store.put(k, write, about)
    except cache_mod.EntryNotWritten as e:  # a full disk: the render goes on uncached
        log.warning("%s: the structures are not cached: %s", path, e)
        return Dataset(structures, source=about)
    return Dataset(structures, paths=paths, source=about, lease=store.lease(k))


def _is_cells_file(path, options) -> bool:
    """Whether `path` is an exabricks cells file (which takes no ingest option);
    another exabricks file is refused."""
    p = Path(path)
    if p.is_dir() or p.suffix.lower() != ".npz":
        return False
    kind, _, _ = schema.peek(p)
    if kind != "cells":
        raise ExabricksError(f"{path}: a {kind} file is not a source: give the three structure "
                             "files BRICKS REGIONS BVH, or a cells file or anything ingest reads")
    if options:
        raise ExabricksError(f"{path}: a cells file takes no ingest options "
                             f"({', '.join(sorted(options))}); ingest the source again")
    return True


def source_cells(path, options: dict | None = None, *, on_step=None) -> schema.Cells:
    """The leaf cells of a source: a cells file as it is, anything else through
    ingest with `options` (on_step twice, as ingest calls it)."""
    from .stages.ingest import ingest

    step = on_step or (lambda: None)
    if _is_cells_file(path, options or {}):
        cells = schema.load(path, "cells")
        step(), step()
        return cells
    return ingest(path, **(options or {}), on_step=step)


def _build(path, options, desc: str):
    """The structures of `path`, built in memory, with a progress bar on a terminal."""
    from . import structures

    with progress.bar(total=5, desc=desc, unit="step") as bar:
        cells = source_cells(path, options, on_step=bar.update)
        return structures.build(cells, where=str(path), on_step=bar.update)


def _normalised(options: dict) -> dict:
    """`options` as JSON values (tuples as lists, paths as strings), for the key."""
    import json

    from .util.jsonfile import json_default

    return json.loads(json.dumps(options, sort_keys=True, default=json_default))
