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

from sheet import ISO, ROOT, render_sheet

OUT = ROOT / "docs" / "images" / "shadows.png"
SIZE = 320


def columns(row: int):
    return (("headlight", {"integrator": "headlight", "spp": 4}),
            ("shadow", {"integrator": "shadow", "spp": 4}),
            ("shadow, iso-surface", {"integrator": "shadow", "spp": 4, "iso": ISO[row]}))


def main() -> None:
    render_sheet(OUT, SIZE, columns)


if __name__ == "__main__":
    main()
