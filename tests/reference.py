"""Independent float64 NumPy references for `probe` and `render` (DESIGN.md eq. 1-2, §4).

Nothing here touches bricks, regions, the BVH or the OpenCL kernels: values
come straight from the leaf cells of a `schema.Cells`.

Reconstruction (paper eq. 1-2): a cell C of width w = 2**level and centre c has
the hat ``H_C(p) = prod_a max(0, 1 - |c_a - p_a| / w)`` and the field is
``sum H_C v_C / sum H_C`` (NaN where the sum is 0). Along an axis, the hat of a
level-l cell is non-zero at p only if its centre lies within w of p, i.e. only
for the cell indices ``floor(p / w - 1/2)`` and that plus one. So every level
is hashed into a uniform grid whose buckets are that level's cells (a dense
table over the level's bounding box, or sorted keys when that box is huge), and
each point visits exactly 8 candidate cells per level -- the candidate set is
provably complete and at most 8 * levels long, whatever the mix of levels. (A
single grid of coarsest-width buckets would hand a point in a fine area up to
(w_max + 1)**3 candidates: ~5000 on the Gerris plume.)

Integration: per pixel-centre ray (`Camera.rays`, float64), the interval
through the support box of the data, uniform steps of at most
``finest width / steps_per_finest_cell`` (midpoint rule), exact opacity
correction ``1 - (1 - alpha)**(dt / unit_distance)``, front-to-back
compositing, no shading, no jitter; NaN samples are transparent.
"""

from __future__ import annotations

import weakref

import numpy as np

from exabricks import schema

# Dense per-level lookup tables up to this many entries (int64: 128 MiB); beyond
# it the level uses sorted keys and binary search.
DENSE_TABLE_LIMIT = 1 << 24

# Points per vectorised batch (bounds the temporaries to a few tens of MiB).
BATCH = 1 << 16

# The 8 candidate offsets {0, 1}^3 per level, x fastest.
_CORNERS = np.array([[dx, dy, dz] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], np.int64)


class _Level:
    """One level's cells hashed by integer cell index q = lower // w.

    The table covers the level's cell indices grown by one on every side: a
    point inside the level's support box has all 8 candidates in that range.
    """

    def __init__(self, level: int, lower: np.ndarray, ids: np.ndarray):
        self.level = level
        self.width = float(2**level)
        q = lower // (1 << level)
        self.qmin = q.min(axis=0) - 1
        self.extent = q.max(axis=0) + 2 - self.qmin
        # Support box of the level's cells: [qmin w - w/2, (qmax + 1) w + w/2], lattice units.
        self.support_lower = (self.qmin + 1 - 0.5) * self.width
        self.support_upper = (self.qmin + self.extent - 1 + 0.5) * self.width
        key = self.key(q)
        # Key offsets of the candidates q0 + _CORNERS (x fastest, as in `key`).
        self.corner_offsets = self.key(_CORNERS + self.qmin)
        size = int(np.prod(self.extent))
        if size <= DENSE_TABLE_LIMIT:
            self.table = np.full(size, -1, np.int64)
            self.table[key] = ids
        else:
            order = np.argsort(key)
            self.keys, self.ids = key[order], ids[order]
            self.table = None

    def key(self, q: np.ndarray) -> np.ndarray:
        """Linear bucket index of cell indices q (..., 3) int64 (inside the grown range)."""
        r = q - self.qmin
        return (r[..., 2] * self.extent[1] + r[..., 1]) * self.extent[0] + r[..., 0]

    def lookup_keys(self, key: np.ndarray) -> np.ndarray:
        """Cell ids (int64) of the cells with linear bucket indices `key`; -1 where none."""
        if self.table is not None:
            return self.table[key]
        pos = np.minimum(np.searchsorted(self.keys, key), self.keys.size - 1)
        return np.where(self.keys[pos] == key, self.ids[pos], -1)


