"""The yt side of benchmarks/bench_peers.py: yt set up to render our frame, and its worker.

worker_yt, yt 4.4.3: `import yt`, `yt.load` (or yt.load_amr_grids, below) + `ds.index`,
scene set-up (Scene, VolumeSource, transfer function, perspective camera,
and the AMRKDTree with its vertex-centred bricks, which yt otherwise builds
in the first render), then `sc.render()`: median of --runs after a warm-up.
yt's default sampling: `num_samples = 10` samples per cell crossing. Skipped
on datasets with more than --yt-max-cells leaf cells (default 10 M: yt never
finished loading the 23.6 M-cell "big" dataset); the table says so.

How yt is matched (yt/visualization/volume_rendering/lens.py, camera.py,
utilities/orientation.py, utilities/lib/image_samplers.pyx,
field_interpolation_tables.pxd):

* Camera: `cam.focus = look_at`, then `cam.set_position(position,
  north_vector=up)` (setting the focus resets north). yt's unit vectors are
  east = north x normal (= -our right), north (= our up'), normal = focus -
  position. PerspectiveLens (lens.py, _get_sampler_params) starts every ray at
  the camera position, ray [i, j] along ``normal w2 + w0 (i/(N-1) - 1/2) east +
  w1 (j/(M-1) - 1/2) north`` (w = cam.width; w1 is forced to w0 M/N): yt's
  first and last rays go through the image *edges*. Ours go through pixel
  centres, u = 2 (col + 1/2)/W - 1, so ``w0 / w2 = 2 tan(fovy/2) aspect (W - 1)/W``
  makes every yt ray one of ours exactly: ray [i, j] is our pixel (row H-1-j,
  col W-1-i) (square images; for W != H yt's forced w1 gives the vertical span
  (W-1)/W instead of (H-1)/H, so non-square sizes are refused). We use w2 = 2 L
  (L below) so that yt's brick-ordering viewpoint (lens.front_center = focus +
  w2/2 normal) lies beyond the data. The image `sc.render()` returns is that
  ray grid rotated by 180 degrees, i.e. ours transposed: ours[row, col] =
  yt_image[col, row]. tests/bench/test_bench_peers.py checks the rays exactly and the
  orientation with an off-centre cube.
* Transfer function: a ColorTransferFunction with grey_opacity=True, bounds
  [lo - d, hi + d] (d = 1e-3 (hi - lo); yt makes values on or outside its
  bounds transparent, ours clamp), log_field = False (our function is linear
  in the data value), nbins = 4096, and its tables filled at yt's nodes
  (`tf.funcs[c].x`, the values where yt's piecewise-linear table is exact)
  from our `TransferFunction.evaluate`: red/green/blue = our colour, alpha =
  sigma(x) = -ln(1 - alpha(x)) * L / unit_distance. yt composites
  ``rgba = dt sigma rgb + (1 - dt sigma) rgba`` with dt in units of its ray
  parameter t (one t spans |ray vector| = L = |position - domain centre| +
  |domain width|/2 on the central ray), i.e. linearised emission-absorption
  with extinction sigma per unit t; ours is 1 - (1 - alpha)^(dt/unit) per step.
  Alpha is clipped to 1 - 1e-6 before the log. Off-axis rays are longer in
  yt's t (by 1/cos of the angle to the axis, <= 7 % at fovy 30), so their
  extinction per world length is that much lower; yt has no early termination.
* Differences that remain: yt walks each ray from the camera but composites
  every new sample *in front of* the accumulated colour (its brick order is
  furthest-first from front_center, which lies behind the data), so
  occlusion is reversed with respect to ours;
  yt's reconstruction is trilinear within each brick from vertex values it
  averages from cell values (no ghost zones), not the basis method.

ExaJet data (gerris, big, shell256) has no yt front end (and yt.load_octree says of
itself that "fluid fields will not work yet, or possibly ever"): our reader's
leaf cells are turned into properly nested grids
(`exabricks.readers.yt_grids.to_amr_grids`) and given to
yt.load_amr_grids. yt then has exactly our leaves and values (checked on the
Gerris plume); the conversion is timed on its own and not counted as yt's
load, but it is part of the yt process's peak memory. Where the data has a
hole (make_big.py's thin shells drop every cell whose centre lies in a sphere,
so refined cells there lack children), yt, which has no empty cells, gets the
missing cells as leaves of a value below its transfer function's bounds:
transparent, as the hole is in ours (its vertex values next to the hole mix
that value in, so yt's image differs there).
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.peers.common import timed_runs

YT_NUM_SAMPLES = 10          # yt's VolumeSource default
YT_NBINS = 4096
YT_PAD = 1e-3                # yt's bounds: the value range widened by this fraction each side
ALPHA_CLIP = 1.0 - 1e-6      # -ln(1 - alpha) is infinite at alpha = 1
# yt is skipped above this many leaf cells: it never finished loading the 23.6 M-cell
# "big" dataset (hours, then killed), and every other dataset has under 1 M.
YT_MAX_CELLS = 10_000_000


def yt_camera_width(camera, width: int, height: int, depth: float) -> list[float]:
    """yt `cam.width` whose perspective rays are exactly our pixel-centre rays (module docstring)."""
    if width != height:
        raise ValueError("yt's perspective lens forces width[1] = width[0] * H / W: use square images")
    half = math.tan(math.radians(camera.fovy) / 2.0)
    w0 = 2.0 * depth * half * (width / height) * (width - 1) / width
    return [w0, w0 * height / width, depth]


def yt_transfer_function(tf, x_bounds, *, ray_length: float, unit_distance: float,
                         nbins: int = YT_NBINS):
    """A yt ColorTransferFunction equal to `tf` at its nodes (module docstring).

    ray_length: world length of one unit of yt's ray parameter t; unit_distance:
    our opacity unit (world). Returns the ColorTransferFunction (grey opacity).
    """
    from yt.visualization.volume_rendering.transfer_functions import ColorTransferFunction

    ytf = ColorTransferFunction(x_bounds, nbins=nbins, grey_opacity=True)
    rgba = tf.evaluate(ytf.funcs[0].x)
    for c in range(3):
        ytf.funcs[c].y[:] = rgba[:, c]
    ytf.funcs[3].y[:] = yt_extinction(rgba[:, 3], ray_length, unit_distance)
    return ytf


def yt_extinction(alpha, ray_length: float, unit_distance: float) -> np.ndarray:
    """yt's alpha table: extinction per unit ray parameter from our slab opacity."""
    alpha = np.minimum(np.asarray(alpha, np.float64), ALPHA_CLIP)
    return -np.log1p(-alpha) * (ray_length / unit_distance)


