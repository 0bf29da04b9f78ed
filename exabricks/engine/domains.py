"""The share of a dataset one domain needs (docs/design-scale.md, "Data-parallel
rendering and MPI"; the domains are exabricks.engine.partition's boxes).

`domain_data` is what a domain's renderer loads: the regions whose boxes overlap
the domain (grown by a halo where central differences look a cell outside
it), the bricks those regions list cropped to the cells that can reach the
domain, and a BVH over the regions. A frame of the domain (kernels/frame.cl
`eb_in_domain`) then takes exactly the samples of the whole frame that lie in
the domain: the same positions (the interval delimiters are those of the
unclipped regions), the same bricks (every region's whole list), so the
domains' images composited front to back in `visibility_order` equal the
one-domain frame up to float rounding. `domain_plan` and `domain_bytes` say
what a domain holds before it is read (the memory budget's planning), and
`region_blocks` how its mapped files are read in steps."""

from __future__ import annotations

import numba
import numpy as np

from .. import schema
from ..util.errors import ExabricksError


def domain_options(bricks: schema.Bricks, scene) -> dict:
    """`domain_data`'s options for frames of `scene`: a halo of as many cells of
    the coarsest level as central differences step (CENTRAL_STEP_CELLS for volume
    samples, ISO_CENTRAL_STEP_CELLS for iso hits: kernels/frame.cl
    eb_field_gradient_by looks that far outside the domain), and no cropping of
    the bricks under level of detail (their mip levels are made from whole
    bricks)."""
    from ..util.constants import CENTRAL_STEP_CELLS, ISO_CENTRAL_STEP_CELLS

    central = scene.lighting.gradient == "central" or scene.settings.reconstruction == "nearest"
    steps = [CENTRAL_STEP_CELLS] if central else []
    if scene.isosurfaces and (central or scene.lighting.iso_gradient == "central"):
        steps.append(ISO_CENTRAL_STEP_CELLS)
    halo = 0.0
    if scene.lighting.shading != "none" and steps and bricks.n_bricks:
        halo = float(2.0 ** int(bricks.level.max())) * max(steps)
    return {"halo": halo, "crop": not scene.settings.lod > 0}


def domain_data(bricks: schema.Bricks, regions: schema.Regions, lower, upper, *,
               halo: float = 0.0, crop: bool = True, fields=None,
               where=("the bricks", "the regions"), blocks=None, touch: int | None = None):
    """(bricks, regions, bvh) of the domain [lower, upper) (module docstring).

    `halo` (lattice units) grows the domain for lookups outside it (central
    differences: up to a cell of the coarsest level). The regions that meet the
    grown domain are kept whole with their lists; each brick they list is cropped
    to its cells within one cell width of the grown domain (a cell's basis
    support reaches half its width beyond it, so no sample of the domain loses a
    term), and dropped from the lists where nothing of it is left (its terms
    there are exactly zero). `crop` False keeps the bricks whole. `fields`:
    the names of the fields to keep (default all). `blocks`: `region_blocks` of
    the regions, which finds the domain's regions without a pass over them all.
    `touch`: the most bytes of mapped brick values one step of the copy may page
    in per field (`_copy_parts`; default GATHER bricks a step), for a memory budget.

    The inputs may be mapped and unvalidated (schema.load(mapped=True)): the
    indices used are checked on the way (errors name `where`, the two files),
    and the domain is validated as a file would be."""
    from ..builders.bvh import build_bvh

    keep, used, first, new_dims, boxes = domain_plan(bricks, regions, lower, upper, halo, crop,
                                                     where, blocks)
    picked = field_rows(bricks, fields)
    start, ids = regions.brick_start, regions.brick_ids
    alive = (new_dims > 0).all(axis=1)
    # the lists without the bricks cropped away, renumbered to the domain's bricks
    number = np.full(bricks.n_bricks, -1, np.int32)
    number[used[alive]] = np.arange(int(alive.sum()))
    lists = [_renumbered_lists(start, ids, part, number) for part in _steps(keep, start, ids)]
    del number
    new_start = np.zeros(len(keep) + 1, np.int64)
    if lists:
        np.cumsum(np.concatenate([np.diff(s) for s, _ in lists]), out=new_start[1:])
    new_ids = np.concatenate([i for _, i in lists]) if lists else np.zeros(0, np.int32)
    del lists
    names = tuple(bricks.fields[f] for f in picked)
    box_lo, box_hi, ranges, finest = _take(keep, regions.lower_lattice, regions.upper_lattice,
                                           regions.value_range, regions.finest_level)
    sub_regions = regions.replace(
        fields=names, lower_lattice=box_lo, upper_lattice=box_hi,
        brick_start=new_start.astype(start.dtype, copy=False),
        brick_ids=new_ids.astype(ids.dtype, copy=False),
        value_range=np.ascontiguousarray(ranges[:, picked]), finest_level=finest, meta={})
    del ranges
    first, new_dims = first[alive], new_dims[alive]
    lower_lattice, level, dims, offsets = (b[alive] for b in boxes)
    del used, alive, boxes
    cells = new_dims.astype(np.int64).prod(axis=1)
    offset = np.zeros(len(cells), np.int64)
    np.cumsum(cells[:-1], out=offset[1:])
    values = np.empty((len(picked), int(cells.sum())), np.float32)
    rows = np.asarray(picked, np.int64)
    base = getattr(bricks.values, "offset", 0) + rows[0] * bricks.values.shape[1] * 4 if len(rows) else 0
    for part in _copy_parts(offsets, dims, touch, base):
        _copy_crops(bricks.values, rows, offsets[part], dims[part], first[part],
                    new_dims[part], offset[part], values)
        schema.release_arrays(bricks.values)
    lower_lattice += first << level[:, None].astype(first.dtype)
    sub_bricks = bricks.replace(fields=names, lower_lattice=lower_lattice, level=level,
                                dims=new_dims.astype(bricks.dims.dtype, copy=False),
                                offset=offset.astype(bricks.offset.dtype, copy=False),
                                values=values, meta={})
    schema.validate(sub_bricks, f"{where[0]} (a domain)")
    schema.validate(sub_regions, f"{where[1]} (a domain)")
    return sub_bricks, sub_regions, build_bvh(sub_regions)


