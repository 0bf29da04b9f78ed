"""Issue 66's level-of-detail bars, measured as stated: `--lod 1` against `--lod 0` on
the thin shells and Enzo at 256² (docs/benchmarks-render.md, "level of detail").

    .venv/bin/python -m benchmarks.bench_lod_bars [--runs N] [--size N] [--only KEY]

Each dataset is opened as `render SOURCE` opens it (the thin shells of
make_big.py, 20.6 M cells, built and cached on first use) and one Renderer draws
its default scene with `--shading none` at SIZE²: the median frame of RUNS at
`--lod 0` and `--lod 1` in turn after one warm-up each, their samples, the
regions visible of all, and the RMSE of premultiplied RGBA against `--lod 0` at
16 spp (the issue's reference) of `--lod 0` and `--lod 1` at 1 spp and of
`--lod 1` at 16 spp (the bias of the coarser representation without the noise).
Prints a Markdown table; the figures in the docs come from it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks import benchdoc


def measure(dataset, size: int, runs: int) -> dict:
    import exabricks as eb

    ds = eb.open(dataset.path, fields=[dataset.field], **({"format": "yt"} if dataset.key == "enzo" else {}))
    r = eb.Renderer(ds)

    def frame(lod, spp=1):
        scene = r.scene(field=dataset.field, size=(size, size), lod=lod, spp=spp, shading="none")
        engine = r._on_device(scene.fields())
        started = time.perf_counter()
        result = engine.render_scene(scene)
        return result, time.perf_counter() - started

    seconds = {0: [], 1: []}
    results = {}
    for k in range(runs + 1):
        for lod in (0, 1):
            results[lod], s = frame(lod)
            if k:
                seconds[lod].append(s)
    reference = frame(0, 16)[0].rgba
    rmse = {name: float(np.sqrt(np.mean((rgba - reference) ** 2)))
            for name, rgba in (("0", results[0].rgba), ("1", results[1].rgba), ("1 at 16 spp", frame(1, 16)[0].rgba))}
    stats = results[0].stats
    return {"seconds": seconds, "samples": {lod: results[lod].stats["samples"] for lod in (0, 1)},
            "regions": (stats["visible_regions"], stats["regions"]), "rmse": rmse}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=3)
    parser.add_argument("--size", type=int, default=256)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    print(f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_lod_bars --runs {args.runs} "
          f"--size {args.size}`\n")
    print("| dataset | s / frame `--lod 0` | s / frame `--lod 1` | samples 0 → 1 | regions visible / all "
          "| RMSE `--lod 0`, 1 spp | RMSE `--lod 1`, 1 spp | RMSE `--lod 1`, 16 spp |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for key in benchdoc.chosen(args.only, ["shell", "enzo"]):
        got = measure(sets[key], args.size, args.runs)
        s0, s1 = (np.median(got["seconds"][lod]) for lod in (0, 1))
        r = got["rmse"]
        print(f"| {sets[key].name} | {s0:.3f} | {s1:.3f} | {got['samples'][0]:,} → {got['samples'][1]:,} "
              f"| {got['regions'][0]:,} / {got['regions'][1]:,} | {r['0']:.4f} | {r['1']:.4f} "
              f"| {r['1 at 16 spp']:.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
