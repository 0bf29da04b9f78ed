"""The look of a scene as the render kernel takes it (kernels/look.cl reads it):
transfer functions and colour maps as merged knots, their knot indexes and
lookup tables, the volume layers, iso-surfaces, slices, meshes' colours and
clipping by field index on the device, packed into one float and one int
buffer with their eb_params offsets."""

from __future__ import annotations

import numpy as np

from ..scene import Scene
from ..picture.transfer_function import TABLE_TOLERANCE, knot_buckets
from ..util.vectors import unit
from .device_data import DeviceDataset, gradient_scales
from .grouped import Grouped


# Iso-hit refinement tolerance, in finest cell widths (docs/design.md).
ISO_TOLERANCE_CELLS = 1e-3


def frame_arrays(scene: Scene, device_dataset: DeviceDataset,
                 copies=None, majorants=None) -> tuple[tuple, dict, list]:
    """The look of `scene` as the render kernel takes it: its float and int arrays
    (look_f, look_i of kernels/render.cl), their eb_params members, and how each
    volume layer is looked up (the stats' "transfer_function_tables"). Every
    transfer function and colour map as merged knots one after the other (and
    each volume layer's knot index, transfer_function.knot_buckets, and lookup
    table, transfer_function.lookup_table, unless --tf-lookup exact or the table
    is further than TABLE_TOLERANCE from the knots), the volume layers,
    iso-surfaces and slices by field index on the device, clipping, and the
    `copies` of overlapping instances (Renderer._mixture; None: none) and the path
    integrator's `majorants` (exabricks.engine.majorants; None: none)."""
    index = {name: i for i, name in enumerate(device_dataset.fields)}
    exponents = device_dataset.exponents
    xs, rgba = [], []

    def value(v, field):  # a data value as the device holds the field's (DeviceDataset.scaled)
        return np.ldexp(np.asarray(v, np.float64), exponents.get(field, 0))

    def knots(tf, field) -> tuple[int, int]:
        x, c = tf.merged_knots(np.float32, exponents.get(field, 0))
        first = sum(len(k) for k in xs)
        xs.append(x)
        rgba.append(np.asarray(c, np.float32))
        return first, len(x)

    buckets = []  # each volume layer's knot index (knot_buckets), its offset in layer.w
    floats, ints = Grouped(np.float32), Grouped(np.int32)
    tables, table_at = [], []  # each volume layer's lookup table (stats) and its float4 offset

    def layer(volume) -> tuple[int, int, int, int]:
        first, n = knots(volume.transfer_function, volume.field)
        offset = sum(len(b) for b in buckets)
        buckets.append(knot_buckets(xs[-1]))
        table = _table(volume, scene.settings)
        exact = table is None
        table_at.append(-1 if exact else floats.add(_table_rows(table, volume, exponents), 4) // 4)
        tables.append({"lookup": "exact"} if exact else
                      {"lookup": "table", "intervals": len(table.rows) - 2,
                       "error_rgb": table.error_rgb, "error_alpha": table.error_alpha})
        return index[volume.field], first, n, offset

    layers = [layer(v) for v in scene.volumes]
    iso, iso_value, iso_color = [], [], []
    for surface in scene.isosurfaces:
        first, n = knots(surface.colormap, surface.color_field) \
            if surface.colormap is not None else (0, 0)
        color_field = index[surface.color_field] if surface.color_field else -1
        iso.append((index[surface.field], color_field, first, n))
        iso_value.append((value(surface.value, surface.field), surface.opacity, 0.0, 0.0))
        iso_color.append((*surface.color, 0.0))
    mesh_color, mesh_info = [], []
    for mesh in scene.meshes:
        first, n = knots(mesh.colormap, mesh.color_field) if mesh.colormap is not None else (0, 0)
        mesh_color.append((*mesh.color, mesh.opacity))
        mesh_info.append((index[mesh.color_field] if mesh.color_field else -1, first, n, 0))
    slices, slice_point, slice_normal = [], [], []
    for plane in scene.slices:
        slices.append((index[plane.field], *knots(plane.colormap, plane.field), 0))
        slice_point.append((*plane.point, plane.opacity))
        slice_normal.append((*unit(plane.normal), 0.0))
    clip = scene.clip
    box = clip.box or ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    planes = [(*p, 0.0) for point, normal in clip.planes
              for p in (point, unit(normal))]
    cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape, np.float32)
    rows = lambda r, dtype: np.asarray(r, dtype).reshape(-1, 4)
    params = {
        "tf_xs_at": floats.add(cat(xs, (1,))), "tf_rgba_at": floats.add(cat(rgba, (1, 4)), 4),
        "gradient_scale_at": floats.add(gradient_scales(device_dataset.spacing_world, device_dataset.fields,
                                                        device_dataset.magnitudes, scene.volumes,
                                                        exponents), 4),
        "iso_value_at": floats.add(rows(iso_value, np.float32), 4),
        "iso_color_at": floats.add(rows(iso_color, np.float32), 4),
        "slice_point_at": floats.add(rows(slice_point, np.float32), 4),
        "slice_normal_at": floats.add(rows(slice_normal, np.float32), 4),
        "clip_planes_at": floats.add(rows(planes, np.float32), 4),
        "layers_at": ints.add(rows(layers or [(0, 0, 0, 0)], np.int32), 4),
        "iso_at": ints.add(rows(iso, np.int32), 4), "slices_at": ints.add(rows(slices, np.int32), 4),
        "mesh_colors_at": floats.add(rows(mesh_color, np.float32), 4),
        "mesh_info_at": ints.add(rows(mesh_info, np.int32), 4), "n_meshes": len(mesh_color),
        "buckets_at": ints.add(np.concatenate(buckets) if buckets else np.zeros(0, np.int32)),
        "tables_at": ints.add(np.asarray(table_at or [-1], np.int32)),
        "n_layers": len(layers), "n_iso": len(iso), "n_slices": len(slices),
        "iso_tolerance": ISO_TOLERANCE_CELLS * device_dataset.finest_width_world,
        "clip_box": clip.box is not None, "clip_lower": (*box[0], 0.0),
        "clip_upper": (*box[1], 0.0), "n_clip_planes": len(clip.planes),
        "copies_at": floats.add(rows(np.zeros((0, 4)) if copies is None else copies, np.float32), 4),
        "n_copies": 0 if copies is None else len(copies),
        "copy_rows": 0 if copies is None else copies.shape[1],
        "majorant_at": floats.add(np.zeros(1, np.float32) if majorants is None else majorants),
    }
    return (floats.array(), ints.array()), params, tables


