"""Pictures of a frame under a memory budget (docs/design-scale.md, "Rendering under a
memory budget"): the image so far after a quarter, half and all of the domains of
the first sample, and the final average of every sample, as `render
--progressive` rewrites it.

    .venv/bin/python docs/pictures/progressive_picture.py [--domains 8] [--size 320]

Runs exabricks.engine.streaming in one process on the Athena++ blast (rho, the
camera and transfer function of docs/pictures/domains_picture.py, default early ray
termination) with a budget that holds at most 1/--domains of the data per domain.
Writes docs/images/budget-progress.png (the four images side by side, over the
dark background) and prints the domains, what each image covers, and the RMSE of
the final image against the in-memory frame.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from benchmarks import benchdoc
from benchmarks.bench_render import ensure_scene
from domains_picture import BACKGROUND, CAMERA

ROOT = Path(__file__).resolve().parents[1]


FLAGS = dict(field="rho", colormap="viridis", range=(1.0, 2.7), opacity=(0.0, 0.02, 0.2, 0.5))


def main(argv=None) -> int:
    from exabricks import schema
    from exabricks.film.image_io import write_image
    from exabricks.scene import scene_from_options
    from exabricks.engine.domains import domain_plan, domain_bytes
    from exabricks.engine.renderer import Renderer
    from exabricks.film.film import over_background
    from exabricks.engine.streaming import PER_BRICK, SLACK, Budgeted, image_bytes, render_steps

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domains", type=int, default=8)
    parser.add_argument("--size", type=int, default=320)
    parser.add_argument("--spp", type=int, default=4)
    args = parser.parse_args(argv)
    d = ensure_scene(ROOT / "bench-data" / "render", benchdoc.datasets()["athena"])
    bricks, regions, bvh = (schema.load(d / f"{n}.npz") for n in ("bricks", "regions", "bvh"))
    scene = scene_from_options(bricks, flags={**FLAGS, **CAMERA, "size": (args.size, args.size),
                                              "spp": args.spp})
    whole = Renderer(bricks, regions, bvh, fields=scene.fields()).render_scene(scene).rgba
    plan = domain_plan(bricks, regions, [-np.inf] * 3, [np.inf] * 3, 0.0, True, ("b", "r"))
    budget = int(image_bytes(scene) + PER_BRICK * bricks.n_bricks
                 + SLACK * domain_bytes(bricks, regions, plan, scene.fields()) / args.domains)
    domains = Budgeted(bricks, regions, scene, budget)
    n = domains.n_domains
    wanted = {(0, max(1, n // 4)), (0, max(1, n // 2)), (0, n)}
    shots = []

    def on_image(rgba, progress):
        key = (progress["samples"][0], progress["pieces"][0])
        if key in wanted:
            shots.append((rgba.copy(), progress))

    final = render_steps(domains, scene, on_image=on_image)
    shots.append((final.rgba, final.stats["progress"]))
    for _, progress in shots:
        print(progress)
    strip = np.concatenate([over_background(img.copy(), BACKGROUND) for img, _ in shots], axis=1)
    out = ROOT / "docs" / "images" / "budget-progress.png"
    write_image(out, strip, metadata={})
    rmse = float(np.sqrt(np.mean((final.rgba - whole) ** 2))) / float(np.abs(whole).max())
    print(f"{n} domains in a budget of {budget:,} bytes -> {out}; RMSE against in memory {rmse:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
