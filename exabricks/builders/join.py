"""`exabricks join PIECES... -o OUT`: the shares that `brick`, `regions` or `bvh
--piece K/N` built (exabricks.formats.pieces) put back together in piece order;
the result equals the one-process build, array for array (docs/design-structures.md,
"Builders by pieces")."""

from __future__ import annotations

import numpy as np

from .. import schema
from ..util.errors import ExabricksError
from .bricks import merge_bricks, statistics
from .bvh import bvh_statistics
from ..formats.pieces import PIECE_KEY, Piece
from .regions import region_statistics

# A BVH's arrays with a row per node.
NODE_ARRAYS = ("lower_lattice", "upper_lattice", "first", "count", "value_range", "finest_level")


def _shares(parts: list[tuple[str, schema.Kind]]) -> list[tuple[str, schema.Kind, dict]]:
    """The shares in piece order, checked to be one whole set of one build."""
    if not parts:
        raise ExabricksError("nothing to join")
    found = []
    for path, obj in parts:
        info = obj.meta.get(PIECE_KEY)
        if not isinstance(info, dict) or not all(type(info.get(k)) is int
                                                  for k in ("index", "count")):
            raise ExabricksError(f"{path}: not a piece of a build (no meta['piece']); "
                                 "build pieces with --piece K/N")
        try:
            Piece(info["index"], info["count"])
        except ExabricksError as e:
            raise ExabricksError(f"{path}: {e}") from None
        found.append((path, obj, info))
    path0, obj0, info0 = found[0]
    count = info0["count"]
    seen = {}
    for path, obj, info in found:
        if info["count"] != count:
            raise ExabricksError(f"{path}: is piece {info['index']} of {info['count']}, but "
                                 f"{path0} is one of {count}")
        if obj.KIND != obj0.KIND:
            raise ExabricksError(f"{path}: holds {obj.KIND}, but {path0} holds {obj0.KIND}")
        if info["index"] in seen:
            raise ExabricksError(f"{path}: piece {info['index']} is also given as "
                                 f"{seen[info['index']]}")
        seen[info["index"]] = path
        if tuple(obj.fields) != tuple(obj0.fields) or not (
                np.array_equal(obj.origin_world, obj0.origin_world)
                and np.array_equal(obj.spacing_world, obj0.spacing_world)):
            raise ExabricksError(f"{path}: has other fields or another world frame than "
                                 f"{path0}: the pieces are not of one dataset")
        if any(obj.meta.get(key) != obj0.meta.get(key)
               for key in ("parameters", "inputs", "built_from")):
            raise ExabricksError(f"{path}: was built from other inputs or with other "
                                 f"parameters than {path0}")
    missing = sorted(set(range(count)) - set(seen))
    if missing:
        raise ExabricksError(f"piece{'s' if len(missing) > 1 else ''} "
                             f"{', '.join(map(str, missing[:8]))}{'…' if len(missing) > 8 else ''}"
                             f" of {count} {'are' if len(missing) > 1 else 'is'} missing")
    return sorted(found, key=lambda f: f[2]["index"])


def _stack(arrays, shifts=None, axis=0) -> np.ndarray:
    """`arrays` one after the other along `axis` (0, or 1 for (F, V) values), the
    k-th plus shifts[k]; copied in steps, each mapped share's pages handed back
    as they are copied, so that a join holds about its output only."""
    shape = list(arrays[0].shape)
    shape[axis] = sum(a.shape[axis] for a in arrays)
    out = np.empty(shape, arrays[0].dtype)
    at = 0
    for k, a in enumerate(arrays):
        n = a.shape[axis]
        pairs = [(a, out[at:at + n])] if axis == 0 else [(a[f], out[f, at:at + n])
                                                          for f in range(a.shape[0])]
        for src, dst in pairs:
            for start, (part,) in schema.rows(src):
                dst[start:start + part.shape[0]] = part if shifts is None else part + shifts[k]
        schema.release_arrays(a)
        at += n
    return out


def join_bricks(parts) -> schema.Bricks:
    """One bricks file from the shares of `brick --piece` ((path, Bricks) pairs):
    the bricks in piece order, offsets moved past the shares before them."""
    shares = _shares(parts)
    at = 0
    for path, obj, info in shares:
        run = info.get("cells")
        if not (isinstance(run, list) and len(run) == 2 and all(type(x) is int for x in run)
                and run[0] == at
                and run[1] - run[0] == obj.values.shape[1]
                and info.get("n_cells") == shares[0][2].get("n_cells")):
            raise ExabricksError(f"{path}: holds cells {run}, but the pieces before it end at "
                                 f"cell {at}: the pieces are not of one build")
        at = run[1]
    if at != shares[0][2].get("n_cells"):
        raise ExabricksError(f"the pieces hold {at} cells, not the {shares[0][2].get('n_cells')} "
                             "of their build")
    width = shares[0][2].get("max_brick_width")
    for path, _, info in shares:
        if not (type(width) is int and 1 <= width <= 1 << 30
                and info.get("max_brick_width") == width):
            raise ExabricksError(f"{path}: its max brick width {info.get('max_brick_width')!r} "
                                 f"is not {width!r}, or not a width")
    objs = [obj for _, obj, _ in shares]
    first = objs[0]
    # What one build does after its partition: join bricks that fill a box together.
    lower, level, dims, offset, values = merge_bricks(
        _stack([o.lower_lattice for o in objs]), _stack([o.level for o in objs]),
        _stack([o.dims for o in objs]),
        _stack([o.offset for o in objs], [info["cells"][0] for _, _, info in shares]),
        _stack([o.values for o in objs], axis=1), width)
    return schema.Bricks(
        fields=first.fields, origin_world=first.origin_world, spacing_world=first.spacing_world,
        meta={"statistics": statistics(level, dims)},
        lower_lattice=lower, level=level, dims=dims, offset=offset, values=values,
    )