# Resident bytes a read of one value of a mapped file can bring in: Linux maps the
# whole page-cache folio around a read fault, and xfs, and ext4 since Linux 6.16,
# cache files in folios of up to 2 MiB, so that a brick far from the previous one
# costs up to this much until its step's pages are handed back (measured:
# docs/benchmarks-scale.md, "The memory budget on every layout").
GRAIN = 1 << 21


def _copy_parts(offsets: np.ndarray, dims: np.ndarray, touch: int | None, base: int = 0):
    """Slices of consecutive bricks (of value `offsets` and `dims`) to copy from a
    mapped file in one step each: GATHER bricks each without `touch`; else runs
    whose values (from byte `base` of the file) lie within at most max(1, touch //
    GRAIN) GRAIN-aligned windows of the file, a run's first to last, so that a
    step of one field brings in at most that many windows of folios (a folio never
    crosses a multiple of its size), however its bricks are spread."""
    n = len(dims)
    if touch is None:
        return [slice(s, s + GATHER) for s in range(0, n, GATHER)]
    start = base + offsets.astype(np.int64) * 4
    end = start + np.maximum(dims.astype(np.int64).prod(axis=1) * 4, 1)
    first, last = (start // GRAIN).tolist(), ((end - 1) // GRAIN).tolist()
    windows = max(1, touch // GRAIN)
    parts, s, lo, hi = [], 0, first[0] if n else 0, last[0] if n else 0
    for b in range(1, n):
        lo_b, hi_b = min(lo, first[b]), max(hi, last[b])
        if hi_b - lo_b + 1 > windows:
            parts.append(slice(s, b))
            s, lo_b, hi_b = b, first[b], last[b]
        lo, hi = lo_b, hi_b
    if n:
        parts.append(slice(s, n))
    return parts


def field_rows(bricks: schema.Bricks, fields) -> list[int]:
    """The rows of `bricks.values` of the names `fields` (all of them for None)."""
    if fields is None:
        return list(range(bricks.n_fields))
    return [bricks.field_index(f) for f in dict.fromkeys(fields)]


def domain_plan(bricks, regions, lower, upper, halo, crop, where, blocks=None):
    """(keep, used, first, new_dims, boxes): the regions meeting the domain grown
    by `halo` (found through `blocks`, `region_blocks`, when given), the bricks
    they list, each one's cells kept (`_crop_boxes`), and their lower_lattice,
    level, dims and offset; every index followed is checked (domain_data)."""
    lo = np.asarray(lower, np.float64) - halo
    hi = np.asarray(upper, np.float64) + halo
    keep = _meeting(regions, lo, hi, blocks)
    start, ids = regions.brick_start, regions.brick_ids
    used_mask = np.zeros(bricks.n_bricks, np.bool_)
    for part in _steps(keep, start, ids):
        begin, end = start[part], start[part + 1]
        if (end < begin).any() or begin.min() < 0 or int(end.max()) > ids.shape[0]:
            raise ExabricksError(f"{where[1]}: brick lists out of order or beyond the list array "
                                 "(the regions file is corrupt)")
        bad = _mark_listed(start, ids, part, used_mask)
        if bad >= 0:
            raise ExabricksError(f"{where[1]}: a region lists brick {int(ids[bad])} of "
                                 f"{bricks.n_bricks}: the regions were built from other bricks")
    used = np.flatnonzero(used_mask)
    del used_mask
    # crop the used bricks to [lo - w, hi + w] (w: their cell width), in cells
    boxes = _take(used, bricks.lower_lattice, bricks.level, bricks.dims, bricks.offset)
    first, new_dims, bad = _crop_boxes(*boxes, bricks.values.shape[1], lo, hi, crop)
    if bad >= 0:
        raise ExabricksError(f"{where[0]}: brick {int(used[bad])}'s dims or value offset lie "
                             "beyond the values (the bricks file is corrupt)")
    return keep, used, first, new_dims, boxes


# Rows per step of a scattered read of mapped files (a domain's regions and
# bricks, which lie anywhere in them): each step touches at most this many
# pages of each array, handed back after it.
GATHER = 1 << 10


def _steps(index: np.ndarray, *arrays):
    """Consecutive parts of GATHER entries of `index`; the mapped pages of `arrays`
    are handed back after each part is used."""
    for s in range(0, len(index), GATHER):
        yield index[s:s + GATHER]
        schema.release_arrays(*arrays)


def _take(index: np.ndarray, *arrays) -> list[np.ndarray]:
    """[a[index] for a in arrays], read in _steps."""
    out = [np.empty((len(index),) + a.shape[1:], a.dtype) for a in arrays]
    done = 0
    for part in _steps(index, *arrays):
        for o, a in zip(out, arrays):
            o[done:done + len(part)] = a[part]
        done += len(part)
    return out


# Regions per block of `region_blocks`.
BLOCK = 1 << 10


# Regions per step of the scans of their bounds (`region_blocks`, `_meeting`): a
# multiple of BLOCK whose pages (two 192 KiB bounds arrays) and temporaries stay
# small beside a budget of a few MiB, whatever the count of regions.
SCAN = 1 << 14


def region_blocks(regions: schema.Regions) -> tuple[np.ndarray, np.ndarray]:
    """The bounds of every BLOCK consecutive regions, (ceil(R / BLOCK), 3) each,
    gathered in steps: a spatial index for `_meeting`, tight because the builder
    stores regions in its k-d tree's order."""
    n = regions.n_regions
    lo = np.empty((-(-n // BLOCK), 3), regions.lower_lattice.dtype)
    hi = np.empty_like(lo)
    for s in range(0, n, SCAN):  # SCAN is a multiple of BLOCK
        for bounds, out, reduce in ((regions.lower_lattice, lo, np.min),
                                    (regions.upper_lattice, hi, np.max)):
            part = np.asarray(bounds[s:s + SCAN])
            whole = len(part) // BLOCK * BLOCK
            b = s // BLOCK
            out[b:b + whole // BLOCK] = reduce(part[:whole].reshape(-1, BLOCK, 3), axis=1)
            if whole < len(part):
                out[b + whole // BLOCK] = reduce(part[whole:], axis=0)
        schema.release_arrays(regions.lower_lattice, regions.upper_lattice)
    return lo, hi


def _meeting(regions: schema.Regions, lo: np.ndarray, hi: np.ndarray, blocks=None) -> np.ndarray:
    """Ids of the regions whose boxes overlap the open box (lo, hi), ascending: of
    every region, or with `blocks` (`region_blocks`) of the blocks that meet it;
    found in steps (the pages of mapped boxes handed back after each)."""
    if blocks is None:
        spans = [(0, regions.n_regions)]
    else:
        meet = np.flatnonzero(np.all(blocks[0] < hi, axis=1) & np.all(blocks[1] > lo, axis=1))
        breaks = np.flatnonzero(np.diff(meet) > 1) + 1
        spans = [(int(run[0]) * BLOCK, min(regions.n_regions, (int(run[-1]) + 1) * BLOCK))
                 for run in np.split(meet, breaks) if run.size]
    found = []
    for begin, end in spans:
        for s in range(begin, end, SCAN):
            e = min(end, s + SCAN)
            low, up = regions.lower_lattice[s:e], regions.upper_lattice[s:e]
            found.append(s + np.flatnonzero(np.all(low < hi, axis=1) & np.all(up > lo, axis=1)))
            schema.release_arrays(regions.lower_lattice, regions.upper_lattice)
    return np.concatenate(found) if found else np.zeros(0, np.int64)


def domain_bytes(bricks: schema.Bricks, regions: schema.Regions, plan, fields=None) -> int:
    """Bytes a Renderer of the domain of `plan` (`domain_plan`) holds on the host
    and the device together: its structures (brick values of `fields` cropped,
    boxes; regions and their lists; a BVH of at most two nodes per region) and
    the float4 copies the device takes of the boxes (device_data.DeviceDataset),
    over-counting lists by the bricks cropped away."""
    keep, used, _, new_dims = plan[:4]
    cells = int(new_dims.astype(np.int64).prod(axis=1).sum())
    start = regions.brick_start
    lists = sum(int((start[part + 1] - start[part]).sum()) for part in _steps(keep, start))
    n_fields = len(field_rows(bricks, fields))
    brick = 3 * 4 + 1 + 3 * 4 + 8 + 16 + 16  # lower, level, dims, offset; device box, dims
    region = 2 * 3 * 4 + 8 * n_fields + 1 + 8 + 32 + 8  # boxes, ranges, level, start; device
    node = 2 * (2 * 3 * 4 + 8 * n_fields + 8 + 32 + 8 + 1) + 4 + 4  # two nodes, links, index
    return cells * 4 * n_fields + len(used) * brick + len(keep) * (region + node) + lists * 4


@numba.njit(cache=True)
def _mark_listed(start, ids, keep, used):
    """used[b] = True for every brick b the regions `keep` list; the position in
    `ids` of the first id out of range, else -1."""
    n = used.shape[0]
    for r in keep:
        for k in range(start[r], start[r + 1]):
            b = ids[k]
            if b < 0 or b >= n:
                return k
            used[b] = True
    return -1


@numba.njit(cache=True)
def _crop_boxes(lower, level, dims, offset, n_values, lo, hi, crop):
    """(first, new_dims, bad): per brick (lower, level, dims, offset), the cells
    [first, first + new_dims) within one cell width of the box [lo, hi]
    (lattice units; all of them without `crop`); `bad` the position of a brick
    whose dims or value range are impossible, else -1."""
    first = np.zeros((len(level), 3), np.int32)
    new_dims = np.zeros((len(level), 3), np.int32)
    for b in range(len(level)):
        cells = 1
        for a in range(3):
            if dims[b, a] < 1:
                return first, new_dims, b
            cells *= dims[b, a]
        if offset[b] < 0 or offset[b] + cells > n_values or level[b] < 0 or level[b] > 30:
            return first, new_dims, b
        w = float(1 << level[b])
        for a in range(3):
            f, l = 0, dims[b, a]
            if crop:
                f = int(min(max(np.floor((lo[a] - w - lower[b, a]) / w), 0.0), dims[b, a]))
                l = int(min(max(np.ceil((hi[a] + w - lower[b, a]) / w), 0.0), dims[b, a]))
            first[b, a] = f
            new_dims[b, a] = max(l - f, 0)
    return first, new_dims, -1


@numba.njit(cache=True)
def _renumbered_lists(start, ids, keep, number):
    """CSR lists of the regions `keep`: their ids mapped by `number`, those mapped
    to -1 left out."""
    new_start = np.zeros(len(keep) + 1, np.int64)
    total = 0
    for i in range(len(keep)):
        r = keep[i]
        for k in range(start[r], start[r + 1]):
            if number[ids[k]] >= 0:
                total += 1
        new_start[i + 1] = total
    out = np.empty(total, np.int32)
    j = 0
    for r in keep:
        for k in range(start[r], start[r + 1]):
            m = number[ids[k]]
            if m >= 0:
                out[j] = m
                j += 1
    return new_start, out


@numba.njit(cache=True)
def _copy_crops(values, rows, offset, dims, first, new_dims, new_offset, out):
    """Into `out` (len(rows), total): the values of the fields `rows` of the
    sub-boxes [first, first + new_dims) of bricks of `dims` (x fastest) at
    `offset` in `values`, each at its `new_offset`."""
    for b in range(len(offset)):
        nx, ny, nz = new_dims[b, 0], new_dims[b, 1], new_dims[b, 2]
        dx, dy = dims[b, 0], dims[b, 1]
        x0, y0, z0 = first[b, 0], first[b, 1], first[b, 2]
        j = new_offset[b]
        for z in range(nz):
            for y in range(ny):
                i = offset[b] + ((z + z0) * dy + (y + y0)) * dx + x0
                for f in range(len(rows)):
                    out[f, j:j + nx] = values[rows[f], i:i + nx]
                j += nx
