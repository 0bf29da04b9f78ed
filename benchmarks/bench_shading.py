"""Volume shading: the high-frequency energy the headlight adds to the default
picture of each real dataset over `--shading none` (docs/design-rendering.md, "Volume
shading"; issue 48).

    .venv/bin/python -m benchmarks.bench_shading [--before "CMD ..."] [--write-docs]

For each dataset (benchmarks.first_picture.DATASETS) both pictures are drawn
with the same scene (the default one, saved by the first render and given to
the second with --scene, so the transfer function and camera are the same).
The figure is the RMS of (L - blur(L)) - (L0 - blur(L0)) over the covered
pixels of the unshaded picture, divided by their mean luminance, where L is
the shaded picture's luminance, L0 the unshaded one's and blur a Gaussian of
sigma 2 pixels; and the mean luminance ratio (how much the headlight darkens).
--before measures another build beside this one (a checkout of an older
commit: "env PYTHONPATH=/path/to/checkout .venv/bin/python -m
exabricks.cli.main", with PYTHONSAFEPATH=1 so that the working directory does not come first); its own default pictures are measured, whatever they
show.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.first_picture import COVERED, DATASETS, SHARED, luminance

TITLE = "Volume shading"


def blur(image: np.ndarray, sigma: float = 2.0) -> np.ndarray:
    """A separable Gaussian blur of a 2-D array (edges repeated)."""
    radius = int(3 * sigma)
    x = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel /= kernel.sum()
    padded = np.pad(image, radius, mode="edge")
    rows = np.apply_along_axis(lambda r: np.convolve(r, kernel, "valid"), 1, padded)
    return np.apply_along_axis(lambda c: np.convolve(c, kernel, "valid"), 0, rows)


def added_detail(shaded: np.ndarray, flat: np.ndarray) -> tuple[float, float]:
    """(high-frequency energy added, mean luminance ratio) of two RGB(A) pictures."""
    lum, base = luminance(shaded), luminance(flat)
    covered = base > COVERED
    detail = (lum - blur(lum)) - (base - blur(base))
    return (float(np.sqrt(np.mean(detail[covered] ** 2)) / base[covered].mean()),
            float(lum[covered].mean() / base[covered].mean()))


def measure(command: list[str], work: Path) -> dict:
    from PIL import Image

    out = {}
    for name, (source, field) in DATASETS.items():
        shaded, flat, scene = work / f"{name}.png", work / f"{name}-none.png", work / f"{name}.json"
        subprocess.run([*command, "render", str(SHARED / source), *field, "--no-cache",
                        "-o", str(shaded)], check=True)
        from exabricks.film.image_io import read_image

        doc = read_image(shaded)[1]["scene"]
        doc.pop("transparent", None)  # older builds know no such key
        scene.write_text(json.dumps(doc))
        subprocess.run([*command, "render", str(SHARED / source), *field, "--no-cache",
                        "--scene", str(scene), "--shading", "none", "-o", str(flat)], check=True)
        pictures = [np.asarray(Image.open(p).convert("RGBA"), np.float64) for p in (shaded, flat)]
        # over black, as a notebook shows a transparent PNG of an older build
        rgb = [np.clip(p[..., :3] * p[..., 3:] / 255.0, 0, 255) for p in pictures]
        out[name] = added_detail(*rgb)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", help="the command of another build to measure beside this one")
    parser.add_argument("--write-docs", action="store_true", help="replace the section of docs/benchmarks.md")
    args = parser.parse_args(argv)
    builds = {"now": benchdoc.exabricks_command()}
    if args.before:
        builds["before"] = shlex.split(args.before)
    figures = {}
    for key, command in builds.items():
        with tempfile.TemporaryDirectory() as tmp:
            figures[key] = measure(command, Path(tmp))
    head = " | ".join(f"{k}: detail added | {k}: luminance ratio" for k in builds)
    lines = [f"| dataset | {head} |", "|---" * (1 + 2 * len(builds)) + "|"]
    for name in DATASETS:
        cells = " | ".join(f"{figures[k][name][0] * 100:.2f} % | {figures[k][name][1]:.3f}" for k in builds)
        lines.append(f"| {name} | {cells} |")
    body = "\n".join([
        "The detail (high-frequency energy: luminance minus its Gaussian blur, sigma 2 px) that "
        "the volume headlight adds to each dataset's default picture over `--shading none` with "
        "the same scene, relative to the mean luminance, and how much it darkens the picture "
        "(docs/design.md, \"Volume shading\"). \"before\" is b0682ec, where the headlight lit every "
        "sample by its normalised gradient; its default pictures differ (its own defaults).", "",
        "    .venv/bin/python -m benchmarks.bench_shading --before \"env PYTHONSAFEPATH=1 PYTHONPATH=CHECKOUT "
        ".venv/bin/python -m exabricks.cli.main\" --write-docs", "",
        f"{benchdoc.machine(opencl=True)}, 2026-12-06.", "", *lines])
    benchdoc.publish(TITLE, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
