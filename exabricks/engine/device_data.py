"""Bricks, regions and BVH checked against each other and uploaded to an OpenCL device.

`check_inputs` is the consistency test shared by render and probe;
`DeviceDataset` holds one dataset's buffers on one device (uploaded once, reused
for every frame or probe), grouped as the EB_DATASET_ARGS of kernels/dataset.cl
take them, and where each array starts in them (`layout`, members of
exabricks.device.kernel_abi.PARAMS).
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass

import numpy as np

from ..util import interrupt
from ..device import kernel_abi, opencl
from .. import schema
from ..util.errors import ExabricksError
from .grouped import Grouped
from .variants import device_kind, frame, program_variant, run_time_params
from .walk_links import walk_links


# Points per enqueue of `DeviceDataset.probe_fields`: a fraction of a second on a CPU device.
PROBE_CHUNK = 1 << 18

# The visibility flags' bits (kernels/traversal.cl EB_SEEN_VOLUME, EB_SEEN_ISO).
SEEN_VOLUME, SEEN_ISO = 1, 2


def load_structures(bricks_path, regions_path, bvh_path):
    """The three structure files of one dataset for a DeviceDataset, each checked for
    its kind: mapped and checked in steps, so that what the device takes as it is
    (values, lists) is shared with the page cache and what it takes in another
    layout (boxes, links) is handed back once converted."""
    bricks, regions, bvh = (schema.load(path, kind, mapped=True, checked=True) for path, kind in (
        (bricks_path, "bricks"), (regions_path, "regions"), (bvh_path, "bvh")))
    check_chain(bricks, regions, bvh, (bricks_path, regions_path, bvh_path))
    return bricks, regions, bvh


def check_chain(bricks, regions, bvh, paths) -> None:
    """ExabricksError unless the files at `paths` record that the regions were built
    from these bricks and the BVH from these regions (schema.check_built_from)."""
    schema.check_built_from(regions, paths[1], bricks, paths[0])
    schema.check_built_from(bvh, paths[2], regions, paths[1])


def check_inputs(bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh) -> None:
    """ExabricksError unless `regions` were built from `bricks` and `bvh` from `regions`.

    Checks what a mix-up of files breaks: field names, world frame, region brick
    ids in range, the BVH's region count and ids, and region/BVH nesting.
    """
    if not isinstance(bricks, schema.Bricks) or not isinstance(regions, schema.Regions) \
            or not isinstance(bvh, schema.Bvh):
        raise ExabricksError("render/probe need a bricks, a regions and a bvh input, in that order")
    for name, other in (("regions", regions), ("bvh", bvh)):
        if tuple(other.fields) != tuple(bricks.fields):
            raise ExabricksError(
                f"the {name} input has fields {list(other.fields)} but the bricks have "
                f"{list(bricks.fields)}: they were not built from the same dataset")
        if not (np.array_equal(other.origin_world, bricks.origin_world)
                and np.array_equal(other.spacing_world, bricks.spacing_world)):
            raise ExabricksError(
                f"the {name} input has another world frame (origin/spacing) than the bricks: "
                "they were not built from the same dataset")
    if regions.brick_ids.size and regions.brick_ids.min() < 0:
        raise ExabricksError(f"the regions refer to brick {int(regions.brick_ids.min())}: "
                             "brick ids cannot be negative (the regions file is corrupt)")
    if regions.brick_ids.size and regions.brick_ids.max() >= bricks.n_bricks:
        raise ExabricksError(
            f"the regions refer to brick {int(regions.brick_ids.max())} but there are only "
            f"{bricks.n_bricks} bricks: the regions were built from other bricks")
    n = regions.n_regions
    if bvh.region_index.shape[0] != n:
        raise ExabricksError(
            f"the bvh indexes {bvh.region_index.shape[0]} regions but the regions input has {n}: "
            "the bvh was built from other regions")
    if n and not np.array_equal(np.sort(bvh.region_index), np.arange(n, dtype=bvh.region_index.dtype)):
        raise ExabricksError("the bvh does not list every region exactly once: it is corrupt "
                             "or was built from other regions")
    if n and bvh.n_nodes:
        root_lo = bvh.lower_lattice[0]
        root_hi = bvh.upper_lattice[0]
        if np.any(regions.lower_lattice < root_lo) or np.any(regions.upper_lattice > root_hi):
            raise ExabricksError("the regions lie outside the bvh's bounds: "
                                 "the bvh was built from other regions")
    if n and not bvh.n_nodes:
        raise ExabricksError("the bvh has no nodes but there are regions to render")


def check_device_memory(device, buffers: dict[str, int]) -> None:
    """ExabricksError unless every buffer (name -> bytes) fits the device's
    largest allocation and all of them its global memory, so that a dataset or
    image too large fails with a message instead of in the OpenCL runtime."""
    largest = int(device.max_mem_alloc_size)
    total = int(device.global_mem_size)
    name = device.name.strip()
    for what, nbytes in buffers.items():
        if nbytes > largest:
            raise ExabricksError(f"the {what} need {nbytes / 2**30:.2f} GiB in one buffer, more "
                                 f"than the {largest / 2**30:.2f} GiB the device {name} allows")
    if sum(buffers.values()) > total:
        raise ExabricksError(f"the dataset needs {sum(buffers.values()) / 2**30:.2f} GiB on the "
                             f"device, more than the {total / 2**30:.2f} GiB of {name}")


def finest_cell_width_world(bricks: schema.Bricks) -> float:
    """World width of the dataset's finest cell: 2**min(level) * min(spacing)."""
    level = int(bricks.level.min()) if bricks.n_bricks else 0
    return float(2.0 ** level * bricks.spacing_world.min())


