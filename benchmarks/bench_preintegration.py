"""Pre-integrated transfer functions (issue 36, item 1), measured before they are built:
at what sample count does each quadrature reach the image of the exact integral?

    .venv/bin/python -m benchmarks.bench_preintegration [--only amrex,athena,gerris]
        [--size 64] [--rates 1,2,4] [--reference-rate 32]
        [--picture PNG [--picture-of athena] [--picture-size 192]] [--write-docs]

For each dataset (the stage files of benchmarks/bench_render.py's work directory,
built on first use) and each transfer function below, the primary rays of a
--size² frame of bench_peers' camera are integrated in float64 along their
interval through the data's world bounds, in n = ceil(length / h) equal steps of
h = finest cell / rate, by these quadratures of the emission-absorption integral
(DESIGN.md: slab opacity alpha per opacity unit, extinction
sigma = -ln(1 - alpha) / unit, colour rgb; premultiplied front-to-back compositing,
no early termination, no jitter):

- *midpoint*: today's exact path (`--tf-lookup exact` and the tables, which equal it
  on these transfer functions): one value per step, at its midpoint,
  opacity ``1 - (1 - alpha)^(h / unit)``;
- *pre-integrated, 1D tables*: one value per step end (n + 1 per ray, shared by
  neighbouring steps), the value taken linear between them; the step's optical depth
  is ``h (S(b) - S(f)) / (b - f)`` and its colour ``(K(b) - K(f)) / (S(b) - S(f))``,
  with S and K the integrals of sigma and sigma rgb over the value (Engel et al. 2001,
  §4, the integral functions: exact in opacity, the colour without the attenuation
  inside one step). A kernel would read S and K from one 4-channel table per layer,
  as it reads RGBA now, and skip the log2 of the opacity correction;
- the same from a table of the size a kernel would read (KERNEL_INTERVALS), and
  that table with today's lookup at the mean of the ends for the steps whose ends
  lie within FLAT_INTERVALS table intervals (where the tables' differences lose
  their precision; the share of such steps is printed);
- *pre-integrated, 2D tables*: the same linear value per step, the step integrated
  with its own attenuation (what Engel's 2D table of (f, b) holds for one step
  length), here by 16 midpoint sub-steps.

The reference is the midpoint rule at --reference-rate samples per finest cell, and
how far it is from the integral is printed (against 1D pre-integration at its rate). The
values come from `probe` (the basis reconstruction, the kernels' own, float32) and
everything after them is float64. Transfer functions, each over the field's range
with the default preset's colours:

- *bench*: bench_peers' (the opacity ramp 0 -> 0.1: nothing to skip);
- *ramp*: the default preset as it is (the opacity ramp 0 -> 1);
- *peaks*: three opacity tents of height 0.5 and half-width 1 % of the range, at a
  quarter, a half and three quarters of it (a transfer function with features
  narrower than the data's change over one step: what pre-integration is for).

Errors are of premultiplied RGBA in [0, 1] against the reference, over every pixel
and channel: RMSE, the largest, and the share of pixels where some channel is off by
more than half an 8-bit step. --picture writes one frame of the peaks function, the
reference | the midpoint rule | the kernel-sized table with its fallback, at the lowest
rate. docs/benchmarks-render.md, "Pre-integrated transfer functions", has the figures;
--write-docs replaces that section.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.bench_render import ensure_scene
from benchmarks.peers.common import DATASETS as PEER_DATASETS, transfer_function

from exabricks import schema
from exabricks.picture.camera import default_camera
from exabricks.engine.device_data import DeviceDataset, finest_cell_width_world
from exabricks.picture.transfer_function import TransferFunction

SECTION = "Pre-integrated transfer functions"
DEFAULT = ("amrex", "athena", "gerris")
NODES = 1 << 16           # intervals of the float64 integral tables
SUB_STEPS = 16            # sub-steps of one step for the 2D tables' integral
RAY_CHUNK = 256
EDGE = 1e-4                # how far inside the bounds the first and last ends lie, in steps
GAUSS = np.polynomial.legendre.leggauss(8)
HALF_STEP_8BIT = 0.5 / 255
KERNEL_INTERVALS = 1024   # the 1D tables' size a kernel would read (16 KiB per layer)
FLAT_INTERVALS = 2         # ... below which a step's ends count as one value
PICTURE_MARGIN = 0.3       # the picture's camera frames the middle 40 % of the bounds
METHODS = ("midpoint", "pre-integrated 1D",
           f"pre-integrated 1D, {KERNEL_INTERVALS:,}-interval table",
           f"the same, ends within {FLAT_INTERVALS} intervals: midpoint", "pre-integrated 2D")


READING = """What it says (docs/design-rendering.md, "Transfer-function tables", has the decision):

