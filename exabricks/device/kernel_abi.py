"""The contract between the host and the kernels, declared once.

* `LIMITS` and `TUNABLES`: every array bound of the kernels. The host keeps its
  inputs within the limits (scene lists, tree depths, samples per ray); a
  tunable may be overridden by a build option (-DEB_QUEUE_SIZE=16).
* `PARAMS`: the scalars of one frame (or probe) and where each of the dataset's
  and the frame's arrays starts in the buffer that groups it, as one C struct
  `eb_params` that the kernels take by value or in one constant buffer
  (`params`, `params_by_value`). The
  render options declared with `kernel=True` (exabricks.scene.options) are
  members too, filled from the scene by `option_params`.
* the build defines of a kernel program come from exabricks.engine.variants.

exabricks.device.opencl.program_for puts `header()` in front of every program it
builds; kernels/common.h refuses to build without it (#error).
"""

from __future__ import annotations

import numpy as np

from ..util.constants import CENTRAL_STEP_CELLS, ISO_CENTRAL_STEP_CELLS, MAX_SAMPLES_PER_RAY, MAX_TREE_DEPTH
from ..scene.modes import MAX_INSTANCES, MAX_ISOSURFACES, MAX_MESH_HITS, MAX_SLICES, RECONSTRUCTIONS
from ..scene.options import SCENE_OPTIONS

# Samples a ray reconstructs at once on CPU devices (kernels/packet.cl): sixteen
# ran no faster on PoCL and waste more lanes at region ends (docs/design.md).
PACKET_WIDTH = 8
# Levels whose samples a --lod frame counts.
LOD_LEVELS = 16
# Mip levels kept per brick for level of detail (exabricks.engine.lod).
MAX_MIP = 6

LIMITS = {
    "EB_STACK_SIZE": MAX_TREE_DEPTH,       # tree-descent stacks: every tree is checked on load
    "EB_MAX_SAMPLES": MAX_SAMPLES_PER_RAY,  # samples of one ray: larger rates are refused
    "EB_MAX_ISO": MAX_ISOSURFACES,          # iso-surfaces of a frame
    "EB_MAX_SLICES": MAX_SLICES,            # slices of a frame
    "EB_MAX_MESH_HITS": MAX_MESH_HITS,      # mesh hits a ray composites (the nearest)
    "EB_LOD_LEVELS": LOD_LEVELS,
    "EB_MAX_MIP": MAX_MIP,
    "EB_MAX_COPIES": MAX_INSTANCES + 1,     # overlapping instances' copies, the data's included
    "EB_CENTRAL_STEP": f"{CENTRAL_STEP_CELLS!r}f",  # central differences' step, cells:
    "EB_ISO_CENTRAL_STEP": f"{ISO_CENTRAL_STEP_CELLS!r}f",  # of volume samples, of iso hits
}
TUNABLES = {
    "EB_QUEUE_SIZE": 64,   # the ordered walk's heap (traversal.cl); fuller walks re-trace
    "EB_LOCATE_MAX": 64,   # bricks a cell-location sample sorts (cell_location.cl)
}

