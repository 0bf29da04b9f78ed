"""The picture of the path integrator (docs/gallery.md, "Path-traced: light that
scatters"; docs/design-rendering.md, "Path tracing"): each shared dataset's default
frame (the automatic transfer function, the default camera, the default key light)
under `--integrator shadow` (single scattering, exactly integrated), path-traced
with 8 scattering events, isotropic and forward-scattering (g = 0.6), and
path-traced with the opaque iso-surface of shadows_picture.py in the volume.

    .venv/bin/python docs/pictures/path_picture.py

Writes docs/images/path.png: one row per dataset (shadow, path, path with g = 0.6,
path with the iso-surface), SIZE x SIZE each, the path-traced frames at SPP samples
per pixel, and prints each frame's time.
"""

from __future__ import annotations

from sheet import ISO, ROOT, render_sheet

OUT = ROOT / "docs" / "images" / "path.png"
SIZE = 192
SPP = 128


def columns(row: int):
    return (("shadow", {"integrator": "shadow", "spp": 1}),
            ("path", {"integrator": "path", "spp": SPP}),
            ("path, g = 0.6", {"integrator": "path", "spp": SPP, "anisotropy": 0.6}),
            ("path, iso-surface", {"integrator": "path", "spp": SPP, "iso": ISO[row]}))


def main() -> None:
    render_sheet(OUT, SIZE, columns)


if __name__ == "__main__":
    main()
