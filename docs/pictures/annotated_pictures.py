"""The pictures of docs/annotate.md: annotated renders of the Gerris plume.

    .venv/bin/python docs/pictures/annotated_pictures.py [--big 4096] [--only NAME ...]

Writes into docs/images/annotated/:

- plume-volume-dark.png: the temperature as a volume (the gallery's view and
  transfer function), its colour bar with the opacity curve, 512².
- plume-scene-dark.png, plume-scene-light.png: docs/examples/plume-scene.json (a
  volume, an iso-surface coloured by W, one of a fixed colour, a slice of V),
  with a title and the time, over a dark and a light background, 512².
- plume-scene-big.png and plume-scene-big-crop.png: the same scene at --big²
  pixels (default 4096), scaled down to 1024 wide, and a 1024² piece of it as
  drawn, from the first colour bar's caption.

The Gerris cells record no time; the pictures state t = 1, the time of the
output (shared/data/README.md), as a caller passes what the source leaves out.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

import exabricks as eb
from exabricks.film.annotate import annotate
from exabricks.film.layout import annotation_layout

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images" / "annotated"
PLUME = ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells"
SCENE = ROOT / "docs" / "examples" / "plume-scene.json"
FACTS = {"time": 1.0}
TITLE = "Gerris buoyant plume"
LIGHT = (0.96, 0.96, 0.94)
VOLUME = {"position": (129, 63, 148), "look_at": (64, 33, 64), "up": (0, 1, 0), "fovy": 30,
          "field": "T", "colormap": "inferno", "range": (0, 0.6), "opacity": (0, 0.05, 0.15, 0.3),
          "background": (0.0, 0.0, 0.0)}


def save(picture: np.ndarray, name: str) -> None:
    Image.fromarray(picture, "RGBA").convert("RGB").save(OUT / name, optimize=True)
    print(OUT / name, f"{picture.shape[1]}x{picture.shape[0]}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--big", type=int, default=4096)
    parser.add_argument("--only", nargs="*", choices=("volume", "dark", "light", "big"))
    args = parser.parse_args(argv)
    only = set(args.only or ("volume", "dark", "light", "big"))
    OUT.mkdir(parents=True, exist_ok=True)
    renderer = eb.Renderer(eb.open(PLUME, cache=False))
    if "volume" in only:
        scene = renderer.scene(**VOLUME, size=(512, 512))
        save(annotate(renderer.render(scene).rgba, scene, title="Gerris plume, temperature"),
             "plume-volume-dark.png")
    for name, background in (("dark", None), ("light", LIGHT)):
        if name in only:
            scene = renderer.scene(SCENE, **({"background": background} if background else {}))
            save(annotate(renderer.render(scene).rgba, scene, facts=FACTS, title=TITLE),
                 f"plume-scene-{name}.png")
    if "big" in only:
        scene = renderer.scene(SCENE, size=(args.big, args.big), spp=1)
        big = annotate(renderer.render(scene).rgba, scene, facts=FACTS, title=TITLE)
        small = Image.fromarray(big, "RGBA").convert("RGB")
        small = small.resize((1024, round(small.height * 1024 / small.width)), Image.LANCZOS)
        small.save(OUT / "plume-scene-big.png", optimize=True)
        print(OUT / "plume-scene-big.png", f"{big.shape[1]}x{big.shape[0]} scaled to 1024 wide")
        layout = annotation_layout((args.big, args.big), scene, facts=FACTS, title=TITLE)
        bar = layout.bars[0].box  # from the caption above the first bar
        top = max(0, round(bar.y - 3.5 * layout.font_px))
        left = min(max(0, bar.x - round(layout.font_px)), big.shape[1] - 1024)
        save(np.ascontiguousarray(big[top:top + 1024, left:left + 1024]),
             "plume-scene-big-crop.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