class CellIndex:
    """The leaf cells of one dataset hashed level by level (module docstring)."""

    def __init__(self, cells: schema.Cells):
        self.cells = cells
        lower = cells.lower_lattice.astype(np.int64)
        level = cells.level.astype(np.int64)
        self.levels = [_Level(int(l), lower[level == l], np.flatnonzero(level == l))
                       for l in np.unique(level)]
        width = np.ldexp(1.0, level.astype(np.int32))[:, None]
        # Support box: every cell's box grown by w/2 on every side (DESIGN.md).
        self.support_lower = (lower - 0.5 * width).min(axis=0) if cells.n_cells else np.zeros(3)
        self.support_upper = (lower + 1.5 * width).max(axis=0) if cells.n_cells else np.zeros(3)
        self.finest_width = float(2.0 ** level.min()) if cells.n_cells else 1.0

    def level_sums(self, points_lattice, values) -> tuple[np.ndarray, np.ndarray]:
        """sum H and sum H v of every level at every point.

        points_lattice: float64 (N, 3), lattice units; values: float64 (n_cells,).
        Returns two float64 arrays (n_levels, N), levels in increasing order.
        """
        p_all = np.asarray(points_lattice, np.float64).reshape(-1, 3)
        weight = np.zeros((len(self.levels), p_all.shape[0]))
        weighted = np.zeros_like(weight)
        for start in range(0, p_all.shape[0], BATCH):
            chunk = p_all[start:start + BATCH]
            for k, lev in enumerate(self.levels):
                # Outside the level's (open) support box every hat of the level is 0.
                rows = np.flatnonzero(np.all((chunk > lev.support_lower)
                                             & (chunk < lev.support_upper), axis=1))
                p = chunk[rows]
                w = lev.width
                q0 = np.floor(p / w - 0.5).astype(np.int64)                   # (n, 3)
                # eq. 1 with each candidate's own centre c = (q + 1/2) w, q = q0 or q0 + 1;
                # the hat is a product over axes, so the 8 weights are an outer product.
                c0 = (q0 + 0.5) * w
                h0 = np.maximum(0.0, 1.0 - np.abs(c0 - p) / w)
                h1 = np.maximum(0.0, 1.0 - np.abs(c0 + w - p) / w)
                hx, hy, hz = (np.stack([h0[:, a], h1[:, a]], axis=1) for a in range(3))
                h = hz[:, :, None, None] * hy[:, None, :, None] * hx[:, None, None, :]
                h = h.reshape(-1, 8)                                          # (n, 8)
                ids = lev.lookup_keys(lev.key(q0)[:, None] + lev.corner_offsets)  # (n, 8)
                present = ids >= 0
                h = np.where(present, h, 0.0)
                weight[k, start + rows] = h.sum(axis=1)
                weighted[k, start + rows] = (h * values[np.where(present, ids, 0)]).sum(axis=1)
        return weight, weighted

    def reconstruct(self, points_lattice, values) -> np.ndarray:
        """eq. 2 at points (N, 3) lattice units from per-cell values (n_cells,) -> float64 (N,)."""
        weight, weighted = self.level_sums(points_lattice, values)
        w, wv = weight.sum(axis=0), weighted.sum(axis=0)
        out = np.full(w.shape, np.nan)
        np.divide(wv, w, out=out, where=w > 0)
        return out


_INDEXES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def cell_index(cells: schema.Cells) -> CellIndex:
    """The (memoised) `CellIndex` of `cells`."""
    if cells not in _INDEXES:
        _INDEXES[cells] = CellIndex(cells)
    return _INDEXES[cells]


def field_values(cells: schema.Cells, field: str | None) -> np.ndarray:
    """Per-cell values of `field` (None: the first) as float64 (n_cells,)."""
    return cells.values[cells.field_index(field)].astype(np.float64)


def reconstruct(cells: schema.Cells, points_lattice, field: str | None = None) -> np.ndarray:
    """Basis reconstruction (eq. 1-2) of `field` at points (N, 3) float64 lattice units.

    Returns float64 (N,); NaN where no cell's hat is positive.
    """
    return cell_index(cells).reconstruct(points_lattice, field_values(cells, field))


def contributing_levels(cells: schema.Cells, points_lattice) -> np.ndarray:
    """How many distinct levels have a positive hat at each point: int (N,)."""
    weight, _ = cell_index(cells).level_sums(points_lattice, np.zeros(cells.n_cells))
    return (weight > 0).sum(axis=0)


def to_lattice(cells: schema.Cells, points_world) -> np.ndarray:
    """World points (N, 3) -> float64 lattice points: (p - origin) / spacing."""
    return (np.asarray(points_world, np.float64) - cells.origin_world) / cells.spacing_world


