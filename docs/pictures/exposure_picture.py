"""The picture of the film's exposure (docs/design-rendering.md, "Integration and
images"): the Athena++ blast's default frame as integrated (--no-auto-exposure),
with the automatic exposure, and with it and --exposure +1, the film applied
once after every sample composited.

    .venv/bin/python docs/pictures/exposure_picture.py

Writes docs/images/exposure.png: the three frames side by side, 240x240 each, over
the PNG's black backdrop.
"""

from __future__ import annotations

import io
from pathlib import Path

from PIL import Image

import exabricks as eb

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images" / "exposure.png"
BLAST = ROOT.parent / "shared" / "data" / "athena-blast3d" / "Blast.out2.00001.athdf"
# (auto_exposure, exposure) of each frame
FRAMES = ((False, 0.0), (True, 0.0), (True, 1.0))


def main() -> None:
    renderer = eb.Renderer(eb.open(BLAST))
    strip = Image.new("RGB", (240 * len(FRAMES), 240))
    for i, (auto, stops) in enumerate(FRAMES):
        image = renderer.render(field="rho", size=(240, 240), spp=4, auto_exposure=auto,
                                exposure=stops)
        strip.paste(Image.open(io.BytesIO(image._repr_png_())).convert("RGB"), (240 * i, 0))  # the PNG's pixels
    strip.save(OUT)
    print(OUT)


if __name__ == "__main__":
    main()