def join_regions(parts) -> schema.Regions:
    """One regions file from the shares of `regions --piece`: the regions in piece
    order, each share's brick lists after those of the shares before it."""
    shares = _shares(parts)
    objs = [obj for _, obj, _ in shares]
    first = objs[0]
    # each share's CSR starts without its leading 0, after the lists before it
    ends = np.cumsum([0] + [int(o.brick_start[-1]) for o in objs])
    start = _stack([np.zeros(1, first.brick_start.dtype)] + [o.brick_start[1:] for o in objs],
                   [0] + list(ends[:-1]))
    regions = schema.Regions(
        fields=first.fields, origin_world=first.origin_world, spacing_world=first.spacing_world,
        meta={},
        lower_lattice=_stack([o.lower_lattice for o in objs]),
        upper_lattice=_stack([o.upper_lattice for o in objs]),
        brick_start=start,
        brick_ids=_stack([o.brick_ids for o in objs]),
        value_range=_stack([o.value_range for o in objs]),
        finest_level=_stack([o.finest_level for o in objs]),
    )
    stats = region_statistics(regions)
    for key in ("n_bricks",):
        stats[key] = first.meta.get("statistics", {}).get(key)
    stats["n_partition_leaves"] = sum(o.meta.get("statistics", {}).get("n_partition_leaves", 0)
                                      for o in objs)
    return regions.replace(meta={"statistics": stats})


def join_bvh(parts) -> schema.Bvh:
    """One BVH from the shares of `bvh --piece`: the top (the same in every share),
    then every subtree's nodes from the share that built it, in subtree order,
    their child links moved to where the block lands."""
    shares = _shares(parts)
    info0 = shares[0][2]
    top, subtrees = info0.get("top"), info0.get("subtrees")
    n_regions = shares[0][1].region_index.shape[0]
    if not (isinstance(top, int) and 1 <= top <= shares[0][1].n_nodes
            and isinstance(subtrees, list) and all(
                isinstance(t, list) and len(t) == 3 and all(isinstance(x, int) for x in t)
                and 0 <= t[0] < top and 0 <= t[1] <= t[2] <= n_regions for t in subtrees)):
        raise ExabricksError(f"{shares[0][0]}: meta['piece'] does not describe a top and its "
                             "subtrees")
    owner, position = {}, {}
    for path, obj, info in shares:
        own, blocks = info.get("own"), info.get("blocks")
        if info.get("top") != top or info.get("subtrees") != subtrees or not (
                isinstance(own, list) and len(own) == 2 and isinstance(blocks, list)
                and len(blocks) == own[1] - own[0]):
            raise ExabricksError(f"{path}: its top or subtrees differ from {shares[0][0]}'s: "
                                 "the pieces are not of one build")
        at = top
        for t, length in zip(range(*own), blocks):
            if t in owner or not isinstance(length, int) or not (
                    0 <= length and at + length <= obj.n_nodes
                    and obj.region_index.shape[0] == n_regions):
                raise ExabricksError(f"{path}: subtree {t} is not where its meta says")
            owner[t], position[t] = obj, (at, length)
            at += length
    if sorted(owner) != list(range(len(subtrees))):
        raise ExabricksError("the pieces do not build every subtree exactly once")
    base = shares[0][1]
    n_nodes = top + sum(length for _, length in position.values())
    arrays = {k: np.empty((n_nodes,) + v.shape[1:], v.dtype) for k, v in base.arrays().items()
              if k in NODE_ARRAYS}
    for k in arrays:
        arrays[k][:top] = getattr(base, k)[:top]
    region_index = _stack([base.region_index])
    at = top
    for t, (node, s, e) in enumerate(subtrees):
        obj = owner[t]
        p, length = position[t]
        for k in arrays:
            arrays[k][node] = getattr(obj, k)[node]
            arrays[k][at:at + length] = getattr(obj, k)[p:p + length]
        moved = np.flatnonzero(arrays["count"][at:at + length] == 0) + at
        arrays["first"][moved] += at - p
        if arrays["count"][node] == 0:
            arrays["first"][node] += at - p
        region_index[s:e] = obj.region_index[s:e]
        schema.release(obj)
        at += length
    bvh = schema.Bvh(fields=base.fields, origin_world=base.origin_world,
                     spacing_world=base.spacing_world, meta={}, region_index=region_index,
                     **arrays)
    return bvh.replace(meta={"statistics": bvh_statistics(bvh)})
