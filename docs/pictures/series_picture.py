"""The picture of docs/time-series.md: a filmstrip of `eb.render_series` over
workflows/make_series.py's series on a fixed hierarchy (the blob that travels
round a circle), one scene for every frame.

    .venv/bin/python docs/pictures/series_picture.py

Writes docs/images/series-filmstrip.png: the 8 frames side by side, 160x120 each.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

import exabricks as eb

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "images" / "series-filmstrip.png"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        subprocess.run([sys.executable, ROOT / "workflows" / "make_series.py", run, "--steps", "8",
                        "--fixed-hierarchy"], check=True, capture_output=True)
        series = eb.open_series(str(run / "plt*"), cache=Path(tmp) / "cache")
        frames = eb.render_series(series, Path(tmp) / "frames", field="phi", size=(160, 120),
                                  spp=4)
        images = [Image.open(f).convert("RGB") for f in frames]
        strip = Image.new("RGB", (160 * len(images), 120))
        for i, image in enumerate(images):
            strip.paste(image, (160 * i, 0))
        strip.save(OUT)
    print(OUT)


if __name__ == "__main__":
    main()
