"""Coherent rays (issue 36, item 2), measured before they are built: how full would
packets of neighbouring rays that share one walk over the regions be?

    .venv/bin/python -m benchmarks.bench_lane_fill [--sizes 512,1024] [--only gerris,...] [--write-docs]

For each dataset (the stage files of benchmarks/bench_render.py's work directory,
built on first use), every primary ray of a frame of each of --sizes of the default camera
(exabricks.picture.camera.default_camera on the data's world bounds) is walked through
the BVH to every region it crosses with positive length: a transfer function that
leaves nothing to skip. A packet of k neighbouring rays (2×2 or 4×2 pixels) that
walks the union of its rays' regions, each lane active in the regions its own ray
crosses, fills

- by regions: sum over the lanes of the regions each visits / (k × the regions of
  the union);
- by samples: the same with each visit weighed by the samples it takes (its
  length in finest cells of the region's finest level, the adaptive sampling of
  §4.2), a region of the union taking as many packet steps as its longest lane.

1 is perfect coherence; 1/k means no two rays of a packet share a region. The
figures bound what packets can gain on a walk that costs per region (BVH queries
and region set-up) and per sample; docs/benchmarks-render.md, "Coherent rays: lane
fill" has them. --write-docs replaces that section.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numba
import numpy as np

from benchmarks import benchdoc
from benchmarks.bench_render import DEFAULT, ensure_scene

from exabricks import schema
from exabricks.picture.camera import default_camera

SECTION = "Coherent rays: lane fill"
PACKETS = ((2, 2), (4, 2))


@numba.njit(cache=True, inline="always")
def _slab(o, inv, lo, hi):
    t0, t1 = 0.0, np.inf
    for a in range(3):
        u = (lo[a] - o[a]) * inv[a]
        v = (hi[a] - o[a]) * inv[a]
        t0 = max(t0, min(u, v))
        t1 = min(t1, max(u, v))
    return t0, t1


@numba.njit(cache=True)
def _walk(o, d, node_lo, node_hi, first, count, index, reg_lo, reg_hi, finest, out_r, out_w):
    """Every region the ray o + t d (t >= 0, lattice units) crosses with positive
    length: ids into out_r, weights (length in finest cells) into out_w; returns
    their count (at most out_r.size)."""
    inv = 1.0 / d
    stack = np.empty(128, np.int64)
    stack[0] = 0
    top = 1
    n = 0
    while top > 0:
        top -= 1
        node = stack[top]
        t0, t1 = _slab(o, inv, node_lo[node], node_hi[node])
        if t0 >= t1:
            continue
        if count[node] == 0:
            stack[top] = first[node]
            stack[top + 1] = first[node] + 1
            top += 2
            continue
        for k in range(first[node], first[node] + count[node]):
            r = index[k]
            s0, s1 = _slab(o, inv, reg_lo[r], reg_hi[r])
            if s0 < s1 and n < out_r.shape[0]:
                out_r[n] = r
                out_w[n] = (s1 - s0) * np.sqrt((d * d).sum()) / (1 << finest[r])
                n += 1
    return n


@numba.njit(cache=True, parallel=True)
def _fill(origins, directions, pw, ph, node_lo, node_hi, first, count, index, reg_lo, reg_hi,
          finest, cap):
    """Per packet of pw × ph pixels: (lane region visits, union regions, lane samples,
    union packet steps, rays with more than `cap` regions)."""
    h, w = origins.shape[0], origins.shape[1]
    gx, gy = w // pw, h // ph
    out = np.zeros((gx * gy, 5))
    for g in numba.prange(gx * gy):
        k = pw * ph
        ids = np.empty(k * cap, np.int64)
        wts = np.empty(k * cap)
        m = 0
        for j in range(ph):
            for i in range(pw):
                y, x = (g // gx) * ph + j, (g % gx) * pw + i
                n = _walk(origins[y, x], directions[y, x], node_lo, node_hi, first, count, index,
                          reg_lo, reg_hi, finest, ids[m:m + cap], wts[m:m + cap])
                if n == cap:
                    out[g, 4] += 1
                m += n
        if m == 0:
            continue
        order = np.argsort(ids[:m], kind="mergesort")
        union = 0
        steps = 0.0
        prev = -1
        best = 0.0
        for q in range(m):
            r = ids[order[q]]
            if r != prev:
                union += 1
                steps += best
                best = 0.0
                prev = r
            best = max(best, np.ceil(wts[order[q]]))
        steps += best
        out[g, 0] = m
        out[g, 1] = union
        out[g, 2] = np.ceil(wts[:m]).sum()
        out[g, 3] = steps
    return out


def tree_arrays(regions: schema.Regions, bvh: schema.Bvh) -> list[np.ndarray]:
    """The arrays `_walk` and `_fill` take after the ray: the BVH's node boxes,
    links and region order, the regions' boxes and finest levels."""
    return [np.ascontiguousarray(a) for a in (
        bvh.lower_lattice.astype(np.float64), bvh.upper_lattice.astype(np.float64),
        bvh.first.astype(np.int64), bvh.count.astype(np.int64), bvh.region_index.astype(np.int64),
        regions.lower_lattice.astype(np.float64), regions.upper_lattice.astype(np.float64),
        regions.finest_level.astype(np.int64))]


