"""Pictures of a data-parallel frame (docs/workflows.md, "MPI"): what each rank's
domain renders, and their composite against the one-process frame.

    .venv/bin/python docs/pictures/domains_picture.py [--ranks 4] [--size 320]

Runs the domains in one process, exactly as `mpiexec -n N exabricks render` splits
them (exabricks.engine.partition: the k-d domains, each domain's cropped share,
its frame of the samples inside it), on the Athena++ blast (rho, the gallery's
camera and transfer function, no early termination). Writes
docs/images/workflow-domains-K.png (domain K alone, premultiplied over the dark
background) and docs/images/workflow-domains-composite.png, and prints the RMSE
of the composite against the one-process frame.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks.bench_render import ensure_scene

ROOT = Path(__file__).resolve().parents[1]


CAMERA = dict(position=(0.66, 0.46, 0.8), look_at=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fovy=30.0)
FLAGS = dict(field="rho", colormap="viridis", range=(1.0, 2.7), opacity=(0.0, 0.02, 0.2, 0.5),
             max_opacity=1.0)
BACKGROUND = (0.05, 0.05, 0.08, 1.0)


def main(argv=None) -> int:
    from exabricks import schema
    from exabricks.film.image_io import write_image
    from exabricks.scene import scene_from_options
    from exabricks.engine.device_data import DatasetScale
    from exabricks.engine.partition import composite, eye_lattice, kd_partition
    from exabricks.engine.domains import domain_data, domain_options
    from exabricks.engine.renderer import Renderer
    from exabricks.film.film import over_background

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ranks", type=int, default=4)
    parser.add_argument("--size", type=int, default=320)
    args = parser.parse_args(argv)
    d = ensure_scene(ROOT / "bench-data" / "render", benchdoc.datasets()["athena"])
    bricks, regions, bvh = (schema.load(d / f"{n}.npz") for n in ("bricks", "regions", "bvh"))
    scene = scene_from_options(bricks, flags={**FLAGS, **CAMERA, "size": (args.size, args.size)})
    scene = scene.replace(settings=dataclasses.replace(scene.settings, max_opacity=1.0))
    whole = Renderer(bricks, regions, bvh, fields=scene.fields()).render_scene(scene).rgba
    part = kd_partition(bricks, regions, args.ranks)
    scale = DatasetScale.of(bricks, scene.fields())
    images = []
    for k in range(args.ranks):
        box = (part.lower[k], part.upper[k])
        domain = domain_data(bricks, regions, *box, **domain_options(bricks, scene))
        images.append(Renderer(*domain, fields=scene.fields(), domain=box, scale=scale)
                      .render_scene(scene).rgba)
        out = ROOT / "docs" / "images" / f"workflow-domains-{k}.png"
        write_image(out, over_background(images[-1].copy(), BACKGROUND), metadata={})
        print(f"domain {k}: {domain[0].n_bricks:,} bricks, {domain[1].n_regions:,} regions -> {out}")
    order = part.visibility_order(eye_lattice(bricks, scene.camera.position))
    over = images[order[0]].copy()
    for k in order[1:]:
        composite(over, images[k])
    rmse = float(np.sqrt(np.mean((over - whole) ** 2))) / float(np.abs(whole).max())
    out = ROOT / "docs" / "images" / "workflow-domains-composite.png"
    write_image(out, over_background(over, BACKGROUND), metadata={})
    print(f"visibility order {order}; composite -> {out}; RMSE against one process {rmse:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
