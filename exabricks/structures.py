"""The three structures of a dataset (paper §3) built from one another, each with
the provenance its file records: bricks from leaf cells, Active Brick Regions
from bricks, the BVH from regions; and a time series' step values for bricks
built from another step of the same cells.

`exabricks brick|regions|bvh` call one function each and save its result; a
source's build (exabricks.source) calls `build` with the builders' defaults, so
both give the same structures.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import contextmanager

from . import schema
from .util.constants import MAX_BRICK_WIDTH
from .util.errors import ExabricksError
from .formats.pieces import WHOLE, Piece

LEAF_SIZE = 4
BINS = 16


def bricks_of(cells: schema.Cells, inputs: Sequence = (), *, where: str | None = None,
              max_brick_width: int = MAX_BRICK_WIDTH, piece: Piece = WHOLE) -> schema.Bricks:
    """The bricks of `cells` (exabricks.builders.bricks.build_bricks) with their meta:
    `inputs` (paths, hashed into the provenance), parameters and the cells' digest
    (`built_from`). `where` names the input in an error."""
    from .builders.bricks import build_bricks

    with _named(where):
        bricks = build_bricks(cells, max_brick_width=max_brick_width, piece=piece)
    meta = schema.make_meta(
        inputs=inputs, parameters={"max_brick_width": max_brick_width},
        statistics=bricks.meta["statistics"], upstream=cells, **_share(bricks),
        # what the reader said of the source (time, units), for annotated images
        **({"source": cells.meta["source"]} if "source" in cells.meta else {}))
    return bricks.replace(meta=meta)


def regions_of(bricks: schema.Bricks, inputs: Sequence = (), *, where: str | None = None,
               merge=None, piece: Piece = WHOLE) -> schema.Regions:
    """The Active Brick Regions of `bricks` (exabricks.builders.regions.build_regions,
    `merge` default: merged regions by the default cost model) with their meta; the
    brick and region counts go into meta["consistency"], which bvh, render and
    probe check."""
    from .builders.regions import Merge, build_regions

    with _named(where):
        regions = build_regions(bricks, Merge() if merge is None else merge, piece)
    meta = schema.make_meta(
        inputs=inputs, parameters=regions.meta["parameters"],
        statistics=regions.meta["statistics"], upstream=bricks,
        consistency={"n_bricks": bricks.n_bricks, "n_regions": regions.n_regions},
        **_share(regions))
    return regions.replace(meta=meta)


def bvh_of(regions: schema.Regions, inputs: Sequence = (), *, where: str | None = None,
           leaf_size: int = LEAF_SIZE, bins: int = BINS, piece: Piece = WHOLE) -> schema.Bvh:
    """The BVH over `regions` (exabricks.builders.bvh.build_bvh) with its meta, after
    checking the regions' own counts (`check_regions`)."""
    from .builders.bvh import build_bvh

    check_regions(regions, where or "the regions")
    with _named(where):
        bvh = build_bvh(regions, leaf_size=leaf_size, bins=bins, piece=piece)
    upstream = regions.meta.get("consistency") or {}
    meta = schema.make_meta(
        inputs=inputs, parameters={"leaf_size": leaf_size, "bins": bins},
        statistics=bvh.meta["statistics"], upstream=regions,
        consistency={
            "n_regions": regions.n_regions,
            "n_bricks": upstream.get("n_bricks"),
            # The bricks file the regions were built from (sha256 chain).
            "bricks_inputs": regions.meta.get("inputs", []),
        },
        **_share(bvh))
    return bvh.replace(meta=meta)


def values_of(cells: schema.Cells, bricks: schema.Bricks, inputs: Sequence = (), *,
              where: str | None = None, bricks_where: str | None = None) -> schema.Values:
    """One step of a time series on the hierarchy of `bricks`: the values of `cells`
    in the bricks' cell order (exabricks.builders.values.step_values), recording the
    bricks' content sha256 and what the reader said of the step (its time)."""
    from .builders.values import step_values

    step = step_values(cells, bricks, where=where or "the source", bricks_where=bricks_where or "the bricks")
    meta = schema.make_meta(
        inputs=inputs, upstream=bricks,
        **({"source": cells.meta["source"]} if "source" in cells.meta else {}))
    return step.replace(meta=meta)


def build(cells: schema.Cells, *, where: str | None = None,
          on_step: Callable[[], None] | None = None) -> tuple[schema.Bricks, schema.Regions, schema.Bvh]:
    """Bricks, regions and BVH of `cells` with the builders' defaults, each recording
    the digest of what it was built from (as the staged files do), so that a saved
    set passes `exabricks.engine.device_data.check_chain`. `on_step` after each."""
    step = on_step or (lambda: None)
    _digest(cells)
    bricks = _digest(bricks_of(cells, where=where))
    step()
    regions = _digest(regions_of(bricks, where=where))
    step()
    bvh = _digest(bvh_of(regions, where=where))
    step()
    return bricks, regions, bvh


def check_regions(regions: schema.Regions, path) -> None:
    """Refuse a regions file whose counts disagree with its own provenance."""
    upstream = regions.meta.get("consistency")
    if not isinstance(upstream, dict) or "n_bricks" not in upstream:
        raise ExabricksError(
            f"{path}: regions file has no meta['consistency']['n_bricks']; "
            "rebuild it with `exabricks regions`"
        )
    n_bricks = upstream["n_bricks"]
    if upstream.get("n_regions") != regions.n_regions:
        raise ExabricksError(
            f"{path}: holds {regions.n_regions} regions but its meta records "
            f"{upstream.get('n_regions')}; the file is inconsistent"
        )
    # negative ids are refused by the load already
    ids = regions.brick_ids
    top = schema.reduce_chunks(ids, lambda a: int(a.max()) if a.size else -1, max)
    if top >= n_bricks:
        raise ExabricksError(f"{path}: brick ids reach {top}, beyond the {n_bricks} bricks "
                             "its meta records")


def _digest(obj):
    """`obj` with the digest of its content in its meta, as a loaded file has it."""
    obj.meta["content_sha256"] = schema.content_sha256(obj)
    return obj


def _share(obj) -> dict:
    return {k: v for k, v in obj.meta.items() if k == "piece"}


@contextmanager
def _named(where):
    """Prefix a builder's ExabricksError with the input's name `where`."""
    try:
        yield
    except ExabricksError as e:
        if not where:
            raise
        raise ExabricksError(f"{where}: {e}") from e
