"""MPI rendering: `mpiexec -n N exabricks render …` (or `srun --mpi=pmi2`) draws
one frame with N processes (docs/design-scale.md, "Data-parallel rendering and MPI").

* ``data`` mode (the default for N > 1): the space is cut into N domains by a
  k-d partition (exabricks.engine.partition), each rank keeps the structures of
  its domain only and renders exactly the samples inside it; the domains' images
  are composited sort-last in visibility order by direct send (IceT's simplest
  strategy, and yt's `reduce_tree_images` does the same front-to-back "over"):
  every rank owns a band of rows, receives that band of every domain's image,
  composites them front to back and sends the result to rank 0, which writes
  the file. Frames of several spp composite each sample on its own, then
  average. Iso-surfaces, ambient occlusion, depth output and the vertex
  reconstruction need data beyond a domain: those frames take ``image`` mode.
* ``image`` mode: every rank holds the whole dataset and renders interleaved
  bands of rows; rank 0 gathers them.

Either way the image equals the one-process image up to float rounding (with
early ray termination off, `--max-opacity 1`: a domain cannot know the opacity
in front of it). Errors: `agree` runs a step on every rank and, if any rank
failed, raises the lowest failing rank's error on all of them, which rank 0
alone prints (exabricks.cli.main); an error outside such a step aborts the MPI
job so that no rank waits forever.

The launcher is recognised from its environment (PMI_SIZE/PMI_RANK from MPICH's
Hydra and SLURM's pmi2, OMPI_COMM_WORLD_* from Open MPI) before mpi4py is
imported, so one process never initialises MPI.
"""

from __future__ import annotations

import os
import time
from types import SimpleNamespace

import numpy as np

from .util.errors import ExabricksError

MODES = ("data", "image")
_SIZE_ENV = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE", "PMIX_SIZE")
_RANK_ENV = ("PMI_RANK", "OMPI_COMM_WORLD_RANK", "PMIX_RANK")


class AgreedError(ExabricksError):
    """An error every rank raises together (`agree`): rank 0 reports it."""


def _env_int(names) -> int | None:
    for name in names:
        value = os.environ.get(name, "")
        if value.isdigit():
            return int(value)
    return None


def launched_size() -> int:
    """Processes the MPI launcher started (1 without one)."""
    return _env_int(_SIZE_ENV) or 1


def launched_rank() -> int:
    """This process's rank by the launcher's environment (0 without one)."""
    return _env_int(_RANK_ENV) or 0


_WORLD: list = []


def world():
    """MPI.COMM_WORLD when started by an MPI launcher with several processes, else
    None. ExabricksError when srun started several tasks without MPI, or mpi4py
    is missing."""
    if _WORLD:
        return _WORLD[0]
    n = launched_size()
    comm = None
    if n <= 1:
        tasks = os.environ.get("SLURM_STEP_NUM_TASKS", "1")
        if tasks.isdigit() and int(tasks) > 1:
            raise ExabricksError(
                f"srun started {tasks} tasks without MPI: each would render the whole frame "
                "alone; use `srun --mpi=pmi2` (or mpiexec inside the allocation)")
    else:
        try:
            from mpi4py import MPI
        except ImportError:
            raise ExabricksError(f"started by an MPI launcher with {n} processes but mpi4py is "
                                 "not installed: pip install 'exabricks[mpi]'") from None
        comm = MPI.COMM_WORLD
        if comm.Get_size() != n:
            raise ExabricksError(f"the launcher announced {n} processes but MPI sees "
                                 f"{comm.Get_size()}: mpi4py and the launcher come from "
                                 "different MPI libraries")
    _WORLD.append(comm)
    return comm


def initialized() -> bool:
    """Whether this process joined an MPI world of several ranks."""
    return bool(_WORLD) and _WORLD[0] is not None


def abort_world(status: int = 1) -> None:
    """End every rank (an error outside `agree`); a no-op without MPI."""
    if _WORLD and _WORLD[0] is not None:
        _WORLD[0].Abort(status)


