"""The meshes' BVH read, built and stored, against taken from the cache of built
structures (docs/benchmarks-render.md, "Meshes with the volume"):

    .venv/bin/python -m benchmarks.bench_mesh_cache bench-data/meshes/sheet2237.ply

(bench_mesh writes the sheets). The cache is a fresh temporary directory.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time


def main(argv) -> int:
    path = argv[0]
    with tempfile.TemporaryDirectory() as root:
        os.environ["EXABRICKS_CACHE"] = root
        from exabricks import mesh

        start = time.perf_counter()
        first = mesh.mesh_set((path,))
        built = time.perf_counter() - start
        mesh._mesh_set.cache_clear()  # as a later process
        start = time.perf_counter()
        mesh.mesh_set((path,))
        cached = time.perf_counter() - start
    print(f"{first.n_triangles:,} triangles: read + build + store {built:.2f} s, "
          f"from the cache {cached:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