def to_world(cells: schema.Cells, points_lattice) -> np.ndarray:
    """Lattice points (N, 3) -> float64 world points: origin + spacing * p."""
    return cells.origin_world + cells.spacing_world * np.asarray(points_lattice, np.float64)


def support_box_world(cells: schema.Cells) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) float64 (3,) world corners of the bounding box of all cell supports."""
    index = cell_index(cells)
    return to_world(cells, index.support_lower), to_world(cells, index.support_upper)


def integrate(cells: schema.Cells, camera, transfer_function, width: int, height: int,
              field: str | None = None, *, steps_per_finest_cell: int = 16,
              unit_distance: float | None = None, max_opacity: float = 1.0,
              light=None, shadow_steps_per_finest_cell: int = 4) -> np.ndarray:
    """Reference image: premultiplied RGBA float64 (height, width, 4), row 0 at the top.

    Emission-absorption without shading or jitter (module docstring). Each ray's
    interval through the support box is split into n equal steps of length
    dt <= finest width (world) / steps_per_finest_cell, each sampled at its
    midpoint. `unit_distance` (world units) defaults to the finest cell width,
    ``2**min(level) * min(spacing)``; a ray stops after the sample that brings
    its opacity to `max_opacity` (1.0: never).

    `light` (direction toward it (3,), ambient, rgb (3,): colour x intensity), the
    shadow integrator (docs/design-rendering.md, "Lights and shadows"): each sample's
    colour times ambient + T rgb, T the transmittance from the sample toward the
    light to the support box's edge, in equal steps of at most finest width /
    `shadow_steps_per_finest_cell`, each sampled at its midpoint (`transmittance`).
    """
    index = cell_index(cells)
    values = field_values(cells, field)
    finest_world = index.finest_width * float(np.min(cells.spacing_world))
    unit = finest_world if unit_distance is None else float(unit_distance)
    dt_max = finest_world / steps_per_finest_cell
    lo, hi = support_box_world(cells)

    origins, directions = camera.rays(width, height)
    o = origins.reshape(-1, 3)
    d = directions.reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t_a, t_b = (lo - o) * inv, (hi - o) * inv
    # A direction component of 0 gives +-inf (or NaN when o sits on the plane):
    # NaN-ignoring min/max keep the other axes' slabs.
    t_near = np.nanmax(np.minimum(t_a, t_b), axis=1).clip(min=0.0)
    t_far = np.nanmin(np.maximum(t_a, t_b), axis=1)
    length = np.where(t_far > t_near, t_far - t_near, 0.0)
    n_steps = np.ceil(length / dt_max).astype(np.int64)
    step = np.where(n_steps > 0, length / np.maximum(n_steps, 1), 0.0)

    image = np.zeros((o.shape[0], 4))
    rays = np.flatnonzero(n_steps > 0)
    chunk_rays = []
    budget = 0
    for r in rays:  # group rays into chunks of about BATCH * 4 samples
        chunk_rays.append(r)
        budget += n_steps[r]
        if budget >= 4 * BATCH:
            _integrate_chunk(np.array(chunk_rays), image, o, d, t_near, step, n_steps, index,
                             values, transfer_function, unit, max_opacity, cells, light,
                             finest_world / shadow_steps_per_finest_cell)
            chunk_rays, budget = [], 0
    if chunk_rays:
        _integrate_chunk(np.array(chunk_rays), image, o, d, t_near, step, n_steps, index,
                         values, transfer_function, unit, max_opacity, cells, light,
                         finest_world / shadow_steps_per_finest_cell)
    return image.reshape(height, width, 4)


def _integrate_chunk(rays, image, o, d, t_near, step, n_steps, index, values, tf, unit,
                     max_opacity, cells, light=None, shadow_dt=None):
    """Composite the rays `rays` into `image` (rows of (n_rays, 4)); see `integrate`."""
    m = int(n_steps[rays].max())
    k = np.arange(m)
    valid = k[None, :] < n_steps[rays][:, None]                      # (R, m)
    t = t_near[rays][:, None] + (k[None, :] + 0.5) * step[rays][:, None]
    points_world = o[rays][:, None, :] + t[..., None] * d[rays][:, None, :]
    value = np.full(valid.shape, np.nan)
    value[valid] = index.reconstruct(to_lattice(cells, points_world[valid]), values)
    rgba = tf.evaluate(value)                                         # NaN -> NaN
    alpha = np.where(valid & np.isfinite(value), rgba[..., 3], 0.0)
    a = 1.0 - np.power(1.0 - alpha, step[rays][:, None] / unit)
    transmit = np.cumprod(1.0 - a, axis=1)
    before = np.concatenate([np.ones((len(rays), 1)), transmit[:, :-1]], axis=1)
    # Early termination: a sample counts only while the opacity before it is below max.
    used = (1.0 - before) < max_opacity
    contribution = np.where(used, before * a, 0.0)
    rgb = np.where(np.isfinite(rgba[..., :3]), rgba[..., :3], 0.0)
    if light is not None:
        direction, ambient, light_rgb = light
        lit = (contribution > 0.0) & valid
        t_light = np.zeros(valid.shape)
        t_light[lit] = transmittance(cells, index, values, tf, unit, points_world[lit], direction,
                                     shadow_dt)
        rgb = rgb * (ambient + t_light[..., None] * np.asarray(light_rgb, np.float64))
    image[rays, :3] = np.einsum("rk,rkc->rc", contribution, rgb)
    image[rays, 3] = 1.0 - np.prod(np.where(used, 1.0 - a, 1.0), axis=1)


# ---------------------------------------------------------------------------------------
# Surfaces, clipping and several fields (DESIGN.md "Surfaces, clipping and several fields")


def transmittance(cells, index, values, tf, unit, points_world, direction, dt_max) -> np.ndarray:
    """The transmittance (N,) from each world point toward `direction` to the edge of
    the support box: equal steps of at most `dt_max`, each sampled at its midpoint,
    opacity corrected to its length as `integrate` does."""
    lo, hi = support_box_world(cells)
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    _, t_far = ray_box_interval(points_world, np.broadcast_to(d, points_world.shape), lo, hi)
    length = np.clip(t_far, 0.0, None)
    n = np.ceil(length / dt_max).astype(np.int64)
    step = np.where(n > 0, length / np.maximum(n, 1), 0.0)
    optical = np.zeros(len(points_world))  # -sum log(1 - a)
    for k in range(int(n.max(initial=0))):
        active = np.flatnonzero(k < n)
        p = points_world[active] + ((k + 0.5) * step[active])[:, None] * d
        value = index.reconstruct(to_lattice(cells, p), values)
        alpha = np.where(np.isfinite(value), tf.evaluate(value)[..., 3], 0.0)
        with np.errstate(divide="ignore"):
            optical[active] -= np.log1p(-np.minimum(alpha, 1.0)) * step[active] / unit
    return np.exp(-optical)


def ray_box_interval(origins, directions, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """(t_near, t_far) float64 (N,) of rays (N, 3) against the box [lower, upper]
    (world units, t >= 0); empty where t_far <= t_near."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t_a, t_b = (np.asarray(lower, np.float64) - o) * inv, (np.asarray(upper, np.float64) - o) * inv
    t_near = np.nanmax(np.minimum(t_a, t_b), axis=1).clip(min=0.0)
    t_far = np.nanmin(np.maximum(t_a, t_b), axis=1)
    return t_near, t_far