def agree(comm, step, *args, **kw):
    """step(*args, **kw) on every rank; if it raised on any rank, every rank raises
    AgreedError with the lowest failing rank's message. Without MPI (comm None)
    just step(*args, **kw)."""
    from .util.errors import one_line

    if comm is None:
        return step(*args, **kw)
    error = None
    try:
        result = step(*args, **kw)
    except ExabricksError as e:
        error, result = str(e), None
    except MemoryError:
        error, result = "out of memory", None
    except Exception as e:  # reported like main's last line of defence
        error, result = f"internal error: {type(e).__name__}: {one_line(str(e))}", None
    errors = comm.allgather(error)
    for rank, message in enumerate(errors):
        if message is not None:
            raise AgreedError(message if rank == 0 else f"rank {rank}: {message}")
    return result


def _row_slabs(height: int, n: int) -> list[tuple[int, int]]:
    """Rows [a, b) owned by each of n ranks for compositing."""
    bounds = [height * k // n for k in range(n + 1)]
    return list(zip(bounds[:-1], bounds[1:]))


def _interleaved_spans(height: int, n: int, rank: int, rows: int = 16) -> list[tuple[int, int]]:
    """Bands of `rows` rows dealt round-robin: rank's (first row, count) spans."""
    return [(a, min(rows, height - a)) for a in range(rank * rows, height, n * rows)]


def load_for(mode: str, bricks_path, regions_path, bvh_path):
    """The three structure files for a run in `mode`: in data mode the bricks and
    regions mapped (a rank reads the pages of its domain only; exabricks.stages.
    partition.domain_data checks what it takes) and the bvh only checked to be
    one of the same regions; else loaded as for one process (load_structures)."""
    from . import schema
    from .engine.device_data import check_chain, load_structures

    if mode != "data":
        return load_structures(bricks_path, regions_path, bvh_path)
    bricks = schema.load(bricks_path, "bricks", mapped=True)
    regions = schema.load(regions_path, "regions", mapped=True)
    bvh = schema.load(bvh_path, "bvh", mapped=True)
    check_chain(bricks, regions, bvh, (bricks_path, regions_path, bvh_path))
    if tuple(regions.fields) != tuple(bricks.fields) or not (
            np.array_equal(regions.origin_world, bricks.origin_world)
            and np.array_equal(regions.spacing_world, bricks.spacing_world)):
        raise ExabricksError(f"{regions_path}: its fields or world frame differ from those of "
                             f"{bricks_path}: they were not built from the same dataset")
    if bvh.region_index.shape[0] != regions.n_regions:
        raise ExabricksError(f"{bvh_path}: the bvh indexes {bvh.region_index.shape[0]} regions but "
                             f"{regions_path} has {regions.n_regions}: it was built from other regions")
    return bricks, regions, bvh


class ParallelRenderer:
    """One frame at a time with every rank of `comm` (module docstring);
    `render_scene` returns the RenderResult on rank 0 and None elsewhere. Build
    it inside `agree`; each rank's own rendering runs inside `agree`, so that
    the collective steps are only reached when every rank got there. In data
    mode `bricks` and `regions` may be mapped (`load_for`) and `bvh` is not used:
    each domain gets its own."""

    def __init__(self, comm, bricks, regions, bvh, scene, *, device=None, mode: str = "data",
                 where=("the bricks", "the regions")):
        from . import schema
        from .engine.device_data import DatasetScale
        from .engine.partition import needs_image_mode
        from .engine.renderer import Renderer

        if mode not in MODES:
            raise ExabricksError(f"unknown MPI mode {mode!r} (one of {', '.join(MODES)})")
        self.comm, self.rank, self.size = comm, comm.Get_rank(), comm.Get_size()
        self.mode = mode
        self.reason = needs_image_mode(scene) if mode == "data" else None
        if self.reason:
            self.mode = "image"
        fields = scene.fields()
        self.frame = SimpleNamespace(origin_world=bricks.origin_world,  # the world frame
                                     spacing_world=bricks.spacing_world)
        if self.mode == "image":
            self.renderer = Renderer(bricks, regions, bvh, fields=fields, device=device)
            return
        from .engine import light_volume
        from .engine.partition import kd_partition
        from .engine.domains import domain_data, domain_options

        self.partition = kd_partition(bricks, regions, self.size)
        self.world_box = schema.world_bounds(bricks)
        for whole in (bricks, regions):  # the partition read them all: only the domain now
            schema.release(whole)
        box = (self.partition.lower[self.rank], self.partition.upper[self.rank])
        domain = domain_data(bricks, regions, *box, **domain_options(bricks, scene), fields=fields,
                           where=where)
        for whole in (bricks, regions):
            schema.release(whole)
        schema.trim_heap()
        self.renderer = Renderer(*domain, fields=fields, device=device, domain=box,
                                 scale=DatasetScale.of(bricks, fields),
                                 light=light_volume.Cache())  # the ranks sum their parts

    def render_scene(self, scene):
        from .engine.renderer import RenderResult
        from .film.film import develop

        start = time.perf_counter()
        if self.mode == "image":
            rgba, depth, stats = self._image(scene)
        else:
            rgba, depth, stats = self._data(scene)
        stats["samples"] = self.comm.allreduce(stats["samples"])
        seconds = time.perf_counter() - start
        if self.rank != 0:
            return None
        stats.update(ms=1e3 * seconds, samples_per_second=stats["samples"] / seconds if seconds
                     else 0.0, mpi={"ranks": self.size, "mode": self.mode,
                                    **({"image_mode_for": self.reason} if self.reason else {})})
        return RenderResult(develop(rgba, scene, stats), depth, stats)

    def _image(self, scene):
        cfg = scene.settings
        spans = _interleaved_spans(cfg.height, self.size, self.rank)
        result = agree(self.comm, self.renderer.integrate, scene, rows=spans)
        rows = np.concatenate([np.arange(a, a + n) for a, n in spans]) if spans \
            else np.zeros(0, np.int64)
        parts = [result.rgba[rows]] + ([result.depth[rows]] if result.depth is not None else [])
        gathered = self.comm.gather(parts, root=0)
        if self.rank != 0:
            return None, None, dict(result.stats)
        rgba, depth = result.rgba, result.depth
        for r, got in enumerate(gathered):
            span = _interleaved_spans(cfg.height, self.size, r)
            idx = np.concatenate([np.arange(a, a + n) for a, n in span]) if span else rows[:0]
            rgba[idx] = got[0]
            if depth is not None:
                depth[idx] = got[1]
        return rgba, depth, dict(result.stats)

    def _light(self, scene) -> None:
        """The shadow integrator's transmittance toward the light, every rank's
        part summed (light_volume): over the box of the regions the frame shows
        on any rank."""
        from .engine import light_volume

        data = self.renderer.dataset
        light = self.renderer.light_cache
        light.box = light_volume.union(self.comm.allgather(
            light_volume.seen_box(data.regions, data.bricks.field_index, scene.volumes))) or self.world_box
        made = agree(self.comm, self.renderer.light, scene)
        light.sum_over(self.comm, data.queue, made)

    def _data(self, scene):
        from .engine.partition import composite, eye_lattice

        cfg = scene.settings
        width, height, spp = int(cfg.width), int(cfg.height), int(cfg.spp)
        order = self.partition.visibility_order(eye_lattice(self.frame, scene.camera.position))
        slabs = _row_slabs(height, self.size)
        mine = slabs[self.rank]
        own = np.zeros((mine[1] - mine[0], width, 4), np.float32)
        samples, stats = 0, {}
        self._light(scene)
        for sample in range(spp):
            result = agree(self.comm, self.renderer.integrate, scene,
                           sample=sample if spp > 1 else None)
            samples += result.stats["samples"]
            stats = dict(result.stats)
            # direct send: band r of this domain's image to rank r
            bands = [np.ascontiguousarray(result.rgba[a:b]) for a, b in slabs]
            received = self.comm.alltoall(bands)
            over = received[order[0]].copy()
            for domain in order[1:]:
                composite(over, received[domain])
            own += over
        if spp > 1:
            own /= np.float32(spp)
        gathered = self.comm.gather(own, root=0)
        stats["samples"] = samples
        for key in ("regions", "visible_regions"):  # rank 0's domain's: not the frame's
            stats.pop(key, None)
        if self.rank != 0:
            return None, None, stats
        return np.concatenate(gathered, axis=0), None, stats

