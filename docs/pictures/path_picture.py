"""The picture of the path integrator (docs/gallery.md, "Path-traced: light that
scatters"; docs/design-rendering.md, "Path tracing"): each shared dataset's default
frame (the automatic transfer function, the default camera, the default key light)
under `--integrator shadow` (single scattering, exactly integrated), and path-traced
with 8 scattering events, isotropic and forward-scattering (g = 0.6).

    .venv/bin/python docs/pictures/path_picture.py

Writes docs/images/path.png: one row per dataset (shadow, path, path with g = 0.6),
SIZE x SIZE each, the path-traced frames at SPP samples per pixel, and prints each
frame's time.
"""

from __future__ import annotations

import io
import time
from pathlib import Path

from PIL import Image

import exabricks as eb

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images" / "path.png"
DATA = ROOT.parent / "shared" / "data"
SHOTS = (  # (source, field, open options)
    (ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells", "T", {}),
    (DATA / "amrex-advection3d" / "plt00020", "phi", {}),
    (DATA / "athena-blast3d" / "Blast.out2.00001.athdf", "rho", {}),
    (DATA / "enzo-moving7" / "moving7_0010", "Density", {"format": "yt"}),
)
SIZE = 192
SPP = 64
COLUMNS = (("shadow", {"spp": 1}), ("path", {"spp": SPP}), ("path", {"spp": SPP, "anisotropy": 0.6}))


def main() -> None:
    sheet = Image.new("RGB", (len(COLUMNS) * SIZE, SIZE * len(SHOTS)))
    for row, (source, field, options) in enumerate(SHOTS):
        renderer = eb.Renderer(eb.open(source, fields=[field], **options))
        for col, (integrator, more) in enumerate(COLUMNS):
            started = time.perf_counter()
            image = renderer.render(field=field, size=(SIZE, SIZE), integrator=integrator, **more)
            print(f"{Path(source).name} {integrator} {more}: {time.perf_counter() - started:.1f} s", flush=True)
            sheet.paste(Image.open(io.BytesIO(image._repr_png_())).convert("RGB"), (SIZE * col, SIZE * row))
    sheet.save(OUT)
    print(OUT)


if __name__ == "__main__":
    main()