def clip_interval(origins, directions, box=None, planes=()) -> tuple[np.ndarray, np.ndarray]:
    """The kept interval (t0, t1) float64 (N,) of each ray (t >= 0): inside `box`
    ((lower xyz), (upper xyz)) and, for every plane (P, N), where (p - P) . N >= 0.
    Empty where t1 <= t0."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    t0, t1 = np.zeros(len(o)), np.full(len(o), np.inf)
    if box is not None:
        a, b = ray_box_interval(o, d, box[0], box[1])
        t0, t1 = np.maximum(t0, a), np.minimum(t1, b)
    for point, normal in planes:
        n = np.asarray(normal, np.float64)
        along = d @ n
        need = (np.asarray(point, np.float64) - o) @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = need / along
        t0 = np.where(along > 0, np.maximum(t0, t), t0)
        t1 = np.where(along < 0, np.minimum(t1, t), t1)
        t1 = np.where((along == 0) & (need > 0), -np.inf, t1)
    return t0, t1


def medium(rgba_layers: np.ndarray, dt, unit: float) -> tuple[np.ndarray, np.ndarray]:
    """Opacity (...) and colour (..., 3) of a step of length dt through the mixture of
    media whose per-layer RGBA (L, ..., 4) are given (alpha per `unit` distance):
    sigma_i = -ln(1 - alpha_i) / unit, opacity 1 - exp(-sum sigma_i dt), colour
    sum sigma_i rgb_i / sum sigma_i. NaN RGBA (no data) is transparent. Layers of
    alpha 1 have infinite extinction: the step is opaque with their mean colour."""
    rgba = np.where(np.isfinite(rgba_layers), rgba_layers, 0.0)
    alpha = rgba[..., 3]
    opaque = alpha >= 1.0
    sigma = -np.log1p(-np.where(opaque, 0.0, alpha)) / unit
    s_sum = sigma.sum(axis=0)
    a = 1.0 - np.exp(-s_sum * dt)
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.einsum("l...,l...c->...c", sigma, rgba[..., :3]) / s_sum[..., None]
    rgb = np.where(s_sum[..., None] > 0, rgb, 0.0)
    n_opaque = opaque.sum(axis=0)
    any_opaque = n_opaque > 0
    rgb_opaque = np.einsum("l...,l...c->...c", opaque.astype(float), rgba[..., :3]) \
        / np.maximum(n_opaque, 1)[..., None]
    return np.where(any_opaque, 1.0, a), np.where(any_opaque[..., None], rgb_opaque, rgb)


def integrate_scene(cells: schema.Cells, camera, layers, width: int, height: int, *,
                    clip_box=None, clip_planes=(), steps_per_finest_cell: int = 16,
                    unit_distance: float | None = None) -> np.ndarray:
    """Reference image of several volume layers, clipped: premultiplied RGBA float64
    (height, width, 4), row 0 at the top, no shading, no early termination.

    `layers`: [(field, transfer function), ...], mixed per step as media (`medium`).
    Each pixel-centre ray keeps its interval through the support box intersected
    with the clip interval (`clip_interval`; world units), split into n equal steps
    of length <= finest width (world) / steps_per_finest_cell, each sampled at its
    midpoint. With one layer and no clipping this is `integrate`."""
    index = cell_index(cells)
    values = [field_values(cells, f) for f, _ in layers]
    finest_world = index.finest_width * float(np.min(cells.spacing_world))
    unit = finest_world if unit_distance is None else float(unit_distance)
    dt_max = finest_world / steps_per_finest_cell
    lo, hi = support_box_world(cells)
    origins, directions = camera.rays(width, height)
    o, d = origins.reshape(-1, 3), directions.reshape(-1, 3)
    t_near, t_far = ray_box_interval(o, d, lo, hi)
    c0, c1 = clip_interval(o, d, clip_box, clip_planes)
    t_near, t_far = np.maximum(t_near, c0), np.minimum(t_far, c1)
    length = np.where(t_far > t_near, t_far - t_near, 0.0)
    n_steps = np.ceil(length / dt_max).astype(np.int64)
    step = np.where(n_steps > 0, length / np.maximum(n_steps, 1), 0.0)
    image = np.zeros((o.shape[0], 4))
    rays = np.flatnonzero(n_steps > 0)
    chunks, chunk, budget = [], [], 0
    for r in rays:
        chunk.append(r)
        budget += n_steps[r]
        if budget >= 4 * BATCH:
            chunks.append(chunk)
            chunk, budget = [], 0
    if chunk:
        chunks.append(chunk)
    for chunk in chunks:
        rows = np.array(chunk)
        m = int(n_steps[rows].max())
        k = np.arange(m)
        valid = k[None, :] < n_steps[rows][:, None]
        t = t_near[rows][:, None] + (k[None, :] + 0.5) * step[rows][:, None]
        points = to_lattice(cells, o[rows][:, None, :] + t[..., None] * d[rows][:, None, :])[valid]
        rgba = np.full((len(layers),) + valid.shape + (4,), np.nan)
        for i, (_, tf) in enumerate(layers):
            value = np.full(valid.shape, np.nan)
            value[valid] = index.reconstruct(points, values[i])   # NaN: no data
            rgba[i] = tf.evaluate(value)
        a, rgb = medium(rgba, step[rows][:, None], unit)
        transmit = np.cumprod(1.0 - a, axis=1)
        before = np.concatenate([np.ones((len(rows), 1)), transmit[:, :-1]], axis=1)
        image[rows, :3] = np.einsum("rk,rkc->rc", before * a, rgb)
        image[rows, 3] = 1.0 - transmit[:, -1]
    return image.reshape(height, width, 4)
