"""Noise: how far the default frame (one sample per pixel) is from a converged
one, and how it converges with --spp (docs/design-rendering.md, "Sample offsets";
issue 48, item 3).

    .venv/bin/python -m benchmarks.bench_noise [--before CHECKOUT] [--reference-spp 256] [--write-docs]

For each real dataset (benchmarks.first_picture.DATASETS) the default scene
(the automatic transfer function and framing camera, 512 x 512) is drawn by
this build at --reference-spp samples per pixel: the converged frame. Then each
build (this one, and with --before another checkout's exabricks, whose sample
offsets differ) draws the same scene at 1, 4 and 16 samples per pixel; the
figures are the RMSE of the premultiplied RGB against the converged frame,
plain and after a Gaussian blur of sigma 1 pixel on both (what a viewer's
eye or a downscaled copy sees of the noise). (Frame times are measured apart,
each build in turn: a shared machine's load moves them more than the offsets do.)
The measurement runs in a child process per build (this file run as a script,
with the build first on PYTHONPATH).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SPPS = (1, 4, 16)


def _blur(a: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """(H, W, C) blurred by a Gaussian of `sigma` pixels (edges repeated)."""
    radius = int(3 * sigma)
    k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    k /= k.sum()
    for axis in (0, 1):
        pad = [(0, 0)] * 3
        pad[axis] = (radius, radius)
        p = np.pad(a, pad, mode="edge")
        n = a.shape[axis]
        a = sum(w * np.take(p, np.arange(i, i + n), axis=axis) for i, w in enumerate(k))
    return a


def _measure(spec: dict) -> dict:
    """In the child: render the scenes of `spec` and return the figures."""
    from dataclasses import replace

    import exabricks as eb

    out = {}
    for name, (source, _, scene_file) in spec["datasets"].items():
        ds = eb.open(source, cache=spec["cache"])
        renderer = eb.Renderer(ds)
        base = renderer.scene(scene_file)
        frames = {}
        for spp in spec["spps"]:
            scene = base.replace(settings=replace(base.settings, spp=spp))
            renderer.render(scene)  # warm
            t = time.perf_counter()
            image = renderer.render(scene)
            frames[spp] = (image.rgba[..., :3].astype(np.float64), time.perf_counter() - t)
        out[name] = frames
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, help="a checkout of another build to measure beside this one")
    parser.add_argument("--reference-spp", type=int, default=256)
    parser.add_argument("--write-docs", action="store_true")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        spec = json.loads(Path(args.child).read_text())
        result = _measure(spec)
        np.savez(spec["out"], **{f"{n}-{spp}": rgb for n, fr in result.items() for spp, (rgb, _) in fr.items()},
                 **{f"{n}-{spp}-s": np.array(s) for n, fr in result.items() for spp, (_, s) in fr.items()})
        return 0

    from benchmarks import benchdoc
    from benchmarks.first_picture import DATASETS, SHARED

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        datasets = {}
        for name, (source, field) in DATASETS.items():
            png = tmp / f"{name}.png"
            subprocess.run([*benchdoc.exabricks_command(), "render", str(SHARED / source), *field,
                            "--cache", str(tmp / "cache"), "-o", str(png)], check=True)
            from exabricks.film.image_io import read_image

            doc = read_image(png)[1]["scene"]
            doc.pop("transparent", None)
            (tmp / f"{name}.json").write_text(json.dumps(doc))
            datasets[name] = (str(SHARED / source), field, str(tmp / f"{name}.json"))

        def run(build: Path, spps, key):
            spec = {"datasets": datasets, "spps": list(spps), "cache": str(tmp / f"cache-{key}"),
                    "out": str(tmp / f"{key}.npz")}
            (tmp / f"{key}.json").write_text(json.dumps(spec))
            env = {**os.environ, "PYTHONSAFEPATH": "1", "PYTHONPATH": str(build)}
            subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(tmp / f"{key}.json")],
                           check=True, env=env)
            return np.load(tmp / f"{key}.npz")

        reference = run(ROOT, [args.reference_spp], "reference")
        builds = {"now": run(ROOT, SPPS, "now")}
        if args.before:
            builds["before"] = run(args.before, SPPS, "before")
        lines = ["| dataset | build | " + " | ".join(f"RMSE {s} spp (blurred)" for s in SPPS) + " |",
                 "|---|---|" + "---|" * len(SPPS)]
        for name in DATASETS:
            ref = reference[f"{name}-{args.reference_spp}"]
            ref_blur = _blur(ref)
            for key, frames in builds.items():
                cells = []
                for spp in SPPS:
                    rgb = frames[f"{name}-{spp}"]
                    rmse = float(np.sqrt(np.mean((rgb - ref) ** 2)))
                    blurred = float(np.sqrt(np.mean((_blur(rgb) - ref_blur) ** 2)))
                    cells.append(f"{rmse:.2e} ({blurred:.2e})")
                lines.append(f"| {name} | {key} | " + " | ".join(cells) + " |")
    body = "\n".join([
        "How far a frame is from the converged one (the same scene at "
        f"{args.reference_spp} samples per pixel): the RMSE of the premultiplied RGB, and in "
        "brackets after a Gaussian blur of sigma 1 pixel on both (what the eye and a downscaled "
        "copy see of the noise), for each dataset's default scene at 512 x 512 (docs/design.md, "
        "\"Sample offsets\").", "",
        "    .venv/bin/python -m benchmarks.bench_noise --before CHECKOUT --write-docs", "",
        f"{benchdoc.machine(opencl=True)}.", "", *lines])
    benchdoc.publish("Noise against a converged frame", body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
