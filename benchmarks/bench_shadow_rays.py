"""Shadow rays: exact integration against ratio tracking at equal error, on real data
against the float64 reference (docs/design-rendering.md, "Lights and shadows";
issue 52).

    .venv/bin/python -m benchmarks.bench_shadow_rays [--size N] [--frames K] [--write-docs]

The scene is the shadow and path integrators' real-data test
(tests/helpers/plume_core.py): the Gerris plume's hot core lit from the side,
single scattering, no ambient term, whose expected frame is the float64
reference of tests/reference.py (16 steps a finest cell along the camera ray, 8
toward the light). Three estimators of it:

* the shadow integrator: the camera ray and its shadow rays integrated exactly
  (one quadrature step per region's finest cell / sampling rate), deterministic:
  its error is its quadrature's, and falls with the sampling rate;
* the path integrator at one bounce, its shadow rays by ratio tracking through
  the majorant grid (the default);
* the same, its shadow rays integrated exactly as the shadow integrator's are
  (`-DEB_PATH_QUADRATURE`, built here only).

The two path estimators share delta tracking along the camera ray, so they
differ only in the shadow rays. Each draws K one-spp frames of independent
seeds; its error at N samples per pixel is sqrt(bias^2 + variance / N), the
bias and the variance per sample fitted over the pixels' means of N = 1 .. K
frames. Time per sample is the median frame's. The time to a relative RMSE E
is then (variance / (E^2 - bias^2)) x time per sample (infinite where the bias
alone exceeds E); the shadow integrator's is the time of the lowest sampling
rate whose frame is within E.
"""

from __future__ import annotations

import argparse
import functools
import time
from dataclasses import replace

import numpy as np

from benchmarks import benchdoc

TITLE = "Shadow rays: exact integration and ratio tracking (PoCL)"
RATES = (0.5, 1.0, 2.0, 4.0, 8.0)
TARGETS = (0.05, 0.02, 0.01)


def scene_and_reference(size: int):
    reference = benchdoc.tests_module("reference")
    plume_core = benchdoc.tests_module("helpers.plume_core").plume_core

    from exabricks.scene import Lighting, Scene, Settings, VolumeLayer

    core = plume_core()
    light = np.asarray(core.light) / np.linalg.norm(core.light)
    scene = Scene(camera=core.camera, volumes=(VolumeLayer("T", core.tf),),
                  lighting=Lighting(integrator="path", light=core.light, ambient=0.0,
                                    light_intensity=0.8, bounces=1),
                  settings=Settings(width=size, height=size, unit_distance=core.unit))
    want = reference.integrate(core.built.cells, core.camera, core.tf, size, size, "T",
                               steps_per_finest_cell=16, unit_distance=core.unit,
                               light=(light, 0.0, (0.8, 0.8, 0.8)), shadow_steps_per_finest_cell=8)
    return core.built, scene, want


def relative_rmse(frame, want, seen) -> float:
    return float(np.sqrt(np.mean((frame[..., :3] - want[..., :3])[seen] ** 2))
                 / np.mean(want[..., :3][seen]))


def path_estimator(renderer, scene, want, seen, k: int) -> dict:
    """K one-spp frames: time per sample, bias and variance per sample (relative)."""
    times, frames = [], []
    renderer.render_scene(scene)  # the build
    for seed in range(k):
        started = time.perf_counter()
        frames.append(renderer.render_scene(scene.replace(settings=replace(scene.settings, seed=seed))).rgba)
        times.append(time.perf_counter() - started)
    frames = np.stack(frames).astype(np.float64)
    scale = np.mean(want[..., :3][seen])
    ns, mse = [], []
    n = 1
    while n <= k // 4:
        groups = frames[: k // n * n].reshape(k // n, n, *frames.shape[1:]).mean(axis=1)
        mse.append(np.mean([np.mean((g[..., :3] - want[..., :3])[seen] ** 2) for g in groups]) / scale ** 2)
        ns.append(n)
        n *= 2
    # mse(N) = bias^2 + variance / N, least squares over the N measured
    a = np.column_stack([np.ones(len(ns)), 1.0 / np.asarray(ns, float)])
    (bias2, variance), *_ = np.linalg.lstsq(a, np.asarray(mse), rcond=None)
    return {"seconds": float(np.median(times)), "bias": float(np.sqrt(max(bias2, 0.0))),
            "variance": float(max(variance, 0.0)), "rmse_1": float(np.sqrt(mse[0])),
            "rmse_all": relative_rmse(frames.mean(axis=0), want, seen)}


def time_to(est: dict, target: float) -> float:
    left = target ** 2 - est["bias"] ** 2
    return est["variance"] / left * est["seconds"] if left > 0 else float("inf")


def main(argv=None) -> int:
    from exabricks.engine.renderer import Renderer

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=1)
    parser.add_argument("--size", type=int, default=32)
    parser.add_argument("--frames", type=int, default=64)
    args = parser.parse_args(argv)
    built, scene, want = scene_and_reference(args.size)
    seen = want[..., 3] > 0.01
    renderer = Renderer(built.bricks, built.regions, built.bvh, field="T")

    rows = []
    shadow = scene.replace(lighting=replace(scene.lighting, integrator="shadow"))
    exact = {}
    for rate in RATES:
        s = shadow.replace(settings=replace(shadow.settings, sampling_rate=rate, jitter=False))
        renderer.render_scene(s)
        started = time.perf_counter()
        frame = renderer.render_scene(s).rgba
        seconds = time.perf_counter() - started
        exact[rate] = (seconds, relative_rmse(frame, want, seen))
        rows.append(f"| shadow integrator, sampling rate {rate:g} | {seconds:.3f} | – | "
                    f"{exact[rate][1] * 100:.2f} % | – | "
                    + " | ".join(f"{seconds:.2f}" if exact[rate][1] <= e else "–" for e in TARGETS) + " |")
        print(rows[-1], flush=True)

    estimators = {}
    for label, extra in (("path, 1 bounce, shadow rays by ratio tracking", ()),
                         ("path, 1 bounce, shadow rays integrated exactly", ("EB_PATH_QUADRATURE",))):
        renderer._kernel = functools.partial(Renderer._kernel, renderer, extra=extra)
        est = path_estimator(renderer, scene, want, seen, args.frames)
        estimators[label] = est
        rows.append(f"| {label} | {est['seconds']:.3f} | {est['rmse_1'] * 100:.1f} % | "
                    f"{est['rmse_all'] * 100:.2f} % | {est['bias'] * 100:.2f} % / {np.sqrt(est['variance']) * 100:.1f} % | "
                    + " | ".join(f"{time_to(est, e):.2f}" for e in TARGETS) + " |")
        print(rows[-1], flush=True)
    del renderer._kernel
    ratio, quad = estimators.values()
    efficiency = (quad["variance"] * quad["seconds"]) / (ratio["variance"] * ratio["seconds"])
    print(f"ratio tracking / exact integration, samples per second x 1 / variance: {efficiency:.2f}")

    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_shadow_rays --size {args.size} "
            f"--frames {args.frames}`, {int(seen.sum())} pixels with data.", "",
            "| estimator | s / frame (1 spp) | relative RMSE at 1 spp | RMSE of the mean of all frames "
            "| bias / per-sample deviation | " + " | ".join(f"s to {e * 100:g} %" for e in TARGETS) + " |",
            "|---|---:|---:|---:|---:|" + "---:|" * len(TARGETS), *rows, "",
            f"Between the path estimators, ratio tracking's efficiency (1 / (variance x time)) is "
            f"{efficiency:.2f} times exact integration's."]
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