- **On the benchmarks' transfer function the midpoint rule wins.** With the opacity
  ramp of bench_peers (and of every speed target of issue 36), today's midpoint
  rule is 3-11x closer to the integral than pre-integration at the same sample
  count, on all three datasets: both are second order, and the midpoint rule's
  constant is smaller where the transfer function is smooth over a step. Matching
  its error takes pre-integration about twice the samples on AMReX and more than
  four times on Athena++ and Gerris.
- **A kernel-sized integral table needs the midpoint lookup too.** The difference
  of the integral tables over a step whose two ends lie close together loses its
  precision: with a 1,024-interval table (16 KiB, about what stays in the L1 cache
  on these CPUs) the error stops falling with the rate: on AMReX and Gerris an
  RMSE of 1.6e-4 to 5.5e-4 on the benchmarks' function, and of 7.6e-4 to 4.8e-3
  on the default ramp, with 14-20 % of the pixels visibly off. Taking the transfer function at the mean of the ends
  for steps within two table intervals removes that floor, and those are most of
  the steps (the line above the table). So a kernel would run today's lookup and
  opacity correction on most samples and the integral tables on the rest; in
  packets of eight lanes it would run both.
- **With features narrower than a step it is the other way round.** On the peaks
  function, pre-integration at one sample per finest cell is closer to the
  integral than the midpoint rule at four, on all three datasets, and at four
  samples it leaves 3.5-5x fewer pixels visibly wrong on AMReX and Gerris. On
  Athena++ the reference itself is off by about 4e-4 RMSE there (the check above),
  which bounds what the finer rates can show. The picture
  (docs/images/preintegration-peaks.png: the reference | the midpoint rule | 1D
  pre-integration with the kernel-sized table, the middle of Athena++'s domain at
  one sample per finest cell) shows what the midpoint rule does there: it speckles the thin shells that
  the peaks make of the blast.
- **1D tables are enough.** Engel's integral functions and the full 2D integral of
  each step agree to within their own errors on the benchmarks' function and the
  peaks; on the default ramp, where a step's own attenuation matters, either can be
  the closer one (the 2D integral on AMReX, the 1D on Gerris).