def _table(volume, settings):
    """The lookup table of a volume layer, or None where it is looked up exactly
    (--tf-lookup exact, or its table further than TABLE_TOLERANCE from the knots)."""
    if settings.tf_lookup != "table":
        return None
    table = volume.transfer_function.table
    return None if max(table.error_rgb, table.error_alpha) > TABLE_TOLERANCE else table


def _table_rows(table, volume, exponents: dict) -> np.ndarray:
    """A volume layer's lookup table as the kernel reads it for the field's values
    as the device holds them (DeviceDataset.scaled): its header (x0, K / span, K)
    made again in float64 for a scaled field (K / span of a tiny span overflows
    float32 before it is scaled)."""
    e = exponents.get(volume.field, 0)
    if e == 0:
        return table.rows
    x, _ = volume.transfer_function.merged_knots(np.float64, e)
    rows = table.rows.copy()
    k = float(rows[0, 2])
    rows[0, :2] = x[0], k / (x[-1] - x[0]) if x[-1] > x[0] else rows[0, 1]
    return rows


def alpha_tolerance(volume, settings) -> float:
    """How far a volume layer's opacity as the kernel reads it may be above its
    transfer function's: its lookup table's largest error, 0 where looked up exactly."""
    table = _table(volume, settings)
    return 0.0 if table is None else float(table.error_alpha)


def table_bytes(scene: Scene) -> int:
    """Bytes of the lookup tables that `frame_arrays` puts in the look of `scene`."""
    return sum(t.rows.nbytes for t in (_table(v, scene.settings) for v in scene.volumes) if t)