def field_magnitude(values: np.ndarray) -> float:
    """The largest finite |value| of one field (1 when there is none)."""
    def largest(chunk):
        finite = np.abs(chunk[np.isfinite(chunk)])
        return float(finite.max()) if finite.size else 0.0

    magnitude = schema.reduce_chunks(values, largest, max)
    return magnitude if magnitude > 0 else 1.0


# Fields whose largest |value| lies outside [2**-VALUE_EXPONENT_LIMIT,
# 2**VALUE_EXPONENT_LIMIT] reach the device times a power of two that brings it
# to [1, 2) (`value_exponent`), and so do their transfer functions' knots, iso-values
# and colour-map ranges (exabricks.engine.look): a field of 1e-39 would otherwise be
# summed and interpolated in float32's subnormals, which CPU devices flush to zero,
# and one of 3e38 would overflow in the reconstruction's sums. A power of two is
# exact; fields within the limits are uploaded as they are, bit for bit.
VALUE_EXPONENT_LIMIT = 32


def value_exponent(magnitude: float) -> int:
    """The power of two (its exponent) a field of largest |value| `magnitude` is
    scaled by on the device (VALUE_EXPONENT_LIMIT), 0 for most fields."""
    if 2.0 ** -VALUE_EXPONENT_LIMIT <= magnitude <= 2.0 ** VALUE_EXPONENT_LIMIT:
        return 0
    return 1 - math.frexp(magnitude)[1]  # magnitude = m 2**e, m in [0.5, 1)


def seen_bits(ranges, field_index, layers=(), isovalues=()) -> np.ndarray:
    """uint8 (M,) bits of M value ranges ((M, fields, 2): nodes' or regions'):
    SEEN_VOLUME where some volume layer (field name, transfer function) has a
    maximum alpha above 0 over the range, SEEN_ISO where some iso-value (field
    name, value) lies inside it. `field_index`: a field's column. In steps
    (schema.rows: small temporaries, a mapped array's pages handed back)."""
    seen = np.zeros(ranges.shape[0], np.uint8)
    for start, (part,) in schema.rows(ranges):
        here = seen[start:start + part.shape[0]]
        for name, tf in layers:
            r = part[:, field_index(name)]
            here |= tf.any_alpha(r[:, 0], r[:, 1]) * np.uint8(SEEN_VOLUME)
        for name, value in isovalues:
            r = part[:, field_index(name)]
            here |= ((r[:, 0] <= value) & (value <= r[:, 1])) * np.uint8(SEEN_ISO)
    return seen