"""


def transfer_functions(value_range) -> dict[str, TransferFunction]:
    """The three transfer functions of the module docstring, over `value_range`."""
    bench = transfer_function(value_range)
    lo, hi = bench.value_range
    span = hi - lo
    tents = [[lo, 0.0]]
    for centre in (0.25, 0.5, 0.75):
        c = lo + centre * span
        tents += [[c - 0.01 * span, 0.0], [c, 0.5], [c + 0.01 * span, 0.0]]
    tents.append([hi, 0.0])
    peaks = TransferFunction(bench.rgb_points, np.array(tents), "peaks")
    return {"bench": bench, "ramp": transfer_function(value_range, alpha_scale=1.0), "peaks": peaks}


class IntegralTables:
    """S(v) = int sigma dv and K(v) = int sigma rgb dv over a transfer function's span at
    NODES + 1 even nodes (float64; sigma per world unit), extended linearly outside,
    where the transfer function clamps."""

    def __init__(self, tf: TransferFunction, unit: float, intervals: int = NODES):
        knots = np.unique(np.concatenate([tf.rgb_points[:, 0], tf.alpha_points[:, 0]]))
        self.lo, self.hi = float(knots[0]), float(knots[-1])
        self.tf, self.unit = tf, unit
        self.nodes = np.linspace(self.lo, self.hi, intervals + 1)
        # Integrate between consecutive points of nodes and knots, where rgba is linear:
        # Gauss-Legendre on -ln(1 - alpha) (integrable where alpha reaches 1).
        cuts = np.unique(np.concatenate([self.nodes, knots]))
        a, b = cuts[:-1], cuts[1:]
        x, w = GAUSS
        v = 0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * x[None, :]
        rgba = tf.evaluate(v)
        sigma = self.sigma(rgba[..., 3])
        half = 0.5 * (b - a)
        parts = np.stack([(sigma * w).sum(1) * half,
                          *[(sigma * rgba[..., c] * w).sum(1) * half for c in range(3)]], 1)
        cumulative = np.concatenate([np.zeros((1, 4)), np.cumsum(parts, 0)])
        at_node = np.searchsorted(cuts, self.nodes)
        self.table = cumulative[at_node]                       # (intervals + 1, 4): S, K rgb
        ends = tf.evaluate(np.array([self.lo, self.hi]))
        self.end_slopes = np.stack([np.concatenate([[s], s * e[:3]])
                                    for s, e in zip(self.sigma(ends[:, 3]), ends)])

    def sigma(self, alpha):
        with np.errstate(divide="ignore"):
            return -np.log1p(-np.minimum(alpha, 1.0)) / self.unit

    def __call__(self, v):
        """(S, K_r, K_g, K_b) at values v (...) -> (..., 4)."""
        x = np.clip(v, self.lo, self.hi)
        out = np.stack([np.interp(x, self.nodes, self.table[:, c]) for c in range(4)], -1)
        for outside, slope in ((np.minimum(v - self.lo, 0.0), self.end_slopes[0]),
                               (np.maximum(v - self.hi, 0.0), self.end_slopes[1])):
            with np.errstate(invalid="ignore"):  # 0 * an infinite slope, not taken
                out += np.where(outside[..., None] != 0, outside[..., None] * slope, 0.0)
        return out


def composite(alpha, rgb):
    """Front-to-back premultiplied RGBA of steps (R, n) opacity and (R, n, 3) colour."""
    transmit = np.cumprod(1.0 - alpha, axis=1)
    before = np.concatenate([np.ones((alpha.shape[0], 1)), transmit[:, :-1]], axis=1)
    out = np.empty((alpha.shape[0], 4))
    out[:, :3] = np.einsum("rk,rkc->rc", before * alpha, rgb)
    out[:, 3] = 1.0 - transmit[:, -1] if alpha.shape[1] else 0.0
    return out


def midpoint(values, h, tf, unit):
    """values (R, n) at step midpoints (NaN: transparent or past the ray's end)."""
    rgba = tf.evaluate(values)
    ok = np.isfinite(values)
    alpha = np.where(ok, 1.0 - np.power(1.0 - np.where(ok, rgba[..., 3], 0.0), h[:, None] / unit),
                     0.0)
    return composite(alpha, np.where(ok[..., None], rgba[..., :3], 0.0))


def fill_ends(ends, steps):
    """Step ends (R, m + 1) of rays of `steps` (R,) steps -> (front, back) (R, m), NaN past
    a ray's last step; inside, a NaN end takes the other end's value (where no cell's
    hat is positive)."""
    f, b = ends[:, :-1], ends[:, 1:]
    inside = np.arange(f.shape[1])[None, :] < steps[:, None]
    f, b = np.where(np.isnan(f), b, f), np.where(np.isnan(b), f, b)
    return np.where(inside, f, np.nan), np.where(inside, b, np.nan)


def preintegrated_1d(ends, steps, h, tables: IntegralTables, flat: float = 1e-12):
    """Engel's integral functions (module docstring); ends (R, m + 1), `steps` per ray. A
    step whose ends differ by less than `flat` of the span takes the transfer function
    at the mean of its ends instead (the integral tables' differences lose their
    precision there)."""
    f, b = fill_ends(ends, steps)
    ok = np.isfinite(f)
    f, b = np.where(ok, f, 0.0), np.where(ok, b, 0.0)
    tf_, tb = tables(f), tables(b)
    ds = b - f
    flat = np.abs(ds) < flat * (tables.hi - tables.lo)
    mid = tables.tf.evaluate(0.5 * (f + b))
    sigma_mid = tables.sigma(mid[..., 3])
    with np.errstate(divide="ignore", invalid="ignore"):
        d_s = tb[..., 0] - tf_[..., 0]
        tau = np.where(flat, sigma_mid, d_s / np.where(flat, 1.0, ds)) * h[:, None]
        rgb = np.where((d_s > 0)[..., None], (tb[..., 1:] - tf_[..., 1:]) / d_s[..., None],
                       mid[..., :3])
    tau = np.where(ok, tau, 0.0)
    return composite(-np.expm1(-tau), np.where(ok[..., None], rgb, 0.0))


def preintegrated_2d(ends, steps, h, tf, unit):
    """Each step with the value linear between its ends, integrated by SUB_STEPS
    midpoint sub-steps with its own attenuation; ends (R, m + 1), `steps` per ray."""
    f, b = fill_ends(ends, steps)
    ok = np.isfinite(f)
    u = (np.arange(SUB_STEPS) + 0.5) / SUB_STEPS
    v = f[..., None] + (b - f)[..., None] * u                   # (R, n, S)
    rgba = tf.evaluate(np.where(ok[..., None], v, 0.0))
    a = 1.0 - np.power(1.0 - rgba[..., 3], (h / SUB_STEPS / unit)[:, None, None])
    a = np.where(ok[..., None], a, 0.0)
    transmit = np.cumprod(1.0 - a, axis=2)
    before = np.concatenate([np.ones(a.shape[:2] + (1,)), transmit[..., :-1]], axis=2)
    emitted = np.einsum("rns,rnsc->rnc", before * a, rgba[..., :3])
    alpha = 1.0 - transmit[..., -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        rgb = np.where((alpha > 0)[..., None], emitted / alpha[..., None], 0.0)
    return composite(alpha, rgb)


class Rays:
    """The rays of one frame through the data's world bounds, and their values."""

    def __init__(self, device: DeviceDataset, camera, size: int, bounds, finest: float):
        o, d = camera.rays(size, size)
        self.o, self.d = o.reshape(-1, 3), d.reshape(-1, 3)
        lo, hi = (np.asarray(x, np.float64) for x in bounds)
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (lo - self.o) / self.d, (hi - self.o) / self.d
        self.t0 = np.nanmax(np.minimum(ta, tb), axis=1).clip(min=0.0)
        self.length = np.maximum(np.nanmin(np.maximum(ta, tb), axis=1) - self.t0, 0.0)
        self.device, self.finest = device, finest

    def values(self, rays, rate: float, ends: bool):
        """Values at the step midpoints (R, m) or ends (R, m + 1) of `rays` at `rate`,
        NaN-padded, the rays' step counts (R,) and step lengths h (R,)."""
        n = np.ceil(self.length[rays] * rate / self.finest).astype(np.int64)
        h = self.length[rays] / np.maximum(n, 1)
        m = int(n.max()) + (1 if ends else 0)
        k = np.arange(m)
        valid = (k[None, :] < (n + 1 if ends else n)[:, None]) & (n > 0)[:, None]
        t = self.t0[rays][:, None] + (k[None, :] + (0.0 if ends else 0.5)) * h[:, None]
        # The ends on the bounds' faces, a hair inside (a box is half-open: a point on
        # its upper face lies in no region).
        t = np.clip(t, (self.t0[rays] + EDGE * h)[:, None],
                    (self.t0[rays] + self.length[rays] - EDGE * h)[:, None])
        points = self.o[rays][:, None, :] + t[..., None] * self.d[rays][:, None, :]
        out = np.full(valid.shape, np.nan)
        if valid.any():
            out[valid] = self.device.probe_fields(points[valid])[0]
        return out, n, h


def measure(rays: Rays, tfs: dict, unit: float, rates, reference_rate: float) -> dict:
    """{tf name: {(method, rate): image (R, 4)}} over every ray; the reference under
    ("reference", rate) and its check (1D pre-integration at the same rate) under
    ("check", rate)."""
    fine = {name: IntegralTables(tf, unit) for name, tf in tfs.items()}
    small = {name: IntegralTables(tf, unit, KERNEL_INTERVALS) for name, tf in tfs.items()}
    images: dict = {name: {} for name in tfs}
    for start in range(0, rays.o.shape[0], RAY_CHUNK):
        chunk = np.arange(start, min(start + RAY_CHUNK, rays.o.shape[0]))
        parts: dict = {name: {} for name in tfs}
        ref, _, h = rays.values(chunk, reference_rate, ends=False)
        ends, steps, h_ends = rays.values(chunk, reference_rate, ends=True)
        for name, tf in tfs.items():
            parts[name]["reference", reference_rate] = midpoint(ref, h, tf, unit)
            parts[name]["check", reference_rate] = preintegrated_1d(ends, steps, h_ends, fine[name])
        for rate in rates:
            mids, _, h = rays.values(chunk, rate, ends=False)
            ends, steps, h = rays.values(chunk, rate, ends=True)
            f, b = fill_ends(ends, steps)
            inside = np.isfinite(f)
            for name, tf in tfs.items():
                got = parts[name]
                span = small[name].hi - small[name].lo
                flat = np.abs(b - f) < FLAT_INTERVALS / KERNEL_INTERVALS * span
                got["flat", rate] = np.array([[np.count_nonzero(flat & inside), inside.sum()]])
                got[METHODS[0], rate] = midpoint(mids, h, tf, unit)
                got[METHODS[1], rate] = preintegrated_1d(ends, steps, h, fine[name])
                got[METHODS[2], rate] = preintegrated_1d(ends, steps, h, small[name])
                got[METHODS[3], rate] = preintegrated_1d(ends, steps, h, small[name],
                                                         flat=FLAT_INTERVALS / KERNEL_INTERVALS)
                got[METHODS[4], rate] = preintegrated_2d(ends, steps, h, tf, unit)
        for name in tfs:
            for key, part in parts[name].items():
                images[name].setdefault(key, []).append(part)
    return {name: {key: np.concatenate(v) for key, v in got.items()} for name, got in images.items()}


def errors(image, reference) -> tuple[float, float, float]:
    """(RMSE, max abs, share of pixels with a channel off by more than half an 8-bit step)."""
    diff = np.abs(image - reference)
    return (float(np.sqrt(np.mean(diff ** 2))), float(diff.max()),
            float(np.mean(diff.max(axis=1) > HALF_STEP_8BIT)))


def picture(path: Path, size: int, frames) -> None:
    """Frames (size², 4) premultiplied RGBA side by side over black, as an 8-bit PNG."""
    from PIL import Image

    gap = np.full((size, 4, 3), 255, np.uint8)
    tiles = [np.rint(np.clip(f[:, :3], 0.0, 1.0) * 255).astype(np.uint8).reshape(size, size, 3)
             for f in frames]
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)).save(path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default=",".join(DEFAULT))
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--rates", default="1,2,4")
    p.add_argument("--reference-rate", type=float, default=32.0)
    p.add_argument("--work", default=str(benchdoc.BENCH / "render"))
    p.add_argument("--picture", type=Path, default=None,
                   help="also write --picture-of's frame with the peaks transfer function, seen "
                        "from closer, as a PNG: the reference | the midpoint rule | 1D "
                        "pre-integration (the kernel-sized table), at the lowest rate")
    p.add_argument("--picture-of", default="athena")
    p.add_argument("--picture-size", type=int, default=192)
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    sets = benchdoc.datasets()
    rows, checks, flats = [], [], []
    for key in benchdoc.chosen([args.only], list(sets)):
        d = ensure_scene(Path(args.work), sets[key])
        cells = schema.load(d / "cells.npz", "cells", mapped=True)
        bricks, regions, bvh = (schema.load(d / f"{k}.npz", k) for k in ("bricks", "regions", "bvh"))
        field = PEER_DATASETS[key][1] if key in PEER_DATASETS else sets[key].field
        device = DeviceDataset(bricks, regions, bvh, field=field)
        values = cells.values[cells.field_index(field)]
        value_range = (float(np.nanmin(values)), float(np.nanmax(values)))
        bounds = schema.world_bounds(cells)
        camera = default_camera(*bounds)
        unit = finest = finest_cell_width_world(bricks)
        rays = Rays(device, camera, args.size, bounds, finest)
        if args.picture is not None and key == args.picture_of:
            tf = {"peaks": transfer_functions(value_range)["peaks"]}
            lo, hi = (np.asarray(x, np.float64) for x in bounds)
            closer = default_camera(lo + PICTURE_MARGIN * (hi - lo), hi - PICTURE_MARGIN * (hi - lo))
            frames = measure(Rays(device, closer, args.picture_size, bounds, finest), tf, unit,
                             rates[:1], args.reference_rate)["peaks"]
            picture(args.picture, args.picture_size, [frames["reference", args.reference_rate],
                                                      frames[METHODS[0], rates[0]],
                                                      frames[METHODS[3], rates[0]]])
        images = measure(rays, transfer_functions(value_range), unit, rates, args.reference_rate)
        for name, got in images.items():
            reference = got["reference", args.reference_rate]
            check = errors(got["check", args.reference_rate], reference)
            print(f"{key} {name}: the reference against 1D pre-integration at its rate: "
                  f"RMSE {check[0]:.1e}, max {check[1]:.1e}", flush=True)
            checks.append(f"{sets[key].name}, {name}: {check[0]:.1e} / {check[1]:.1e}")
            for method in METHODS:
                cells_ = [errors(got[method, rate], reference) for rate in rates]
                rows.append(f"| {sets[key].name} | {name} | {method} | " + " | ".join(
                    f"{r:.1e} / {m:.1e} / {s:.1%}" for r, m, s in cells_) + " |")
                print(rows[-1], flush=True)
            flat = [got["flat", rate].sum(axis=0) for rate in rates]
            flats.append(f"{sets[key].name}, {name}: " + ", ".join(
                f"{n / max(total, 1):.0%}" for n, total in flat))
    header = " | ".join(f"rate {r:g}: RMSE / max / pixels off" for r in rates)
    body = (
        f"Command: `.venv/bin/python -m benchmarks.bench_preintegration --only {args.only} "
        f"--size {args.size} --rates {args.rates} --reference-rate {args.reference_rate:g}"
        + (f" --picture {args.picture} --picture-of {args.picture_of} --picture-size "
           f"{args.picture_size}" if args.picture else "") + " --write-docs`\n\n"
        f"- machine: {benchdoc.machine(opencl=True)}\n"
        f"- {args.size}² rays of bench_peers' camera, float64 after `probe`; errors of "
        f"premultiplied RGBA against the midpoint rule at {args.reference_rate:g} samples per "
        "finest cell; pixels off: some channel off by more than half an 8-bit step "
        "(benchmarks/bench_preintegration.py says how)\n"
        f"- how far the reference is from the integral: it against 1D pre-integration at the "
        f"same {args.reference_rate:g} samples per finest cell (RMSE / max): " + "; ".join(checks)
        + "\n"
        f"- steps whose ends lie within {FLAT_INTERVALS} intervals of the "
        f"{KERNEL_INTERVALS:,}-interval table (rates {args.rates}): " + "; ".join(flats)
        + "\n\n"
        f"| dataset | transfer function | quadrature | {header} |\n"
        "|---|---|---|" + "---:|" * len(rates) + "\n" + "\n".join(rows) + "\n\n" + READING)
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