# (name, C type): the members of eb_params in order, each naturally aligned.
# Offsets ("*_at") count elements of the buffer they index: see DeviceDataset and
# frame_arrays in exabricks.engine.
PARAMS = (
    # camera (world) and the world -> lattice map
    ("cam_origin", "float4"), ("cam_forward", "float4"), ("cam_du", "float4"),
    ("cam_dv", "float4"), ("origin_world", "float4"), ("inv_spacing", "float4"),
    # clipping box (world) and a domain's half-open box (lattice)
    ("clip_lower", "float4"), ("clip_upper", "float4"),
    ("domain_lower", "float4"), ("domain_upper", "float4"),
    # the shadow integrator's light (kernels/light.cl): direction toward it (unit,
    # world), colour x intensity and, in w, the ambient term
    ("light_dir", "float4"), ("light_rgb", "float4"),
    # its cached transmittance (kernels/light_volume.cl, exabricks.engine.light_volume):
    # node (0, 0, 0) and, in w, 1 / the node spacing along the light; the axes across
    # the light, each with 1 / its node spacing; the nodes per axis and, in w, whether
    # the frame reads the cache
    ("light_origin", "float4"), ("light_u", "float4"), ("light_v", "float4"),
    ("light_dims", "int4"),
    # the path integrator's majorant grid (exabricks.engine.majorants): its lattice
    # corner and, in w, 1 / macrocell width; its macrocells per axis
    ("majorant_lower", "float4"), ("majorant_dims", "int4"),
    # distance between fields in the brick, vertex and mip values
    ("field_stride", "long"), ("vertex_stride", "long"), ("mip_stride", "long"),
    # the image and its samples
    ("width", "int"), ("height", "int"), ("spp", "int"), ("seed", "uint"), ("jitter", "int"),
    # integration
    ("step_base", "float"), ("inv_unit_distance", "float"), ("max_opacity", "float"),
    ("lod_scale", "float"),
    # lighting
    ("shading", "int"), ("ao_samples", "int"), ("ao_distance", "float"),
    # what the frame holds
    ("n_layers", "int"), ("n_iso", "int"), ("n_slices", "int"), ("iso_tolerance", "float"),
    ("clip_box", "int"), ("n_clip_planes", "int"), ("use_front", "int"),
    ("domain", "int"),  # a domain's frame: its samples only (kernels/frame.cl, eb_in_domain)
    # features chosen per frame (exabricks.engine.variants, Feature.param): the
    # reconstruction (EB_RECONSTRUCTION_*)
    ("reconstruction", "int"),
    # the dataset: counts, and offsets into its grouped buffers
    ("n_nodes", "int"), ("n_regions", "int"), ("n_bricks", "int"), ("n_tree_nodes", "int"),
    ("node_lower_at", "int"), ("node_upper_at", "int"),        # geometry (float)
    ("region_lower_at", "int"), ("region_upper_at", "int"),
    ("node_link_at", "int"), ("node_region_at", "int"),        # links (int)
    ("node_parent_at", "int"),                                 # (exabricks.engine.walk_links)
    ("node_visible_at", "int"), ("region_visible_at", "int"),  # flags (uchar)
    ("region_level_at", "int"),
    ("tree_lower_at", "int"), ("tree_upper_at", "int"),        # tree (4-byte words)
    ("tree_link_at", "int"), ("tree_brick_at", "int"),
    # the frame's look: offsets into its float and int buffers
    ("tf_xs_at", "int"), ("tf_rgba_at", "int"), ("gradient_scale_at", "int"),
    ("iso_value_at", "int"), ("iso_color_at", "int"), ("slice_point_at", "int"),
    ("slice_normal_at", "int"), ("clip_planes_at", "int"),
    ("layers_at", "int"), ("iso_at", "int"), ("slices_at", "int"), ("buckets_at", "int"),
    ("tables_at", "int"), ("mesh_colors_at", "int"), ("mesh_info_at", "int"), ("n_meshes", "int"),
    # the meshes' buffer (exabricks.mesh.MeshSet): float4 offsets
    ("mesh_tris_at", "int"), ("mesh_nodes_at", "int"), ("mesh_normals_at", "int"),
    # overlapping instances (kernels/mixture.cl): copy_rows float4 rows per copy in the look
    ("copies_at", "int"), ("n_copies", "int"), ("copy_rows", "int"),
    # the path integrator's majorants: float offset in the look
    ("majorant_at", "int"),
) + tuple((o.name, "float" if o.kind == "float" else "int") for o in SCENE_OPTIONS if o.kernel)

_C_TYPES = {"float4": (np.float32, (4,)), "int4": (np.int32, (4,)), "long": np.int64, "int": np.int32,
            "uint": np.uint32, "float": np.float32}


