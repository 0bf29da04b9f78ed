"""What an iso-surface adds to a path-traced frame on PoCL (issue 62, item 2).

    .venv/bin/python -m benchmarks.bench_path_surfaces [--runs N] [--size N] [--spp N] [--only KEY] [--write-docs]

Each dataset is opened as `render SOURCE` opens it, with the field of benchdoc;
one Renderer draws its default scene under `--integrator path` at SIZE² and SPP
samples per pixel, without and with one opaque iso-surface at the field's 97th
percentile (a closed surface about the densest features), the two frames in turn
after one warm-up each (its kernel build). An iso-surface does add work a path
must do: a path that meets it is shaded there (a shadow ray toward the light, a
bounce), where without it most paths leave the translucent medium unscattered.
What issue 62 asks to remove is the search: iso crossings are looked for only in
the regions whose value range brackets the iso-value (the visibility flags'
SEEN_ISO bit), and only before the medium's collision. Median and min-max over
the runs; "ratio" is with / without, frame by frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks import benchdoc

TITLE = "Path integrator with an iso-surface (PoCL)"
PERCENTILE = 97


def measure(dataset, runs: int, size: int, spp: int) -> dict:
    import exabricks as eb

    ds = eb.open(dataset.path, fields=[dataset.field], **({"format": "yt"} if dataset.key == "enzo" else {}))
    r = eb.Renderer(ds)
    iso = float(np.percentile(ds.bricks.values[0], PERCENTILE))
    options = dict(field=dataset.field, size=(size, size), spp=spp, integrator="path")
    scenes = {"without": r.scene(**options), "with": r.scene(**options, iso=[iso])}
    engine = r._on_device(scenes["without"].fields())
    seconds = {name: [] for name in scenes}
    for k in range(runs + 1):
        for name, scene in scenes.items():
            started = time.perf_counter()
            engine.render_scene(scene)
            if k:  # the first round builds
                seconds[name].append(time.perf_counter() - started)
    return {"iso": iso, **seconds}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=3)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--spp", type=int, default=4)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    rows = []
    for key in benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"]):
        got = measure(sets[key], args.runs, args.size, args.spp)
        ratios = [b / a for a, b in zip(got["without"], got["with"])]
        rows.append(f"| {sets[key].name} | {got['iso']:.4g} | {benchdoc.fmt_spread(got['without'])} "
                    f"| {benchdoc.fmt_spread(got['with'])} | {benchdoc.fmt_spread(ratios, unit='x', digits=2)} |")
        print(rows[-1], flush=True)
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_path_surfaces --runs {args.runs} "
            f"--size {args.size} --spp {args.spp}`.", "",
            "| dataset | iso-value | s / frame without | s / frame with | ratio |",
            "|---|---:|---:|---:|---:|", *rows]
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
