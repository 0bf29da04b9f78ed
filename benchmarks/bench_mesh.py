"""Meshes with the volume (issue 37; docs/design-rendering.md, "Meshes"): what the mesh BVH
build costs and what a mesh adds to a frame.

    .venv/bin/python -m benchmarks.bench_mesh [--triangles 1e6,1e7] [--size 1024] [--runs 3] [--write-docs]

Meshes: a wavy sheet through the middle of the AMReX advection data, a grid of
N x N vertices (2 (N - 1)^2 triangles) whose height is a sum of sines, written as
binary PLY under bench-data/meshes/. For each size:

- *build*: `exabricks.mesh.build_mesh_set` of the read mesh in this process (the
  median of --runs after a warm-up, so numba's compiled code is loaded), and its
  two parts timed on their own in the same runs: the BVH (`mesh_bvh`: triangles
  per second, nodes and depth) and the smooth-shading corner normals
  (`corner_normals`); and reading the file (trimesh).
- *frame*: an AMReX frame at --size (default camera, viridis with an opacity ramp
  0 -> 0.1 over the field's range, headlight shading), with
  no mesh, with the sheet opaque (it hides the volume behind it: fewer samples)
  and with the sheet at opacity 0.3 (every sample and every mesh hit): the
  median kernel time of --runs frames after a warm-up, the variants in turn.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc

SECTION = "Meshes with the volume"
NOTES = """
*Build*: `build_mesh_set` in a warm process: the triangles' boxes, the binned-SAH
tree of the regions' builder (`stages.bvh.build_tree`, 16 bins, leaves of at most
four triangles, both cores), the node boxes and the triangles in tree order, and
the smooth-shading normals of every corner (*normals*: `corner_normals`, the
points grouped by position, angle-weighted face normals within the crease angle).
*BVH*: `mesh_bvh` alone (the boxes, the tree, its bounds, the triangles in its
order).
*Read*: trimesh's binary PLY reader and our checks. *Frame*: the kernel's time
of one 1024² AMReX frame (default camera, viridis with an opacity ramp 0 → 0.1,
headlight shading); *opaque*: the sheet at opacity 1, which ends every ray that
meets it (the volume behind is not sampled); *translucent*: opacity 0.3, every
volume sample and the sheet's hit (each ray also walks the mesh BVH once).
What it says (issue 37's targets: a 10 M-triangle mesh adds at most 30 % to a
1024² AMReX frame; the BVH builds at 2 M triangles/s or more):

- **The frame: missed for a translucent mesh, met for an opaque one.** At
  opacity 0.3 every ray walks the mesh BVH once (26 levels at 10 M triangles)
  and composites the hit. Taken apart at 10 M triangles, before smooth
  shading (in one process, 3 frames each): the surface build of the kernel
  costs 3.5 % (one triangle out of view: 771 against 746 ms); the walk's box
  tests 29 % (the triangle test switched off, so that nothing is hit: 989 ms);
  the triangle tests and the hits' shading and compositing the other 10 %.
  The triangle test reads each vertex in the ray's axis order with one vector
  permute; that made no difference, so the walk over the nodes is what a wider
  or compressed BVH would have to cut. Smooth shading (the corners' normals
  interpolated at each hit) took the translucent 10 M sheet from 1.41x to
  about 1.46x. An opaque sheet hides the volume behind it and the frame gets
  cheaper. Before the sample packets learnt to composite as a vector when no
  surface hit falls among their lanes (and to span regions when there is no
  iso-surface), the translucent 1 M sheet cost 1.46x.
