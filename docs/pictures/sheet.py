"""What the gallery's comparison sheets share (shadows_picture.py, path_picture.py):
each shared dataset's default frame, one row per dataset and one column per way of
rendering it, pasted into one PNG."""

from __future__ import annotations

import io
import time
from pathlib import Path

from PIL import Image

import exabricks as eb

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
GERRIS = ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells"
AMREX = DATA / "amrex-advection3d" / "plt00020"
DATASETS = (  # (source, field, open options)
    (GERRIS, "T", {}),
    (AMREX, "phi", {}),
    (DATA / "athena-blast3d" / "Blast.out2.00001.athdf", "rho", {}),
    (DATA / "enzo-moving7" / "moving7_0010", "Density", {"format": "yt"}),
)
# per dataset, an iso-value of its structure: the plume's core of `make demo`, else
# the iso-values of docs/gallery.md's iso and shell shots
ISO = (0.45, 1.5, 1.5, 3.0)


def render_sheet(out: Path, size: int, columns) -> None:
    """The sheet at `out`: row i is DATASETS[i] as each (label, eb.Renderer.render
    keywords) of columns(i) renders it, size x size; prints each frame's time."""
    cells = [columns(row) for row in range(len(DATASETS))]
    sheet = Image.new("RGB", (size * len(cells[0]), size * len(DATASETS)))
    for row, ((source, field, options), shots) in enumerate(zip(DATASETS, cells)):
        renderer = eb.Renderer(eb.open(source, fields=[field], **options))
        for col, (label, keywords) in enumerate(shots):
            started = time.perf_counter()
            image = renderer.render(field=field, size=(size, size), **keywords)
            print(f"{Path(source).name} {label}: {time.perf_counter() - started:.1f} s", flush=True)
            sheet.paste(Image.open(io.BytesIO(image._repr_png_())).convert("RGB"), (size * col, size * row))
    sheet.save(out)
    print(out)
