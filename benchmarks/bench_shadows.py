"""The shadow integrator's cost on PoCL: each shared dataset's default picture under
the headlight and under `--integrator shadow` (docs/design-rendering.md, "Lights and
shadows"; issue 52).

    .venv/bin/python -m benchmarks.bench_shadows [--runs N] [--size N] [--only KEY] [--write-docs]

Each dataset is opened as `render SOURCE` opens it (the structures from the cache)
with the field of benchdoc; one Renderer draws the default scene at SIZE² and 1
sample per pixel, the integrators alternating frame by frame after one warm-up
frame each (its kernel build). "samples" are the primary ray's reconstructions
(the stats' samples); under the shadow integrator each lit sample also marches
a shadow ray, whose reconstructions are not counted, so "M samples/s" is
primary samples per second: the rate at which the frame itself advances. Median
and min-max over the runs.
"""

from __future__ import annotations

import argparse
import time

from benchmarks import benchdoc

TITLE = "Shadow integrator (PoCL)"
INTEGRATORS = ("headlight", "shadow")


def measure(dataset, runs: int, size: int) -> dict:
    import exabricks as eb

    ds = eb.open(dataset.path, fields=[dataset.field], **({"format": "yt"} if dataset.key == "enzo" else {}))
    renderer = eb.Renderer(ds)
    times = {i: [] for i in INTEGRATORS}
    samples = {}
    for run in range(runs + 1):
        for integrator in INTEGRATORS:
            started = time.perf_counter()
            image = renderer.render(field=dataset.field, size=(size, size), integrator=integrator)
            if run:
                times[integrator].append(time.perf_counter() - started)
            samples[integrator] = int(image.metadata["settings"].get("samples", 0))
    return {"times": times, "samples": samples}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=3)
    parser.add_argument("--size", type=int, default=256)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"])
    rows = []
    for key in keys:
        got = measure(sets[key], args.runs, args.size)
        t = {i: benchdoc.median_spread(got["times"][i])[0] for i in INTEGRATORS}
        print(key, {i: round(t[i], 3) for i in INTEGRATORS}, f"ratio {t['shadow'] / t['headlight']:.1f}", flush=True)
        rows.append((sets[key].name, got, t))
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_shadows --runs {args.runs} "
            f"--size {args.size}`.", "",
            "| dataset | headlight s | shadow s | shadow / headlight | samples | headlight M samples/s "
            "| shadow M samples/s |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, got, t in rows:
        n = got["samples"]["shadow"]
        body.append(f"| {name} | {benchdoc.fmt_spread(got['times']['headlight'], unit='')} | "
                    f"{benchdoc.fmt_spread(got['times']['shadow'], unit='')} | {t['shadow'] / t['headlight']:.1f} | "
                    f"{n:,} | {got['samples']['headlight'] / t['headlight'] / 1e6:.1f} | {n / t['shadow'] / 1e6:.2f} |")
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
