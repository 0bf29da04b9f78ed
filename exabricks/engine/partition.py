"""A k-d partition of space into convex domains (docs/design-scale.md, "Data-parallel
rendering and MPI").

`kd_partition` cuts the lattice space of a dataset into `n` boxes by planes at
lattice integers, each cut placed so that both sides hold their share of the
bytes (brick values and region lists, counted at the boxes' centres). The outer
faces of the outermost domains lie at infinity and every box is half-open
(lower <= p < upper), so each point of space lies in exactly one domain.

The share of the dataset each domain holds is exabricks.engine.domains'.
`budget_partition` cuts space so that every domain fits a memory budget.

`visibility_order` is the classic BSP order: at every cut the side holding the
eye comes first, which is front to back along every ray of a pinhole camera.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .. import schema
from ..util.errors import ExabricksError
from .domains import domain_bytes, domain_plan, field_rows, region_blocks


@dataclass(frozen=True)
class KdPartition:
    """Inner nodes i: axis[i] in 0..2, plane[i] (lattice units), children left[i],
    right[i] (node ids; a negative id -1 - k is domain k). `lower`, `upper`: float64
    (n, 3) half-open boxes of the domains, +-inf on the outer faces. `nbytes`: int64
    (n,) each domain's `domain_bytes`, where a budget planned it (else None)."""

    axis: np.ndarray
    plane: np.ndarray
    left: np.ndarray
    right: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    nbytes: np.ndarray | None = None

    @property
    def n_domains(self) -> int:
        return int(self.lower.shape[0])

    def visibility_order(self, eye_lattice) -> list[int]:
        """Domain ids front to back as seen from `eye_lattice` (lattice units)."""
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


# Cells per axis, at most, of the grid of bytes that the cuts are chosen on.
GRID = 128
# Bricks or regions per step when their bytes are gathered into the grid.
STEP = 1 << 18


