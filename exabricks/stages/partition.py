"""A k-d partition of space into convex pieces, and the share of a dataset each
piece needs (docs/design.md, "Data-parallel rendering").

`kd_partition` cuts the lattice space of a dataset into `n` boxes by planes at
lattice integers, each cut placed so that both sides hold their share of the
bytes (brick values and region lists, counted at the boxes' centres). The outer
faces of the outermost pieces lie at infinity and every box is half-open
(lower <= p < upper), so each point of space lies in exactly one piece.

`piece_data` is what a piece's renderer loads: the regions whose boxes overlap
the piece (grown by a halo where central differences look half a cell outside
it), the bricks those regions list cropped to the cells that can reach the
piece, and a BVH over the regions. A frame of the piece (kernels/scene.cl `eb_in_piece`) then takes
exactly the samples of the whole frame that lie in the piece: the same
positions (the interval delimiters are those of the unclipped regions), the same
bricks (every region's whole list), so the pieces' images composited front to
back in `visibility_order` equal the one-piece frame up to float rounding.

`visibility_order` is the classic BSP order: at every cut the side holding the
eye comes first, which is front to back along every ray of a pinhole camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import schema
from ..errors import ExabricksError


@dataclass(frozen=True)
class KdPartition:
    """Inner nodes i: axis[i] in 0..2, plane[i] (lattice units), children left[i],
    right[i] (node ids; a negative id -1 - k is piece k). `lower`, `upper`: float64
    (n, 3) half-open boxes of the pieces, +-inf on the outer faces."""

    axis: np.ndarray
    plane: np.ndarray
    left: np.ndarray
    right: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n_pieces(self) -> int:
        return int(self.lower.shape[0])

    def visibility_order(self, eye_lattice) -> list[int]:
        """Piece ids front to back as seen from `eye_lattice` (lattice units)."""
        eye = np.asarray(eye_lattice, np.float64)
        if not len(self.axis):
            return [0]
        order, stack = [], [0]
        while stack:
            node = stack.pop()
            if node < 0:
                order.append(-1 - node)
                continue
            near, far = self.left[node], self.right[node]
            if eye[self.axis[node]] >= self.plane[node]:
                near, far = far, near
            stack += [far, near]  # near pops first
        return order


def _weights(bricks: schema.Bricks, regions: schema.Regions):
    """Points (centres, lattice units) and their bytes: every brick's values and
    box, every region's box and list."""
    width = np.ldexp(1.0, bricks.level.astype(np.int32))[:, None]
    brick_centre = bricks.lower_lattice + 0.5 * bricks.dims * width
    cells = bricks.dims.astype(np.float64).prod(axis=1)
    brick_bytes = cells * 4.0 * bricks.n_fields + 40.0
    region_centre = 0.5 * (regions.lower_lattice.astype(np.float64) + regions.upper_lattice)
    region_bytes = 34.0 + 4.0 * np.diff(regions.brick_start) + 8.0 * regions.n_fields
    return (np.concatenate([brick_centre, region_centre]),
            np.concatenate([brick_bytes, region_bytes]))


