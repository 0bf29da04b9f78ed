"""The shadow integrator's cost on PoCL: each shared dataset's default picture under
the headlight and under `--integrator shadow`, its transmittance toward the light
cached (the default) and traced (docs/design-rendering.md, "Lights and shadows";
issues 52 and 62).

    .venv/bin/python -m benchmarks.bench_shadows [--runs N] [--size N] [--only KEY] [--write-docs]

Each dataset is opened as `render SOURCE` opens it (the structures from the cache)
with the field of benchdoc; one Renderer draws the default scene at SIZE² and 1
sample per pixel after one warm-up frame of each kind (its kernel builds). Each
run draws, in turn: the headlight frame; the cached shadow frame with its
light-space volume built anew (the first frame after the light, the transfer
function or the data changed: "cached, built"); the same frame again, the volume
reused (every later frame, a camera change included: "cached"). Median and
min-max over the runs; "build" is the volume's share of the built frame. The
traced frame (a shadow ray from every lit sample) is drawn once, and "RMSE" is
the premultiplied RGBA of the cached frame against it.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks import benchdoc

TITLE = "Shadow integrator (PoCL)"
KINDS = ("headlight", "built", "cached")


def measure(dataset, runs: int, size: int) -> dict:
    import exabricks as eb

    ds = eb.open(dataset.path, fields=[dataset.field], **({"format": "yt"} if dataset.key == "enzo" else {}))
    api_renderer = eb.Renderer(ds)
    scenes = {"headlight": api_renderer.scene(field=dataset.field, size=(size, size)),
              "cached": api_renderer.scene(field=dataset.field, size=(size, size), integrator="shadow"),
              "traced": api_renderer.scene(field=dataset.field, size=(size, size), integrator="shadow",
                                           shadow_rays="traced")}
    renderer = api_renderer._on_device(scenes["headlight"].fields())

    def frame(kind):
        if kind == "built":
            renderer.light_cache.volume = None  # as after a change of light or transfer function
        started = time.perf_counter()
        result = renderer.integrate(scenes["cached" if kind == "built" else kind])
        return time.perf_counter() - started, result

    times, build = {k: [] for k in KINDS}, []
    for run in range(runs + 1):
        for kind in KINDS:
            seconds, result = frame(kind)
            if run:
                times[kind].append(seconds)
                if kind == "built":
                    build.append(result.stats["light_volume"]["ms"] / 1e3)
    cached = result
    traced_seconds, traced = frame("traced")
    rmse = float(np.sqrt(np.mean((cached.rgba.astype(np.float64) - traced.rgba) ** 2)))
    return {"times": times, "build": build, "traced": traced_seconds, "rmse": rmse,
            "nodes": cached.stats["light_volume"]["nodes"], "mib": cached.stats["light_volume"]["bytes"] / 2**20}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=3)
    parser.add_argument("--size", type=int, default=512)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"])
    rows = []
    for key in keys:
        got = measure(sets[key], args.runs, args.size)
        t = {k: benchdoc.median_spread(got["times"][k])[0] for k in KINDS}
        print(key, {k: round(t[k], 3) for k in KINDS}, f"traced {got['traced']:.2f}",
              f"built / headlight {t['built'] / t['headlight']:.2f}", f"rmse {got['rmse']:.2e}", flush=True)
        rows.append((sets[key].name, got, t))
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_shadows --runs {args.runs} "
            f"--size {args.size}`.", "",
            "| dataset | headlight s | cached, built s | build s | cached s | built / headlight "
            "| cached / headlight | traced s | traced / headlight | nodes | MiB | RMSE cached - traced |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|"]
    for name, got, t in rows:
        nodes = "x".join(str(n) for n in got["nodes"])
        body.append(f"| {name} | {benchdoc.fmt_spread(got['times']['headlight'], unit='')} | "
                    f"{benchdoc.fmt_spread(got['times']['built'], unit='')} | "
                    f"{benchdoc.median_spread(got['build'])[0]:.3f} | "
                    f"{benchdoc.fmt_spread(got['times']['cached'], unit='')} | "
                    f"{t['built'] / t['headlight']:.2f} | {t['cached'] / t['headlight']:.2f} | "
                    f"{got['traced']:.1f} | {got['traced'] / t['headlight']:.0f} | {nodes} | "
                    f"{got['mib']:.0f} | {got['rmse']:.1e} |")
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
