"""A poster drawn tile by tile (docs/workflows.md, "Data larger than memory"):
the whole frame scaled down beside a crop of it at full resolution.

    .venv/bin/python docs/pictures/poster_picture.py [--size 2048] [--crop 512]

Renders the Athena++ blast (rho, the camera and transfer function of
docs/pictures/progressive_picture.py) as one `exabricks render --tile 512 64
--memory-budget 12MiB` command of --size² pixels, over the pictures' dark
background, then writes docs/images/poster.png: the frame scaled down to
--crop² by averaging, and the --crop² pixels around its centre as drawn.
Prints the command's domains, bands and peak memory.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from benchmarks import benchdoc
from benchmarks.bench_render import ensure_scene
from domains_picture import BACKGROUND, CAMERA
from progressive_picture import FLAGS

ROOT = Path(__file__).resolve().parents[1]



def main(argv=None) -> int:
    from exabricks.film.image_io import read_image, write_image

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--crop", type=int, default=512)
    args = parser.parse_args(argv)
    d = ensure_scene(ROOT / "bench-data" / "render", benchdoc.datasets()["athena"])
    files = [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]
    flags = ["--field", FLAGS["field"], "--colormap", FLAGS["colormap"],
             "--range", *FLAGS["range"], "--opacity", ",".join(map(str, FLAGS["opacity"])),
             "--position", *CAMERA["position"], "--look-at", *CAMERA["look_at"],
             "--up", *CAMERA["up"], "--fovy", CAMERA["fovy"],
             "--background", ",".join(map(str, BACKGROUND[:3])),
             "--size", args.size, args.size, "--tile", 512, 64, "--memory-budget", "12MiB"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "poster.png"
        wall, _, peak = benchdoc.run_child([*benchdoc.exabricks_command(), "render", *files,
                                            "-o", out, *flags])
        rgba, meta = read_image(out)
    k = args.size // args.crop
    small = rgba.reshape(args.crop, k, args.crop, k, 4).mean(axis=(1, 3))
    c = (args.size - args.crop) // 2
    crop = rgba[c:c + args.crop, c:c + args.crop]
    gap = np.ones((args.crop, 8, 4), np.float32)
    write_image(ROOT / "docs" / "images" / "poster.png",
                np.concatenate([small, gap, crop], axis=1), metadata={})
    s = meta["settings"]
    print(f"{args.size}² in tiles {s['tile']}: {s['pieces']} domains, {wall:.1f} s, peak "
          f"{benchdoc.fmt_bytes(peak)} -> docs/images/poster.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