- **The BVH: met at 1 M triangles (2.27 M/s), at 10 M 1.97 M/s here, 1.5 %
  short.** It is the regions' binned-SAH builder: its top six
  levels split breadth first until there are 64 subtrees, a level's nodes at
  once on the two threads, then the subtrees on the threads. The first split,
  which nothing runs beside, now makes its two passes over every triangle (the
  centroids' bounds, then the bins) in parts on both threads, merged
  (`stages.bvh._split_root`): at 10 M triangles 5.15 s (1.94 M/s) became
  5.08 s in this table's runs, which come between full builds, and 4.9 s
  (2.04 M/s) in two runs of the BVH alone; the trees are the same, array for
  array (tested on the Gerris cell supports, and checked on this 10 M-triangle
  sheet).
- **The normals** cost nearly as much as the BVH at 10 M triangles: the points
  grouped by position (a sort of a hash of the 5 M vertices' float32
  coordinates), the corners grouped by point (a counting sort), then each
  point's corners summed with the point's faces in cache.
- **Reading** a 10 M-triangle binary PLY through trimesh takes longer than the
  build. A later process takes the set (BVH and normals) from the cache of
  built structures (docs/design.md, "Sources and the cache of built
  structures"): `.venv/bin/python -m benchmarks.bench_mesh_cache
  bench-data/meshes/sheet2237.ply` read, built and stored the 10 M-triangle
  sheet in 21.2 s and took it from the cache in 2.9 s (hashing the 190 MB
  file, reading the 756 MB entry and checking it) on 2026-12-05.
"""


def sheet(n: int, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of an n x n wavy sheet across the box [lo, hi], at its middle height."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    span = hi - lo
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    z = 0.5 + 0.12 * np.sin(6 * np.pi * x) * np.cos(4 * np.pi * y) + 0.05 * np.sin(23 * x + 17 * y)
    v = np.stack([lo[0] + span[0] * x, lo[1] + span[1] * y, lo[2] + span[2] * z], axis=-1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v.astype(np.float32), faces.astype(np.int32)


def ensure_sheet(triangles: int, lo, hi) -> Path:
    import trimesh

    n = int(round(np.sqrt(triangles / 2))) + 1
    path = benchdoc.BENCH / "meshes" / f"sheet{n}.ply"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        v, f = sheet(n, lo, hi)
        trimesh.Trimesh(vertices=v, faces=f, process=False).export(path)
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--triangles", default="1e6,1e7", help="mesh sizes (comma-separated)")
    p.add_argument("--size", type=int, default=1024)
    benchdoc.add_common_args(p, runs=3)
    args = p.parse_args(argv)

    import exabricks as eb
    from exabricks import schema
    from exabricks.engine.renderer import Renderer
    from exabricks.mesh import build_mesh_set, corner_normals, mesh_bvh, read_mesh
    from exabricks.scene.model import MeshLayer
    from exabricks.builders.bvh import tree_depths
    from benchmarks.peers.common import ALPHA_SCALE, DATASETS

    dataset = eb.open(DATASETS["amrex"][0], cache=False)
    bricks, regions, bvh = dataset.structures()
    scene = eb.Renderer(dataset).scene(size=(args.size, args.size), colormap="viridis",
                                       opacity=[0.0, ALPHA_SCALE])
    lo, hi = schema.world_bounds(bricks)
    renderer = Renderer(bricks, regions, bvh, fields=scene.fields())
    rows = []
    for count in (int(float(t)) for t in args.triangles.split(",")):
        path = ensure_sheet(count, lo, hi)
        t = time.perf_counter()
        mesh = read_mesh(path)
        read_s = time.perf_counter() - t
        build_mesh_set([mesh])  # warm-up: numba's cached code
        builds, trees, normals = [], [], []
        owner = np.zeros(len(mesh.faces), np.float32)
        for _ in range(args.runs):
            t = time.perf_counter()
            meshes = build_mesh_set([mesh])
            builds.append(time.perf_counter() - t)
            t = time.perf_counter()
            mesh_bvh(mesh.vertices, mesh.faces, owner)
            trees.append(time.perf_counter() - t)
            t = time.perf_counter()
            corner_normals(mesh.vertices, mesh.faces)
            normals.append(time.perf_counter() - t)
        depth = int(tree_depths(meshes.links[:, 0].astype(np.int64),
                                meshes.links[:, 1].astype(np.int64)).max()) + 1
        variants = {"no mesh": scene,
                    "opaque": scene.replace(meshes=(MeshLayer(str(path), opacity=1.0),)),
                    "translucent": scene.replace(meshes=(MeshLayer(str(path), opacity=0.3),))}
        times = {k: [] for k in variants}
        samples = {}
        for k, s in variants.items():  # warm-up, and the mesh's upload
            samples[k] = renderer.render_scene(s).stats["samples"]
        for _ in range(args.runs):
            for k, s in variants.items():
                times[k].append(renderer.render_scene(s).stats["ms"])
        base = statistics.median(times["no mesh"])
        bvh_s = statistics.median(trees)
        rows.append((count, meshes.n_triangles, read_s, builds, trees, normals, len(meshes.nodes),
                     depth, times, samples, base))
        print(f"{meshes.n_triangles:,} triangles: read {read_s:.2f} s, build "
              f"{statistics.median(builds):.2f} s (BVH {bvh_s:.2f} s, "
              f"{meshes.n_triangles / bvh_s / 1e6:.2f} M/s; normals {statistics.median(normals):.2f} s), "
              + ", ".join(f"{k} {statistics.median(v):.0f} ms" for k, v in times.items()), flush=True)

    lines = [f"Command: `.venv/bin/python -m benchmarks.bench_mesh --triangles {args.triangles} "
             f"--size {args.size} --runs {args.runs}`", "",
             f"- machine: {benchdoc.machine(opencl=True)}", "",
             "| triangles | read s | build s | BVH s | BVH M triangles/s | normals s | nodes / depth | "
             "frame ms: no mesh | opaque (samples) | translucent 0.3 | translucent / no mesh |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for _, n, read_s, builds, trees, normals, nodes, depth, times, samples, base in rows:
        lines.append(
            f"| {n:,} | {read_s:.2f} | {benchdoc.fmt_spread(builds, 's', 2)} | "
            f"{benchdoc.fmt_spread(trees, 's', 2)} | {n / statistics.median(trees) / 1e6:.2f} | "
            f"{benchdoc.fmt_spread(normals, 's', 2)} | "
            f"{nodes:,} / {depth} | {benchdoc.fmt_spread(times['no mesh'], '', 0)} | "
            f"{benchdoc.fmt_spread(times['opaque'], '', 0)} ({samples['opaque']:,} of "
            f"{samples['no mesh']:,}) | {benchdoc.fmt_spread(times['translucent'], '', 0)} | "
            f"{statistics.median(times['translucent']) / base:.2f}x |")
    benchdoc.publish(SECTION, "\n".join(lines) + "\n" + NOTES, args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
