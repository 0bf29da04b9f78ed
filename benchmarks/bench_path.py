"""The path integrator on PoCL: speed, the majorant grid's efficiency, and the time to a
stated noise level (docs/design-rendering.md, "Path tracing"; issue 52).

    .venv/bin/python -m benchmarks.bench_path [--size N] [--spp N] [--only KEY] [--write-docs]

Each dataset is opened as `render SOURCE` opens it, and its default scene is drawn
under `--integrator path` (default light, 8 bounces, isotropic) at SIZE². For
majorant grids of 16 to 128 macrocells along the longest axis (the grid is
remade, the bricks, regions and BVH are not): the seconds of an SPP frame, paths
(pixel samples) and reconstructions per second, and the real and null
collisions of the free paths (efficiency: real / (real + null), the share of
tentative collisions that scatter; ratio tracking's evaluations toward the
lights are counted apart). The noise: the RMSE of an SPP frame against a frame of
REFERENCE x SPP samples per pixel, relative to that frame's mean colour over its
drawn pixels (corrected for the reference's own noise, 1/REFERENCE of the
variance); the time to 2 % follows from 1/sqrt(N), which tests/engine/test_path.py
shows. Block-structured layouts (AMReX, Athena++) and octree-like ones (Gerris,
Enzo) side by side.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from benchmarks import benchdoc

TITLE = "Path integrator (PoCL)"
GRIDS = (16, 32, 64, 128)
REFERENCE = 8
NOISE = 0.02


def measure(dataset, size: int, spp: int) -> dict:
    import exabricks as eb
    from exabricks.engine.majorants import MACROCELLS, MacrocellGrid

    ds = eb.open(dataset.path, fields=[dataset.field], **({"format": "yt"} if dataset.key == "enzo" else {}))
    r = eb.Renderer(ds)
    scene = r.scene(field=dataset.field, size=(size, size), spp=spp, integrator="path")
    engine = r._on_device(scene.fields())
    bvh = engine.dataset.bvh
    out = {}
    for macrocells in GRIDS:
        engine._macrocells = {"grid": MacrocellGrid.over(bvh.lower_lattice[0], bvh.upper_lattice[0],
                                                         macrocells)}
        engine.render_scene(replace(scene, settings=replace(scene.settings, spp=1)))  # build, ranges
        started = time.perf_counter()
        result = engine.render_scene(scene)
        seconds = time.perf_counter() - started
        out[macrocells] = {"seconds": seconds, "stats": result.stats, "rgba": result.rgba}
    frame = out[MACROCELLS]["rgba"]
    engine._macrocells = {}
    reference = engine.render_scene(replace(scene, settings=replace(
        scene.settings, spp=REFERENCE * spp, seed=1))).rgba
    drawn = reference[..., 3] > 0.01
    mse = np.mean((frame[..., :3] - reference[..., :3])[drawn] ** 2) * REFERENCE / (REFERENCE + 1)
    noise = float(np.sqrt(mse) / np.mean(reference[..., :3][drawn]))
    return {"grids": out, "noise": noise, "pixels": size * size, "spp": spp}


def main(argv=None) -> int:
    from exabricks.engine.majorants import MACROCELLS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=1)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--spp", type=int, default=16)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"])
    rows, noise_rows = [], []
    for key in keys:
        got = measure(sets[key], args.size, args.spp)
        paths = got["pixels"] * got["spp"]
        for macrocells, g in got["grids"].items():
            c, s = g["stats"]["collisions"], g["seconds"]
            efficiency = c["real"] / max(1, c["real"] + c["null"])
            rows.append(f"| {sets[key].name} | {macrocells} ({'x'.join(map(str, g['stats']['macrocells']))}) "
                        f"| {s:.2f} | {paths / s / 1e6:.2f} | {g['stats']['samples'] / s / 1e6:.2f} "
                        f"| {c['real']:,} | {c['null']:,} | {efficiency:.2f} | {c['ratio']:,} |")
            print(rows[-1], flush=True)
        s = got["grids"][MACROCELLS]["seconds"]
        to_noise = s * (got["noise"] / NOISE) ** 2
        noise_rows.append(f"| {sets[key].name} | {got['noise'] * 100:.1f} % | {s:.2f} | "
                          f"{got['spp'] * (got['noise'] / NOISE) ** 2:,.0f} | {to_noise:.0f} |")
        print(noise_rows[-1], flush=True)
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_path --size {args.size} "
            f"--spp {args.spp}`.", "",
            "| dataset | macrocells (grid) | s / frame | M paths/s | M reconstructions/s | real collisions "
            "| null collisions | efficiency | ratio-tracking evaluations |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|", *rows, "",
            f"Noise at {args.spp} spp ({MACROCELLS} macrocells, the default) and the time to "
            f"{NOISE * 100:.0f} % at {args.size}²:", "",
            f"| dataset | relative RMSE at {args.spp} spp | s / frame | spp for {NOISE * 100:.0f} % "
            f"| s for {NOISE * 100:.0f} % |", "|---|---:|---:|---:|---:|", *noise_rows]
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
