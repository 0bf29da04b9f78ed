"""Picture of a build by pieces (docs/workflows.md, "One large dataset
preprocessed in pieces"): which piece built each brick, beside the plume
rendered from the joined files.

    .venv/bin/python docs/pictures/build_pieces_picture.py [--pieces 4] [--size 480 360]

Runs `exabricks brick --piece K/N` for every K on the embedded Gerris plume,
`exabricks join`, then `regions` and `bvh`, all as commands, and checks that the
joined bricks equal `exabricks brick` in one process. Writes
docs/images/workflow-build-pieces-T.png (field T, the gallery's camera and
transfer function) and docs/images/workflow-build-pieces.png: the same bricks
with each cell's value replaced by the index of the piece that built it (tab10
colours, nearest-cell reconstruction so that pieces stay crisp).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from benchmarks import benchdoc
from benchmarks.gallery import G_CAM, G_TF, _f

ROOT = Path(__file__).resolve().parents[1]


GERRIS = ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells"
IMAGES = ROOT / "docs" / "images"
OPACITY = 0.02  # per unit distance (the finest cell): the cut shows through the box


def main(argv=None) -> int:
    from exabricks import schema

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pieces", type=int, default=4)
    p.add_argument("--size", type=int, nargs=2, default=(480, 360))
    args = p.parse_args(argv)
    eb = [*benchdoc.exabricks_command(), "-q"]
    n = args.pieces

    def run(*a):
        subprocess.run([*eb, *map(str, a)], check=True)

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        run("ingest", GERRIS, "-o", d / "cells.npz")
        run("brick", d / "cells.npz", "-o", d / "whole.npz")
        for k in range(n):
            run("brick", d / "cells.npz", "--piece", f"{k}/{n}", "-o", d / f"bricks.{k}.npz")
        run("join", *[d / f"bricks.{k}.npz" for k in range(n)], "-o", d / "bricks.npz")
        whole, joined = schema.load(d / "whole.npz"), schema.load(d / "bricks.npz")
        same = all(np.array_equal(v, joined.arrays()[k]) for k, v in whole.arrays().items())
        print(f"joined bricks equal the one-process bricks: {same}")
        if not same:
            return 1
        # The same bricks, each cell's value the index of the piece that built it.
        owner = np.concatenate([np.full(schema.load(d / f"bricks.{k}.npz").values.shape[1], k,
                                        np.float32) for k in range(n)])
        schema.save(d / "owner_bricks.npz", joined.replace(fields=("piece",), values=owner[None]))
        size = ["--size", *args.size]
        for name, src, flags in (
                ("workflow-build-pieces-T.png", "bricks", [*_f(G_CAM), *_f(G_TF)]),
                # render's default three-quarter view of the whole box
                ("workflow-build-pieces.png", "owner_bricks",
                 ["--field", "piece", "--colormap", "tab10", "--range", 0, 9, "--opacity",
                  f"{OPACITY},{OPACITY}", "--reconstruction", "nearest"])):
            run("regions", d / f"{src}.npz", "-o", d / f"{src}_regions.npz")
            run("bvh", d / f"{src}_regions.npz", "-o", d / f"{src}_bvh.npz")
            run("render", d / f"{src}.npz", d / f"{src}_regions.npz", d / f"{src}_bvh.npz",
                *flags, *size, "--background", "0.05,0.05,0.08", "-o", IMAGES / name)
            print(f"wrote {IMAGES / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