def kd_partition(bricks: schema.Bricks, regions: schema.Regions, n: int) -> KdPartition:
    """`n` pieces of about equal bytes (module docstring)."""
    if int(n) < 1:
        raise ExabricksError(f"a partition needs at least one piece, got {n}")
    centres, weights = _weights(bricks, regions)
    if regions.n_regions:
        box_lo = np.floor(regions.lower_lattice.min(axis=0)).astype(np.float64)
        box_hi = np.ceil(regions.upper_lattice.max(axis=0)).astype(np.float64)
    else:
        box_lo, box_hi = np.zeros(3), np.ones(3)
    axis, plane, left, right, lower, upper = [], [], [], [], [], []

    def build(lo, hi, open_lo, open_hi, idx, count) -> int:
        if count == 1:
            lower.append(open_lo)
            upper.append(open_hi)
            return -len(lower)  # -1 - k for piece k
        node = len(axis)
        axis.append(0), plane.append(0.0), left.append(0), right.append(0)
        a = int(np.argmax(hi - lo))
        share = (count // 2) / count
        cut = _cut(centres[idx, a], weights[idx], share, lo[a], hi[a])
        axis[node], plane[node] = a, cut
        below = centres[idx, a] < cut
        lo_l, hi_l, lo_r, hi_r = lo.copy(), hi.copy(), lo.copy(), hi.copy()
        hi_l[a] = lo_r[a] = cut
        ohi_l, olo_r = open_hi.copy(), open_lo.copy()
        ohi_l[a] = olo_r[a] = cut
        left[node] = build(lo_l, hi_l, open_lo, ohi_l, idx[below], count // 2)
        right[node] = build(lo_r, hi_r, olo_r, open_hi, idx[~below], count - count // 2)
        return node

    inf = np.full(3, np.inf)
    build(box_lo, box_hi, -inf, inf, np.arange(len(weights)), int(n))
    return KdPartition(np.asarray(axis, np.int32), np.asarray(plane, np.float64),
                       np.asarray(left, np.int64), np.asarray(right, np.int64),
                       np.asarray(lower, np.float64), np.asarray(upper, np.float64))


def _cut(x: np.ndarray, w: np.ndarray, share: float, lo: float, hi: float) -> float:
    """A lattice-integer plane strictly inside (lo, hi) when the box is wider than
    one unit (else its middle) with about `share` of the weight below."""
    if hi - lo < 2.0:
        return 0.5 * (lo + hi)
    if len(x) and w.sum() > 0:
        order = np.argsort(x, kind="stable")
        cumulative = np.cumsum(w[order])
        k = int(np.searchsorted(cumulative, share * cumulative[-1]))
        value = float(np.round(x[order][min(k, len(x) - 1)]))
    else:
        value = float(np.round(lo + share * (hi - lo)))
    return float(min(max(value, lo + 1.0), hi - 1.0))


def piece_options(bricks: schema.Bricks, scene) -> dict:
    """`piece_data`'s options for frames of `scene`: a halo of half a cell of the
    coarsest level where normals come from central differences (kernels/scene.cl
    eb_field_gradient looks that far outside the piece), and no cropping of the
    bricks under level of detail (their mip levels are made from whole bricks)."""
    central = scene.lighting.gradient == "central" or scene.settings.reconstruction == "nearest"
    halo = 0.0
    if scene.lighting.shading != "none" and central and bricks.n_bricks:
        halo = float(2.0 ** int(bricks.level.max())) / 2.0
    return {"halo": halo, "crop": not scene.settings.lod > 0}


def piece_data(bricks: schema.Bricks, regions: schema.Regions, lower, upper, *,
               halo: float = 0.0, crop: bool = True):
    """(bricks, regions, bvh) of the piece [lower, upper) (module docstring).

    `halo` (lattice units) grows the piece for lookups outside it (central
    differences: half a cell of the coarsest level). The regions that meet the
    grown piece are kept whole with their lists; each brick they list is cropped
    to its cells within one cell width of the grown piece (a cell's basis
    support reaches half its width beyond it, so no sample of the piece loses a
    term), and dropped from the lists where nothing of it is left (its terms
    there are exactly zero). `crop` False keeps the bricks whole."""
    from .bvh import build_bvh

    lo = np.asarray(lower, np.float64) - halo
    hi = np.asarray(upper, np.float64) + halo
    keep = np.flatnonzero(np.all(regions.lower_lattice < hi, axis=1)
                          & np.all(regions.upper_lattice > lo, axis=1))
    start, ids = regions.brick_start, regions.brick_ids
    gather = _ranges(start[keep], (start[keep + 1] - start[keep]).astype(np.int64))
    listed = ids[gather]
    owner = np.repeat(np.arange(len(keep)), (start[keep + 1] - start[keep]).astype(np.int64))
    used = np.unique(listed)
    # crop the used bricks to [lo - w, hi + w] (w: their cell width), in cells
    width = np.ldexp(1.0, bricks.level[used].astype(np.int32))[:, None]
    corner = bricks.lower_lattice[used].astype(np.float64)
    dims = bricks.dims[used].astype(np.int64)
    first = np.clip(np.floor((np.where(np.isfinite(lo), lo, -np.inf) - width - corner) / width),
                    0, dims).astype(np.int64)
    last = np.clip(np.ceil((np.where(np.isfinite(hi), hi, np.inf) + width - corner) / width),
                   0, dims).astype(np.int64)
    if not crop:
        first, last = np.zeros_like(dims), dims
    new_dims = np.maximum(last - first, 0)
    alive = new_dims.prod(axis=1) > 0
    # lists without the bricks cropped away, renumbered
    number = np.cumsum(alive) - 1
    slot = np.searchsorted(used, listed)
    kept = alive[slot]
    counts = np.bincount(owner[kept], minlength=len(keep))
    new_start = np.zeros(len(keep) + 1, start.dtype)
    np.cumsum(counts, out=new_start[1:])
    sub_regions = regions.replace(
        lower_lattice=regions.lower_lattice[keep], upper_lattice=regions.upper_lattice[keep],
        brick_start=new_start, brick_ids=number[slot[kept]].astype(ids.dtype),
        value_range=regions.value_range[keep], finest_level=regions.finest_level[keep], meta={})
    src, first, new_dims, dims = used[alive], first[alive], new_dims[alive], dims[alive]
    cells = new_dims.prod(axis=1)
    offset = np.zeros(len(src), bricks.offset.dtype)
    np.cumsum(cells[:-1], out=offset[1:])
    values = bricks.values[:, _crop_indices(bricks.offset[src], dims, first, new_dims, cells)]
    sub_bricks = bricks.replace(
        lower_lattice=(bricks.lower_lattice[src] + first * np.ldexp(
            1, bricks.level[src].astype(np.int64))[:, None]).astype(bricks.lower_lattice.dtype),
        level=bricks.level[src], dims=new_dims.astype(bricks.dims.dtype), offset=offset,
        values=values, meta={})
    return sub_bricks, sub_regions, build_bvh(sub_regions)


def _crop_indices(offset, dims, first, new_dims, cells) -> np.ndarray:
    """Value indices of the sub-boxes [first, first + new_dims) of bricks of `dims`
    (x fastest) whose values start at `offset`, brick after brick."""
    total = int(cells.sum())
    brick = np.repeat(np.arange(len(cells)), cells)
    j = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(cells) - cells, cells)
    nx, ny = new_dims[brick, 0], new_dims[brick, 1]
    x, y, z = j % nx, (j // nx) % ny, j // (nx * ny)
    dx, dy = dims[brick, 0], dims[brick, 1]
    f = first[brick]
    return offset[brick] + ((z + f[:, 2]) * dy + (y + f[:, 1])) * dx + (x + f[:, 0])


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The concatenated index ranges [starts[i], starts[i] + counts[i])."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    first = np.repeat(np.asarray(starts, np.int64) - np.concatenate([[0], np.cumsum(counts)[:-1]]),
                      counts)
    return first + np.arange(total, dtype=np.int64)


def eye_lattice(bricks: schema._Kind, position) -> np.ndarray:
    """A world point (the camera's position) in lattice units."""
    return (np.asarray(position, np.float64) - bricks.origin_world) / bricks.spacing_world


def composite(front: np.ndarray, back: np.ndarray) -> np.ndarray:
    """Premultiplied RGBA `back` seen through `front` (front to back, in place
    into `front`): C = C_front + (1 - A_front) C_back."""
    front += (1.0 - front[..., 3:4]) * back
    return front
