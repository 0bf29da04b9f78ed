"""The picture of the shadow integrator (docs/gallery.md, "Lit from one side, with
shadows"; docs/design-rendering.md, "Lights and shadows"): each shared dataset's default
frame (the automatic transfer function, the default camera) under today's
headlight and under `--integrator shadow`, its default key light 35 degrees above
the view and 60 to its left, and then with an opaque iso-surface in the volume (the
plume's core of `make demo`, T = 0.45; the iso-values of docs/gallery.md's iso and
shell shots otherwise), whose shadow falls on itself and on the volume.

    .venv/bin/python docs/pictures/shadows_picture.py

Writes docs/images/shadows.png: one row per dataset (headlight, shadow, shadow with
the iso-surface), 320x320 each, 4 samples per pixel, and prints each frame's time.
"""

from __future__ import annotations

import io
import time
from pathlib import Path

from PIL import Image

import exabricks as eb

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images" / "shadows.png"
DATA = ROOT.parent / "shared" / "data"
SHOTS = (  # (source, field, an iso-value of the field's structure, open options)
    (ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells", "T", 0.45, {}),
    (DATA / "amrex-advection3d" / "plt00020", "phi", 1.5, {}),
    (DATA / "athena-blast3d" / "Blast.out2.00001.athdf", "rho", 1.5, {}),
    (DATA / "enzo-moving7" / "moving7_0010", "Density", 3.0, {"format": "yt"}),
)
SIZE = 320


def main() -> None:
    sheet = Image.new("RGB", (3 * SIZE, SIZE * len(SHOTS)))
    for row, (source, field, iso, options) in enumerate(SHOTS):
        renderer = eb.Renderer(eb.open(source, fields=[field], **options))
        for col, (integrator, more) in enumerate((("headlight", {}), ("shadow", {}), ("shadow", {"iso": iso}))):
            started = time.perf_counter()
            image = renderer.render(field=field, size=(SIZE, SIZE), spp=4, integrator=integrator, **more)
            print(f"{Path(source).name} {integrator}: {time.perf_counter() - started:.1f} s", flush=True)
            sheet.paste(Image.open(io.BytesIO(image._repr_png_())).convert("RGB"), (SIZE * col, SIZE * row))
    sheet.save(OUT)
    print(OUT)


if __name__ == "__main__":
    main()