def byte_grid(bricks: schema.Bricks, regions: schema.Regions, max_bytes: int | None = None,
              n_fields: int | None = None):
    """(grid, origin, cell): the bytes of every brick (values and box) and every
    region (box and list) spread evenly over the cells of a grid of `cell`-wide
    cells (a power of two lattice units, at most GRID per axis, from `origin`)
    that its box covers; gathered in steps, so that its memory is the grid's
    (three float64 copies of it at most: under `max_bytes` when given, by fewer
    cells per axis, but never fewer than 64). `n_fields`: the fields whose
    values count (default all)."""
    cells = GRID
    if max_bytes is not None:
        cells = int(min(GRID, max(64, (max_bytes / 24) ** (1 / 3) - 1)))
    if regions.n_regions:  # in steps: the bounds may be mapped
        origin = np.floor(schema.reduce_chunks(regions.lower_lattice, lambda a: a.min(axis=0),
                                               np.minimum)).astype(np.float64)
        top = np.ceil(schema.reduce_chunks(regions.upper_lattice, lambda a: a.max(axis=0),
                                           np.maximum)).astype(np.float64)
    else:
        origin, top = np.zeros(3), np.ones(3)
    cell = float(2.0 ** max(0, int(np.ceil(np.log2(max(float((top - origin).max()), 1.0) / cells)))))
    shape = np.maximum(np.ceil((top - origin) / cell).astype(np.int64), 1)
    edges = shape + 1
    corners = np.zeros(int(np.prod(edges)), np.float64)  # the grid's differences

    def add(lo, hi, nbytes):
        i0 = np.clip(np.floor((lo - origin) / cell).astype(np.int64), 0, shape - 1)
        i1 = np.clip(np.ceil((hi - origin) / cell).astype(np.int64), i0 + 1, shape)
        density = nbytes / (i1 - i0).prod(axis=1)
        for corner in range(8):  # inclusion-exclusion at the box's 8 corners
            pick = [(corner >> a) & 1 for a in range(3)]
            ix, iy, iz = ((i1 if p else i0)[:, a] for a, p in enumerate(pick))
            sign = -1.0 if sum(pick) % 2 else 1.0
            corners[:] += np.bincount((iz * edges[1] + iy) * edges[0] + ix,
                                      weights=sign * density, minlength=corners.size)

    per_cell = 4.0 * (bricks.n_fields if n_fields is None else n_fields)
    step = STEP if max_bytes is None else int(min(STEP, max(4096, max_bytes // 256)))
    for s in range(0, bricks.n_bricks, step):
        dims = bricks.dims[s:s + step].astype(np.float64)
        lo = bricks.lower_lattice[s:s + step].astype(np.float64)
        hi = lo + dims * np.ldexp(1.0, bricks.level[s:s + step].astype(np.int32))[:, None]
        add(lo, hi, dims.prod(axis=1) * per_cell + 40.0)
        schema.release(bricks)  # mapped inputs: only a step's pages at a time
    for s in range(0, regions.n_regions, step):
        lists = np.diff(regions.brick_start[s:s + step + 1]).astype(np.float64)
        add(regions.lower_lattice[s:s + step].astype(np.float64),
            regions.upper_lattice[s:s + step].astype(np.float64),
            34.0 + 8.0 * regions.n_fields + 4.0 * lists)
        schema.release(regions)
    grid = corners.reshape(edges[::-1]).transpose(2, 1, 0)
    for a in range(3):
        grid = np.cumsum(grid, axis=a)
    return grid[:-1, :-1, :-1], origin, cell


def kd_partition(bricks: schema.Bricks, regions: schema.Regions, n: int) -> KdPartition:
    """`n` domains of about equal bytes (module docstring): each cut halves (for an
    odd count, splits in proportion) the bytes of its box along the box's
    longest axis, at a cell boundary of `byte_grid`."""
    if int(n) < 1:
        raise ExabricksError(f"a partition needs at least one domain, got {n}")

    def split(lower, upper, count, block):
        return None if count == 1 else ((count // 2) / count, count // 2, count - count // 2)

    return _kd_tree(*byte_grid(bricks, regions), split, int(n))


class _Uncuttable(ExabricksError):
    """A box of one cell of the byte grid that would have to be cut."""


def budget_partition(bricks: schema.Bricks, regions: schema.Regions, max_bytes: int, *,
                     fields=None, halo: float = 0.0, crop: bool = True,
                     where=("the bricks", "the regions"),
                     grid_bytes: int | None = None, blocks=None) -> KdPartition:
    """Domains each of whose `domain_data` (of `fields`, with `halo` and `crop`)
    holds at most `max_bytes` on the host and the device together
    (`domain_bytes`): a box is cut in halves of its bytes, as `kd_partition`
    cuts, until its exact domain fits. ExabricksError when a domain that fits
    would be smaller than a cell of the byte grid (at most `grid_bytes`),
    naming the bytes needed. `blocks`: `region_blocks` of the regions (made here
    when not given)."""
    blocks = region_blocks(regions) if blocks is None else blocks

    def split(lower, upper, _, block):
        if max(block.shape) > 1 and block.sum() > max_bytes:
            # the grid's estimate undercounts a domain: cut at once
            return 0.5, None, None
        plan = domain_plan(bricks, regions, lower, upper, halo, crop, where, blocks)
        need = domain_bytes(bricks, regions, plan, fields)
        for whole in (bricks, regions):  # mapped inputs: the plan's pages go back
            schema.release(whole)
        if need <= max_bytes:
            needs[_box_key(lower, upper)] = need
            return None
        smallest[0] = min(smallest[0], need)
        return 0.5, None, None

    smallest, needs = [np.inf], {}
    try:
        grid = byte_grid(bricks, regions, grid_bytes, len(field_rows(bricks, fields)))
        tree = _kd_tree(*grid, split, None)
        return dataclasses.replace(tree, nbytes=np.array(
            [needs[_box_key(lo, hi)] for lo, hi in zip(tree.lower, tree.upper)], np.int64))
    except _Uncuttable:
        raise ExabricksError(
            f"domains of {mib(max_bytes)} are too small for this dataset: the smallest domain it "
            f"can be cut into holds {mib(smallest[0])}") from None


def _box_key(lower, upper) -> tuple:
    return tuple(float(x) for x in (*lower, *upper))


def mib(nbytes) -> str:
    """A byte count for messages, in MiB (KiB below one MiB, bytes below one KiB)."""
    if nbytes < 2**10:
        return f"{int(nbytes)} byte{'' if nbytes == 1 else 's'}"
    if nbytes < 2**20:
        return f"{nbytes / 2**10:,.1f} KiB"
    return f"{nbytes / 2**20:,.{1 if nbytes < 10 * 2**20 else 0}f} MiB"


def _kd_tree(grid, origin, cell, split, payload) -> KdPartition:
    """The k-d tree whose boxes `split`(lower, upper, payload, the box's cells of
    `grid`) cuts: it returns None for a domain, else (share of the box's bytes
    before the cut, the two halves' payloads); each cut lies across the box's
    longest axis at a cell boundary of `grid` (`_cut`)."""
    axis, plane, left, right, lower, upper = [], [], [], [], [], []
    stack = [(np.zeros(3, np.int64), np.array(grid.shape), np.full(3, -np.inf), np.full(3, np.inf),
              payload, None)]
    while stack:  # (grid box [g0, g1), open bounds, payload, (parent, side))
        g0, g1, open_lo, open_hi, payload, link = stack.pop()
        block = grid[g0[0]:g1[0], g0[1]:g1[1], g0[2]:g1[2]]
        cut = split(open_lo, open_hi, payload, block)
        if cut is None:
            lower.append(open_lo)
            upper.append(open_hi)
            node = -len(lower)  # -1 - k for domain k
        else:
            share, first, second = cut
            node = len(axis)
            a, k = _cut(block, g1 - g0, share)
            at = origin[a] + cell * (g0[a] + k)
            axis.append(a), plane.append(at), left.append(0), right.append(0)
            mid0, mid1 = g1.copy(), g0.copy()
            mid0[a] = mid1[a] = g0[a] + k
            hi_l, lo_r = open_hi.copy(), open_lo.copy()
            hi_l[a] = lo_r[a] = at
            stack.append((mid1, g1, lo_r, open_hi, second, (node, 1)))
            stack.append((g0, mid0, open_lo, hi_l, first, (node, 0)))
        if link is not None:
            (left if link[1] == 0 else right)[link[0]] = node
    return KdPartition(np.asarray(axis, np.int32), np.asarray(plane, np.float64),
                       np.asarray(left, np.int64), np.asarray(right, np.int64),
                       np.asarray(lower, np.float64).reshape(-1, 3),
                       np.asarray(upper, np.float64).reshape(-1, 3))


def _cut(block: np.ndarray, size: np.ndarray, share: float) -> tuple[int, int]:
    """(axis, k): the longest axis of `block` (grid cells) that is at least two cells
    long, and the cut after k of its cells (0 < k < its length) nearest to `share`
    of the block's bytes before it. A block of one cell cannot be cut: refused."""
    axes = [a for a in np.argsort(-size, kind="stable") if size[a] >= 2]
    if not axes:
        raise _Uncuttable(f"the data is too small to cut into that many domains "
                             f"(a domain would be less than one cell of {GRID}^3)")
    a = int(axes[0])
    marginal = block.sum(axis=tuple(x for x in range(3) if x != a))
    cumulative = np.cumsum(marginal)
    if cumulative[-1] > 0:  # the cell boundary nearest to the share
        k = int(np.argmin(np.abs(cumulative - share * cumulative[-1]))) + 1
    else:
        k = int(round(share * size[a]))
    return a, min(max(k, 1), int(size[a]) - 1)


def eye_lattice(frame: schema.Kind, position) -> np.ndarray:
    """A world point (the camera's position) in the lattice units of any exabricks
    object `frame` (its origin_world and spacing_world)."""
    return (np.asarray(position, np.float64) - frame.origin_world) / frame.spacing_world


def composite(front: np.ndarray, back: np.ndarray) -> np.ndarray:
    """Premultiplied RGBA `back` seen through `front` (front to back, in place
    into `front`): C = C_front + (1 - A_front) C_back."""
    front += (1.0 - front[..., 3:4]) * back
    return front


def needs_image_mode(scene) -> str | None:
    """Why a frame cannot be split by space (None if it can)."""
    if scene.isosurfaces:
        return "iso-surfaces"
    if scene.meshes:  # a mesh reaches beyond the data, where no domain is
        return "meshes"
    if scene.instances:  # each copy is drawn from the whole dataset
        return "instances"
    if scene.lighting.ao_samples:
        return "ambient occlusion"
    if scene.settings.depth:
        return "depth output"
    if scene.settings.reconstruction == "vertex":
        return "the vertex reconstruction"
    lighting = scene.lighting
    if lighting.integrator == "shadow" and lighting.shadow_rays == "traced":
        return "shadow rays (--integrator shadow --shadow-rays traced)"  # toward the light
    if lighting.integrator == "shadow" and scene.slices:  # their shadows are traced
        return "slices' shadows (--integrator shadow)"
    if scene.lighting.integrator == "path":
        return "scattered paths (--integrator path)"
    return None