@dataclass(frozen=True)
class DatasetScale:
    """What a dataset's frames are scaled by: its finest cell width (the default
    unit distance) and each field's magnitude (the gradient scales). A domain of
    a dataset (exabricks.engine.partition) renders with the whole's."""

    finest_width_world: float
    magnitudes: dict  # field name -> magnitude

    @property
    def exponents(self) -> dict:
        """Field name -> the power of two its values are scaled by on the device."""
        return {f: value_exponent(m) for f, m in self.magnitudes.items()}

    @classmethod
    def of(cls, bricks: schema.Bricks, fields) -> "DatasetScale":
        return cls(finest_cell_width_world(bricks),
                   {f: field_magnitude(bricks.values[bricks.field_index(f)]) for f in fields})


# Finest cells over which a change of a layer's whole transfer-function range is a
# gradient of strength 1: where a volume sample is shaded fully (kernels/look.cl,
# eb_headlight; docs/design-rendering.md, "Volume shading").
SHADING_CELLS = 1.0
# The smallest range a gradient is measured against, as a share of the field's
# largest |value|: keeps the kernel's dot(g, g) far from float overflow.
MIN_SHADING_SPAN = 1e-6


def gradient_scale(spacing_world, span: float) -> np.ndarray:
    """Per-axis factor turning a lattice-unit gradient into one parallel to the
    world-unit gradient whose length is 1 where the field changes by `span` over
    SHADING_CELLS finest cells: 1 / spacing divided by its largest component,
    times SHADING_CELLS / span."""
    inv = 1.0 / np.asarray(spacing_world, np.float64)
    return inv / inv.max() * SHADING_CELLS / span


def gradient_scales(spacing_world, fields, magnitudes: dict, volumes=(),
                    exponents: dict | None = None) -> np.ndarray:
    """(F, 4) float32 rows of `gradient_scale` of each of `fields`: against the
    value range of the first volume layer of that field (`volumes`: the scene's
    VolumeLayer), else against the field's largest |value| (`magnitudes`), for
    values scaled by 2**`exponents` (value_exponent; default none)."""
    spans = {}
    for layer in volumes:
        lo, hi = layer.transfer_function.value_range
        spans.setdefault(layer.field, hi - lo)
    rows = []
    for f in fields:
        floor = MIN_SHADING_SPAN * magnitudes[f]
        span = math.ldexp(max(spans.get(f, magnitudes[f]), floor), (exponents or {}).get(f, 0))
        rows.append([*gradient_scale(spacing_world, span), 0.0])
    return np.array(rows or [[1.0, 1.0, 1.0, 0.0]], np.float32)


def _packed(dtype, *parts) -> np.ndarray:
    """Parts ((n,) or (n, k) arrays) side by side as the columns of one (n, width)
    `dtype` array, written in place: the rows of OpenCL's int2, int4 or float4."""
    widths = [1 if p.ndim == 1 else p.shape[1] for p in parts]
    out = np.empty((parts[0].shape[0], sum(widths)), dtype)
    at = 0
    for part, width in zip(parts, widths):
        out[:, at:at + width] = part.reshape(-1, width)
        at += width
    return out