def float4_box(box) -> tuple:
    """A box (lower, upper) as two float4 members of eb_params take it (a domain's
    domain_lower and domain_upper): two tuples, hashable."""
    return tuple((*np.asarray(b, np.float64), 0.0) for b in box)


def _dtype() -> np.dtype:
    """PARAMS as a numpy dtype laid out as C lays out eb_params: each member at the
    next multiple of its size, the whole a multiple of 16 bytes."""
    names, formats, offsets, at = [], [], [], 0
    for name, ctype in PARAMS:
        dtype = np.dtype(_C_TYPES[ctype])
        at = -(-at // dtype.itemsize) * dtype.itemsize
        names.append(name)
        formats.append(dtype)
        offsets.append(at)
        at += dtype.itemsize
    return np.dtype({"names": names, "formats": formats, "offsets": offsets,
                     "itemsize": -(-at // 16) * 16})


PARAMS_DTYPE = _dtype()


def params(**values) -> np.ndarray:
    """One eb_params (zero where not given), members by name."""
    out = np.zeros(1, PARAMS_DTYPE)
    for name, value in values.items():
        out[name] = value
    return out


# NVIDIA's register cap (the driver's -cl-nv-maxrregcount) for the render programs
# that fit it without a spill under the offline gauge (benchmarks/gpu_gauge.py):
# those of volume layers drawn one sample at a time by the headlight or path
# integrator, with analytic normals. Left alone (about 112 registers for the GPU default) ptxas holds more
# loads in flight and runs fewer warps; capped, 21 warps fit a multiprocessor where
# 18 did. The other programs would spill under it (central differences: 400 B).
# benchmarks/gpu_checks.sh
# compares the two on a lent GPU (ab_kernels --options=-cl-nv-maxrregcount=112).
NV_REGISTER_CAP = 96


def nv_build_options(capped: bool) -> tuple[str, ...]:
    """The build options an NVIDIA device gets beyond the others' for a program that
    the register cap fits (`capped`: exabricks.engine.variants.Variant.capped) or not."""
    return (f"-cl-nv-maxrregcount={NV_REGISTER_CAP}",) if capped else ()


def params_by_value(surfaces: bool) -> bool:
    """Whether the render program (eb_render, eb_probe) of a variant with or without
    `surfaces` takes its eb_params by value, else in a __constant buffer
    (kernels/common.h, EB_PARAMS_ARG: by value except where out-of-line functions
    would copy it to the stack)."""
    return not surfaces


def option_params(scene) -> dict:
    """The eb_params members of the render options the kernels read (`kernel=True`),
    from `scene` (exabricks.scene.Scene)."""
    out = {}
    for option in SCENE_OPTIONS:
        if option.kernel:
            value = option.value_in(scene)
            out[option.name] = option.choices.index(value) if option.kind == "choice" else value
    return out


def header() -> str:
    """The C text that every program starts with: EB_ABI, LIMITS, TUNABLES (unless
    defined by a build option), the values of the kernel-read choices
    (EB_ISO_GRADIENT_CENTRAL), the reconstructions' (EB_RECONSTRUCTION_NEAREST) and the
    eb_params struct."""
    lines = ["/* exabricks.device.kernel_abi.header() */", "#define EB_ABI 1"]
    lines += [f"#define {name} {value}" for name, value in LIMITS.items()]
    for name, value in TUNABLES.items():
        lines += [f"#ifndef {name}", f"#define {name} {value}", "#endif"]
    for option in SCENE_OPTIONS:  # a kernel-read choice's values: EB_NAME_CHOICE
        if option.kernel and option.kind == "choice":
            lines += [f"#define EB_{option.name.upper()}_{choice.upper().replace('-', '_')} {i}"
                      for i, choice in enumerate(option.choices)]
    lines += [f"#define EB_RECONSTRUCTION_{name.upper()} {i}" for i, name in enumerate(RECONSTRUCTIONS)]
    lines.append("typedef struct {")
    lines += [f"    {ctype} {name};" for name, ctype in PARAMS]
    lines.append("} eb_params;")
    return "\n".join(lines) + "\n"