def yt_image_to_ours(image) -> np.ndarray:
    """The (N, N, 4) image `sc.render()` returns as our float32 (row, col, rgba) layout:
    yt's ray grid rotated by 180 degrees, i.e. ours transposed (module docstring)."""
    return np.ascontiguousarray(np.asarray(image).transpose(1, 0, 2)).astype(np.float32)


def yt_bounds(value_range) -> tuple[float, float]:
    """yt's transfer-function bounds: `value_range` widened by YT_PAD of its width each side
    (of max(1, |value|) for a constant field), since yt drops values on or outside them."""
    lo, hi = value_range
    pad = YT_PAD * (hi - lo) if hi > lo else YT_PAD * max(1.0, abs(lo))
    return lo - pad, hi + pad


def yt_skip_reason(cells: int, cap: int) -> str | None:
    """Why yt is not run on a dataset of `cells` leaf cells (None: it is run)."""
    if cells > cap:
        return f"skipped: {cells:,} cells > --yt-max-cells {cap:,}"
    return None


def worker_yt(spec: dict) -> dict:
    from exabricks.picture.camera import Camera
    from exabricks.picture.transfer_function import TransferFunction

    camera = Camera.from_dict(spec["camera"])
    tf = TransferFunction.from_paraview_dict(spec["transfer_function"])
    size, runs = spec["size"], spec["runs"]
    t = time.perf_counter()
    import yt
    from yt.visualization.volume_rendering.api import Scene, create_volume_source
    t_import = time.perf_counter() - t
    yt.set_log_level(40)

    t_convert = None
    if spec["yt_mode"] == "grids":
        from exabricks import readers, schema
        from exabricks.readers import yt_grids

        t = time.perf_counter()
        cells = readers.read(spec["path"], fields=[spec["field"]])
        # Cells missing from the data (the thin shells' hole) become leaves of a value
        # below yt's bounds, which its transfer function makes transparent.
        low, high = yt_bounds(spec["value_range"])
        grids, top = yt_grids.to_amr_grids(cells, source=spec["path"],
                                            fill=low - (high - low))
        lo, hi = (np.asarray(b) for b in schema.world_bounds(cells))
        root = np.rint((hi - lo) / cells.spacing_world / (1 << top)).astype(int)
        del cells
        t_convert = time.perf_counter() - t
        t = time.perf_counter()
        ds = yt.load_amr_grids(grids, root, bbox=np.column_stack([lo, hi]), length_unit=1.0)
        del grids
    else:
        t = time.perf_counter()
        ds = yt.load(spec["path"])
    ds.index  # noqa: B018  (builds the grid hierarchy)
    t_load = time.perf_counter() - t
    fields = [f for f in ds.field_list if f[1] == spec["field"]]
    if not fields:
        raise SystemExit(f"yt: no field {spec['field']!r} in {spec['path']}")

    t = time.perf_counter()
    sc = Scene()
    source = create_volume_source(ds.all_data(), fields[0])
    source.log_field = False
    centre = ds.domain_center.to("code_length").d
    domain_width = ds.domain_width.to("code_length").d
    position = np.asarray(camera.position)
    ray_length = float(np.linalg.norm(position - centre) + 0.5 * np.linalg.norm(domain_width))
    source.transfer_function = yt_transfer_function(
        tf, yt_bounds(spec["value_range"]), ray_length=ray_length,
        unit_distance=spec["unit_distance"])
    sc.add_source(source)
    cam = sc.add_camera(ds, lens_type="perspective")
    cam.resolution = (size, size)
    cam.focus = ds.arr(camera.look_at, "code_length")
    cam.set_position(ds.arr(camera.position, "code_length"), north_vector=np.asarray(camera.up))
    depth = 2.0 * ray_length
    cam.width = ds.arr(yt_camera_width(camera, size, size, depth), "code_length")
    # The AMRKDTree and its vertex-centred bricks, exactly as yt's validate_volume
    # decorator builds them in the first render (render_source.py).
    source.volume.set_fields([source.field], [source.log_field], no_ghost=not source.use_ghost_zones)
    source._volume_valid = True
    t_setup = time.perf_counter() - t
    source.num_samples = YT_NUM_SAMPLES

    def frame():
        return np.asarray(sc.render())

    first_s, times, image = timed_runs(frame, runs)
    rgba = yt_image_to_ours(image)
    np.save(spec["image_prefix"] + "-yt.npy", rgba)
    return {"import_s": t_import, "convert_s": t_convert, "load_index_s": t_load, "setup_s": t_setup,
            "first_frame_s": first_s, "frame_s": times, "grids": int(ds.index.num_grids),
            "ray_length": ray_length, "num_samples": YT_NUM_SAMPLES,
            "unit_vectors": np.asarray(cam.unit_vectors).tolist()}