class DeviceDataset:
    """One dataset resident on one OpenCL device: the structures and the values
    of `fields` (default: `field`, else the first field) only, one after the
    other (the kernels' field f is fields[f]; the program is built with
    -DEB_N_FIELDS). `scale`: the DatasetScale of the whole dataset when
    `bricks` are a domain of it (exabricks.engine.partition; default: theirs),
    so that a domain renders as the whole does."""

    def __init__(self, bricks: schema.Bricks, regions: schema.Regions, bvh: schema.Bvh,
                 *, field: str | None = None, fields=None, device=None,
                 scale: DatasetScale | None = None):
        check_inputs(bricks, regions, bvh)
        self.bricks, self.regions, self.bvh = bricks, regions, bvh
        if fields is None or not len(fields):
            fields = (bricks.fields[bricks.field_index(field)],) if bricks.fields else ()
        self.fields = tuple(dict.fromkeys(fields))
        self.field_indices = [bricks.field_index(f) for f in self.fields]
        self.field = self.fields[0] if self.fields else field
        self.field_index = self.field_indices[0] if self.fields else 0
        scale = DatasetScale.of(bricks, self.fields) if scale is None else scale
        self.device = opencl.choose_device(device)
        check_device_memory(self.device, {
            "brick values": bricks.values.shape[1] * 4 * max(1, len(self.fields)),
            "brick boxes": bricks.n_bricks * 40,
            "region lists": regions.brick_ids.nbytes + regions.brick_start.nbytes,
            "region boxes": regions.n_regions * 26,  # two float3 corners, level, visible
            "BVH nodes": bvh.n_nodes * 33 + bvh.region_index.nbytes,  # corners, int2, visible
        })
        self.context, self.queue = opencl.context_for(self.device)
        # The resident buffers share host memory on CPU devices (opencl.to_device):
        # when the dataset goes, even unwinding from a signal mid-frame, its kernels
        # must have finished before that memory is freed.
        weakref.finalize(self, self.queue.finish)
        q = self.queue

        def up(queue, array, dtype=None):  # resident for the dataset's life: shared on CPUs
            return opencl.to_device(queue, array, dtype, share=True)

        b, r = bricks, regions
        # The boxes of the BVH and of the regions, (n, 3) corners (traversal.cl,
        # EB_CORNER), and the BVH's links and leaf-order region ids, grouped.
        geometry, links, layout = Grouped(np.float32), Grouped(np.int32), {}
        for name, array in (("node_lower_at", bvh.lower_lattice), ("node_upper_at", bvh.upper_lattice),
                            ("region_lower_at", r.lower_lattice),
                            ("region_upper_at", r.upper_lattice)):
            layout[name] = geometry.add(array)
        layout["node_link_at"] = links.add(_packed(np.int32, bvh.first, bvh.count), align=2)
        layout["node_region_at"] = links.add(bvh.region_index)
        layout["node_parent_at"] = links.add(walk_links(bvh.first, bvh.count, bvh.lower_lattice,
                                                        bvh.upper_lattice))
        # Per brick its box (lower corner, 1 / width), then its dims (N, level) as int4.
        inv_width = np.ldexp(np.float32(1), -b.level.astype(np.int32))
        grid = np.concatenate([_packed(np.float32, b.lower_lattice, inv_width),
                               _packed(np.int32, b.dims, b.level).view(np.float32)])
        # A run of consecutive fields is a view (no copy of the values on the host).
        first = self.field_indices[0] if self.fields else 0
        consecutive = self.field_indices == list(range(first, first + len(self.field_indices)))
        values = b.values[first:first + max(1, len(self.field_indices))] if consecutive \
            else b.values[self.field_indices]
        self.exponents = {f: scale.exponents.get(f, 0) for f in self.fields}
        values = self.scaled(values)
        self._geometry = [up(q, geometry.array()), up(q, links.array())]
        self._lists = [up(q, r.brick_start, np.int64), up(q, r.brick_ids, np.int32),
                       up(q, grid, np.float32), up(q, b.offset, np.int64),
                       up(q, values, np.float32)]
        # node visibility | region visibility | region finest level (flags_for)
        self._finest_level = np.ascontiguousarray(r.finest_level, np.int8).view(np.uint8)
        self._all_visible = up(q, self.flags_for(None, None))
        self.layout = {**layout, "node_visible_at": 0, "region_visible_at": max(bvh.n_nodes, 1),
                       "region_level_at": max(bvh.n_nodes, 1) + max(r.n_regions, 1),
                       "n_nodes": bvh.n_nodes, "n_regions": r.n_regions,
                       "n_bricks": b.n_bricks, "field_stride": b.values.shape[1]}
        # Vertex values (reconstruction "vertex"), mip levels (--lod) and the
        # cell-location tree: made and uploaded on first use; these dummies stand in.
        self._no_per_brick = [up(q, np.zeros(1, np.int64)), up(q, np.zeros(1, np.float32))]
        self._no_tree = up(q, np.zeros(1, np.float32))
        self._vertex_args = self._mip_args = None
        # The device holds these in its own layout now: mapped pages go back.
        schema.release_arrays(b.lower_lattice, b.level, b.dims, bvh.first, bvh.count,
                              bvh.lower_lattice, bvh.upper_lattice, bvh.region_index,
                              r.lower_lattice, r.upper_lattice)

        self.spacing_world = np.array(b.spacing_world, np.float64)
        self.magnitudes = scale.magnitudes
        self.finest_width_world = scale.finest_width_world
        self.min_spacing_world = float(b.spacing_world.min())
        self._location_args = None
        self.brick_tree = self.brick_tree_seconds = None

    def program_for(self, variant, extra=()):
        """The kernel program `variant` (exabricks.engine.variants.Variant), with
        `extra` defines (tests)."""
        return opencl.program_for(self.context, (*variant.defines, *extra), capped=variant.capped)

    @property
    def empty(self) -> bool:
        return self.bvh.n_nodes == 0 or self.regions.n_regions == 0

    def visibility(self, layers=(), isovalues=()):
        """Per node and per region (paper §4.1 space skipping, per frame, no
        rebuild), uint8 (M,), (R,) bits: SEEN_VOLUME where some volume layer
        (field name, transfer function) has a maximum alpha above 0 over the
        value range, SEEN_ISO where some iso-value (field name, value) lies inside
        it (a search for iso crossings alone passes over the rest)."""
        return tuple(seen_bits(ranges, self.bricks.field_index, layers, isovalues)
                     for ranges in (self.bvh.value_range, self.regions.value_range))

    def flags_for(self, node_visible, region_visible) -> np.ndarray:
        """The flags buffer's contents: node visibility, region visibility (uint8,
        each given, or all visible) and the regions' finest levels."""
        n_nodes, n_regions = max(self.bvh.n_nodes, 1), max(self.regions.n_regions, 1)
        out = np.full(n_nodes + 2 * n_regions, SEEN_VOLUME | SEEN_ISO, np.uint8)
        if node_visible is not None:
            out[:self.bvh.n_nodes] = node_visible
        if region_visible is not None:
            out[n_nodes:n_nodes + self.regions.n_regions] = region_visible
        out[n_nodes + n_regions:n_nodes + n_regions + self.regions.n_regions] = self._finest_level
        return out

    def dataset_args(self, flags=None, reconstruction: str = "basis", lod: bool = False,
                     cell_location: bool = False) -> tuple[list, dict]:
        """The kernel arguments EB_DATASET_ARGS (kernels/dataset.cl) with the `flags`
        buffer (default: all visible) for `reconstruction`, level of detail and
        the cell-location tree, and their eb_params members (layout)."""
        layout = dict(self.layout)
        vertex, mip = self._no_per_brick, self._no_per_brick
        if reconstruction == "vertex":
            vertex, layout["vertex_stride"] = self.vertex_args()
        if lod:
            mip, layout["mip_stride"] = self.mip_args()
        tree = self._no_tree
        if cell_location:
            tree, tree_layout = self.location_args()
            layout.update(tree_layout)
        flags = self._all_visible if flags is None else flags
        return [*self._geometry, flags, *self._lists, *vertex, *mip, tree], layout

    def params(self, **values) -> np.void:
        """eb_params with this dataset's world frame and `values` (kernel_abi.params),
        the kernels' argument by value."""
        return kernel_abi.params(origin_world=(*self.bricks.origin_world, 0.0),
                                 inv_spacing=(*(1.0 / self.bricks.spacing_world), 0.0), **values)[0]

    def scaled(self, values: np.ndarray, inverse: bool = False) -> np.ndarray:
        """`values` ((F, n), a row per field of `fields`) as the device holds them:
        each row times 2**its exponent (value_exponent), or back with `inverse`;
        `values` themselves where no field is scaled."""
        exponents = [self.exponents.get(f, 0) for f in self.fields]
        if not any(exponents):
            return values
        sign = -1 if inverse else 1
        return np.stack([np.ldexp(row, sign * e) for row, e in zip(values, exponents)])

    def probe_fields(self, points_world, *, reconstruction: str = "basis") -> np.ndarray:
        """Values of every uploaded field at `points_world` (N, 3) world units ->
        (F, N) float32, F = len(self.fields), with `reconstruction`.

        NaN where no region contains the point or no cell has support there (no
        containing cell, for nearest and vertex). Points travel as float32.
        """
        return self.scaled(self._probe(points_world, reconstruction), inverse=True)

    def _probe(self, points_world, reconstruction: str) -> np.ndarray:
        """`probe_fields` as the device holds the values (`scaled`)."""
        points = np.asarray(points_world)
        if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.number):
            raise ExabricksError(f"points must be a numeric (N, 3) array, got shape {points.shape} "
                                 f"and dtype {points.dtype}")
        n = points.shape[0]
        n_fields = max(1, len(self.fields))
        out = np.full((n_fields, n), np.nan, np.float32)
        if n == 0 or self.empty:
            return out
        q = self.queue
        local = 64
        point = frame(kind=device_kind(self.device), n_fields=len(self.fields) or 1,
                      reconstruction=reconstruction)
        kernel = opencl.kernel(self.program_for(program_variant(point)), "eb_probe")
        args, layout = self.dataset_args(reconstruction=reconstruction)
        params = self.params(**layout, **run_time_params(point))
        # In chunks, so that a signal can stop a large probe between enqueues.
        chunk = min(n, PROBE_CHUNK)
        values_buf = opencl.empty_buffer(q, 4 * chunk * n_fields)
        values = np.empty(chunk * n_fields, np.float32)
        points = np.ascontiguousarray(points, np.float32)
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            kernel(q, (-(-m // local) * local,), (local,),
                   np.int32(m), opencl.to_device(q, points[start:start + m]), params,
                   *args, values_buf)
            opencl.read_back(q, values_buf, values[:m * n_fields])
            out[:, start:start + m] = values[:m * n_fields].reshape(n_fields, m)
            interrupt.raise_pending()
        return out

    def mip_args(self) -> list:
        """The bricks' mip levels for level of detail (exabricks.engine.lod), made and
        uploaded on first use."""
        if self._mip_args is None:
            from .lod import brick_mips

            offset, mips = brick_mips(self.bricks, self.field_indices or [0])
            self._mip_args = self._per_brick_args("mip levels", offset, self.scaled(mips))
        return self._mip_args

    def vertex_args(self) -> list:
        """The vertex values of every brick for reconstruction "vertex"
        (exabricks.engine.vertex: the basis field at the vertices, stitched at
        level boundaries), made with the device's basis probe on first use."""
        if self._vertex_args is None:
            from .vertex import vertex_values

            points_world = lambda lattice: self.bricks.origin_world + \
                self.bricks.spacing_world * lattice
            self._vertex_args = self._per_brick_args("vertex values", *vertex_values(
                self.bricks, lambda lattice: self._probe(points_world(lattice), "basis")))
        return self._vertex_args

    def _per_brick_args(self, what: str, offset: np.ndarray, values: np.ndarray) -> tuple:
        """([offsets (int64), values (float32 (F, n))] buffers, the stride between
        fields) of extra per-brick data, checked against the device."""
        check_device_memory(self.device, {what: values.nbytes})
        q, up = self.queue, opencl.to_device
        return [up(q, offset, np.int64), up(q, values, np.float32)], values.shape[1]

    def location_args(self) -> tuple:
        """The tree over the brick supports (exabricks.engine.cell_location) as one
        buffer of 4-byte words (kernels/dataset.cl) and its eb_params members,
        built and uploaded on the first call (kept as `brick_tree`, its build time
        in `brick_tree_seconds`)."""
        if self._location_args is None:
            start = time.perf_counter()
            from .cell_location import build_brick_tree  # numba: only for this lookup

            tree = self.brick_tree = build_brick_tree(self.bricks)
            self.brick_tree_seconds = time.perf_counter() - start
            words = Grouped(np.float32)
            layout = {"tree_lower_at": words.add(tree.lower), "tree_upper_at": words.add(tree.upper),
                      "tree_link_at": words.add(_packed(np.int32, tree.first, tree.count)
                                                .view(np.float32), align=2),
                      "tree_brick_at": words.add(np.asarray(tree.brick_index, np.int32)
                                                 .view(np.float32)),
                      "n_tree_nodes": tree.first.shape[0]}
            self._location_args = opencl.to_device(self.queue, words.array()), layout
        return self._location_args