def lattice_rays(bricks: schema.Bricks, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The default camera's primary rays of a size² frame in lattice units (the same t)."""
    camera = default_camera(*schema.world_bounds(bricks))
    origins, directions = camera.rays(size, size)
    return ((origins - bricks.origin_world) / bricks.spacing_world,
            directions / bricks.spacing_world)


def measure(bricks, regions, bvh, size: int, cap: int = 1 << 13) -> dict:
    """The lane fill of 2×2 and 4×2 packets of a size² frame (see the module)."""
    origins, directions = lattice_rays(bricks, size)
    tree = tree_arrays(regions, bvh)
    row = {"regions": regions.n_regions}
    for pw, ph in PACKETS:
        out = _fill(origins, directions, pw, ph, *tree, cap)
        if out[:, 4].any():
            raise SystemExit(f"a ray crosses more than {cap} regions")
        hit = out[:, 1] > 0
        k = pw * ph
        row[(pw, ph)] = {
            "regions per ray": out[:, 0].sum() / (size * size),
            "by regions": out[hit, 0].sum() / (k * out[hit, 1].sum()),
            "by samples": out[hit, 2].sum() / (k * out[hit, 3].sum()),
            "packets": int(hit.sum()),
        }
    return row


READING = """Reading the figures. On the four shared datasets a ray crosses 3-4
regions (merged regions, docs/design.md), and packets would be nearly full
(2×2: 0.95-0.98 at 1024²). But the walk is only 6-16 % of a frame's kernel time
there ("Where a frame's time goes (perf)"), and the samples, the rest, already
run in lanes (the sample packets of one ray, kernels/packet.cl): four rays
sharing one walk would save at most three quarters of that share, 5-12 %. On
the octree-like thin shells the walk weighs more (21 % of the kernel's time on
the same layout at 1.1 M cells), but a 2×2 packet would leave 29 % of its lane
steps idle at 1024² and 45 % at 512², and a 4×2 one about half. Ray packets
would pay little where they fill and least where the walk matters: not built
(issue 36, item 2).
"""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="512,1024", help="frame sides, comma-separated")
    p.add_argument("--only", default=",".join(DEFAULT))
    p.add_argument("--work", default=str(benchdoc.BENCH / "render"))
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    sets = benchdoc.datasets()
    rows = []
    for key in benchdoc.chosen([args.only], list(sets)):
        d = ensure_scene(Path(args.work), sets[key])
        structures = [schema.load(d / f"{k}.npz", k, mapped=True) for k in ("bricks", "regions", "bvh")]
        for size in (int(x) for x in args.sizes.split(",")):
            row = measure(*structures, size)
            a, b = row[PACKETS[0]], row[PACKETS[1]]
            rows.append(f"| {sets[key].name} | {row['regions']:,} | {size}² | "
                        f"{a['regions per ray']:.1f} | {a['by regions']:.2f} | "
                        f"{a['by samples']:.2f} | {b['by regions']:.2f} | {b['by samples']:.2f} |")
            print(rows[-1], flush=True)
    body = (
        f"Command: `.venv/bin/python -m benchmarks.bench_lane_fill --sizes {args.sizes} --only "
        f"{args.only} --write-docs`\n\n- machine: {benchdoc.machine()}\n"
        "- every primary ray of a frame of the default camera, walked through every region it "
        "crosses (nothing skipped); regions per ray: over every pixel; fill: the share of a "
        "packet's lane steps that do work when the packet walks the union of its rays' "
        "regions, by regions and by samples (benchmarks/bench_lane_fill.py says how)\n\n"
        "| dataset | regions | frame | regions per ray | 2×2 by regions | 2×2 by samples | "
        "4×2 by regions | 4×2 by samples |\n|---|---:|---|---:|---:|---:|---:|---:|\n"
        + "\n".join(rows) + "\n\n" + READING)
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
