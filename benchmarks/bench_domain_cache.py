"""Domains kept resident across samples, bands and frames under a memory budget
(issue 38, item 2): domain reads and seconds with the cache of
exabricks.engine.streaming.Budgeted, against the same Budgeted holding one
domain at a time (its capacity set to nothing), in one run.

    .venv/bin/python -m benchmarks.bench_domain_cache [--size 256] [--budgets 8,16]
        [--write-docs]

On make_big.py's layouts at test size (benchmarks.bench_budget.make_layouts:
octree-like, block-structured, thin shells), each under each budget (MiB):
- a frame in bands of 32 rows (`render --tile SIZE 32`);
- a progressive frame of 4 samples (sample after sample, as `--progressive`);
- an orbit of 4 frames, 4 degrees apart (the viewer's and `movie`'s case).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


from benchmarks import benchdoc
from benchmarks.bench_budget import make_layouts

SECTION = "Domains kept across samples, bands and frames"
WAYS = ("one at a time", "kept", "kept and prefetched")
CASES = ("bands of 32 rows", "4 samples, progressive", "4 frames of an orbit")


def _scene(bricks, field: str, size: int):
    from exabricks.scene.build import scene_from_options

    scene = scene_from_options(bricks, flags={"field": field, "size": (size, size)})
    return scene.replace(settings=dataclasses.replace(scene.settings, max_opacity=1.0))


def _case(domains, scene, case: str) -> None:
    from exabricks.engine.streaming import render_steps, render_tiled

    width = int(scene.settings.width)
    if case == CASES[0]:
        render_tiled(domains, scene, (width, 32), lambda *a: None)
    elif case == CASES[1]:
        spp4 = scene.replace(settings=dataclasses.replace(scene.settings, spp=4))
        render_steps(domains, spp4, deadline=time.perf_counter() + 1e9)
    else:
        from exabricks import schema
        from exabricks.picture.camera_path import orbit

        for camera in orbit(*schema.world_bounds(domains.bricks), 4, degrees=12.0):
            render_steps(domains, scene.replace(camera=camera))


def bench(work: Path, size: int, budgets) -> list[str]:
    from exabricks import schema
    from exabricks.engine.streaming import Budgeted

    rows = []
    for name, (files, field) in make_layouts(work).items():
        bricks, regions = (schema.load(f, mapped=True) for f in files[:2])
        scene = _scene(bricks, field, size)
        for mib in budgets:
            for case in CASES:
                figures = {way: [] for way in WAYS}
                # the first run warms the caches; then each way twice, alternately
                for way in (WAYS[0], *WAYS, *reversed(WAYS)):
                    domains = Budgeted(bricks, regions, scene, mib << 20, prefetch=way == WAYS[2])
                    if way == WAYS[0]:
                        domains.capacity = 0  # nothing stays beside the next domain
                    start = time.perf_counter()
                    _case(domains, scene, case)
                    figures[way].append((time.perf_counter() - start, domains.reads,
                                         domains.n_domains))
                    figures[way] = figures[way][-2:]
                (s0, r0, n0), (s1, r1, _), (s2, r2, n2) = (min(figures[w]) for w in WAYS)
                rows.append(f"| {name} | {mib} MiB | {case} | {n0} | {r0} | {r1} | {n2} | {r2} | "
                            f"{s0:.2f} | {s1:.2f} | {s2:.2f} | {s0 / s1:.2f}x | {s0 / s2:.2f}x |")
                print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--budgets", default="8,16", help="MiB, comma-separated")
    parser.add_argument("--work", type=Path, default=benchdoc.ROOT / "bench-data" / "layouts")
    parser.add_argument("--write-docs", action="store_true")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    budgets = [int(b) for b in args.budgets.split(",")]
    rows = bench(args.work, args.size, budgets)
    body = (f"Measured on {benchdoc.machine(opencl=True)} with\n`.venv/bin/python -m "
            f"benchmarks.bench_domain_cache --size {args.size} --budgets {args.budgets}`: "
            f"{args.size}² frames of make_big.py's layouts at test size (the streaming tests' "
            "layouts). Each case is drawn three ways in the same run: by a `Budgeted` holding "
            "one domain at a time (as before domains were kept), by one keeping domains resident "
            "as the budget allows, and by one that also makes the next domain on a thread while "
            "the one before it draws (its domains planned smaller so that the budget holds "
            "both). After one run to warm the caches each way runs twice, alternately; the "
            "best of two.\n\n"
            "| layout | budget | case | domains | reads, one at a time | reads, kept | domains, "
            "prefetched | reads, prefetched | s, one at a time | s, kept | s, prefetched | "
            "kept | prefetched |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
            + "\n".join(rows) + "\n")
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
