"""The picture of the film's optional denoiser (docs/gallery.md, "Denoised previews";
docs/design-rendering.md, "Path tracing"): each shared dataset's default frame
path-traced at PREVIEW samples per pixel, raw and denoised (`--denoise`, Intel Open
Image Denoise), beside the same frame at CONVERGED samples per pixel.

    .venv/bin/python docs/pictures/denoise_picture.py

Writes docs/images/denoise.png: one row per dataset (raw, denoised, converged),
SIZE x SIZE each, and prints each frame's time.
"""

from __future__ import annotations

from sheet import ROOT, render_sheet

OUT = ROOT / "docs" / "images" / "denoise.png"
SIZE = 160
PREVIEW, CONVERGED = 8, 256


def columns(row: int):
    return ((f"path, {PREVIEW} spp", {"integrator": "path", "spp": PREVIEW}),
            (f"path, {PREVIEW} spp, denoised", {"integrator": "path", "spp": PREVIEW, "denoise": True}),
            (f"path, {CONVERGED} spp", {"integrator": "path", "spp": CONVERGED, "seed": 1}))


def main() -> None:
    render_sheet(OUT, SIZE, columns)


if __name__ == "__main__":
    main()
