"""Render the gallery of render modes (docs/gallery.md) on the shared real datasets.

    .venv/bin/python -m benchmarks.gallery [--only gerris,athena-iso,...] [--list]
                                          [--size N] [--out DIR] [--no-docs]

Each dataset (benchmarks/benchdoc.py: the embedded Gerris plume, the AMReX
plotfile, the Athena++ blast, the Enzo moving7 run through yt, and make_big.py's
generated thin shells, 20.6 M octree-like cells) goes through the
`exabricks` stage commands once (ingest, brick, regions, bvh; cached under
bench-data/gallery/<dataset>/, git-ignored). Then every shot below is one
`exabricks render` command writing docs/images/gallery-<dataset>-<mode>.png,
and docs/gallery.md is rewritten with each image, the exact command that made it
(paths relative to the repository root) and one sentence on what it shows.

--only picks datasets or shots (`gerris`, `athena-clip-plane`; repeatable or
comma-separated). --size N and --out DIR render elsewhere or smaller (for trying
out a change) and leave docs/gallery.md alone, as does --no-docs.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from benchmarks import benchdoc

ROOT = Path(__file__).resolve().parents[1]


WORK = ROOT / "bench-data" / "gallery"
IMAGES = ROOT / "docs" / "images"
DOC = ROOT / "docs" / "gallery.md"
EXAMPLES = "docs/examples"


@dataclass(frozen=True)
class Shot:
    dataset: str          # benchdoc dataset key
    mode: str             # image docs/images/gallery-<dataset>-<mode>.png
    title: str
    text: str             # one sentence on what it shows
    flags: tuple[str, ...]

    @property
    def key(self) -> str:
        return f"{self.dataset}-{self.mode}"


def _f(text: str) -> tuple[str, ...]:
    return tuple(shlex.split(text))


# ---------------------------------------------------------------------------
# Cameras and transfer functions per dataset, from `exabricks info cells.npz`
# and the value distributions (see the notes above each block).

# Gerris plume: world [0, 128]^3; the plume (T > 0.01) fills x, z in [46, 82],
# y in [10, 56]; T in [0, 0.88] (hot cap T > 0.3 above y = 38); the horizontal
# velocities U, W in +-0.095 (a vortex ring: +-0.06 holds 99 %), V in [-0.02, 0.36].
G_CAM = "--position 129 63 148 --look-at 64 33 64 --up 0 1 0 --fovy 30"
G_TF = "--field T --colormap inferno --range 0 0.6 --opacity 0,0.05,0.15,0.3"
G_CLOSE = "--position 97 58 106 --look-at 64 44 64 --up 0 1 0 --fovy 30"
G_HIGH = "--position 120 100 140 --look-at 64 33 64 --up 0 1 0 --fovy 30"
G_CORE = "--field T --colormap inferno --range 0.1 0.8 --opacity 0,0.1,0.3,0.6"
G_SLICE = "--slice-colormap YlGnBu --slice-range 0 0.5 --clip-box 42 0 42 86 62 86"

# Athena++ blast: world [-0.5, 0.5]^3; a spherical shell of dense gas (rho up to
# 2.72, ambient 1) of radius ~0.2 around a hot, thin bubble (rho down to 0.04,
# press up to 1.65, ambient 0.1).
A_CAM = "--position 0.66 0.46 0.8 --look-at 0 0 0 --up 0 1 0 --fovy 30"
A_TF = "--field rho --colormap viridis --range 1 2.7 --opacity 0,0.02,0.2,0.5"
A_FAINT = "--field rho --colormap viridis --range 1 2.7 --opacity 0,0.01,0.04,0.08"

# AMReX advection: world [0, 1]^3; phi = 1 outside a tube along z
# (x in [0.54, 0.82], y in [0.32, 0.86]) where it rises to 1.97.
X_CAM = "--position 2.1 1.65 2.3 --look-at 0.68 0.6 0.5 --up 0 1 0 --fovy 24"
X_TF = "--field phi --colormap viridis --range 1 1.97 --opacity 0,0,0.3,0.6,0.9"

# Enzo moving7: world [0, 1]^3, 8 levels; a collapsing clump at (0.75, 0.75, 0.75):
# Density 0.1 outside, > 10 within 0.06, > 1e4 within 0.002 (up to 2.6e5).
E_CAM = "--position 1.23 1.04 1.33 --look-at 0.75 0.75 0.75 --up 0 1 0 --fovy 30"
E_CLOSE = "--position 0.93 0.86 0.97 --look-at 0.75 0.75 0.75 --up 0 1 0 --fovy 30"
E_TF = ("--field Density --colormap viridis --range 1 30 --opacity 0,0.02,0.1,0.3,0.6 "
        "--unit-distance 0.01")


# Thin shells (make_big.py --thin-shell, ExaJet files: origin 0, spacing 1): world
# [0, 1024]^3; five fronts of radius 160-340 around (300-640)^3 where rho peaks at
# 0.5-1.1 (up to 3.4 where they cross) over a background of 0.02-0.08; a hole of
# radius 123 at (799, 256, 307).
S_CAM = "--position 1790 1360 2020 --look-at 450 470 470 --up 0 1 0 --fovy 30"
S_TF = "--field rho --colormap magma --range 0.1 1.2 --opacity 0,0.02,0.15,0.4"


# The first picture: each dataset with no option but its field (docs/scene.md, "Defaults").
DEFAULT_FIELDS = {"gerris": "--field T", "athena": "--field rho", "amrex": "", "enzo": "--field Density"}
# exabricks.picture.auto_transfer.suggested_iso_value of each (tests/picture/test_first_picture.py).
SUGGESTED_ISO = {"gerris": 0.2281, "athena": 1.721, "amrex": 1.357, "enzo": 0.786}


def shots() -> list[Shot]:
    s = []

    def add(dataset, mode, title, text, flags):
        s.append(Shot(dataset, mode, title, text, _f(flags)))

    for key, field in DEFAULT_FIELDS.items():
        add(key, "defaults", "The default picture",
            "No option but the field: the automatic transfer function on the field's scale, "
            "the framing camera, the weighted headlight, an opaque PNG.", field)
    for key, field in DEFAULT_FIELDS.items():
        add(key, "suggested-iso", "The suggested iso-surface",
            "The viewer's \"Add iso-surface\" value (suggested_iso_value, docs/scene.md), "
            "alone, in the default view.", f"{field} --iso {SUGGESTED_ISO[key]} --no-volume")

    # -- Gerris plume --------------------------------------------------------
    add("gerris", "volume", "Volume (headlight)",
        "The temperature T as a translucent medium (inferno over [0, 0.6]) with the default "
        "headlight shading: the hot cap on top of the rising plume.",
        f"{G_CAM} {G_TF}")
    add("gerris", "volume-unshaded", "Volume without shading",
        "The same volume with `--shading none` (emission-absorption only): no gradient "
        "term, so the cap loses its relief.",
        f"{G_CAM} {G_TF} --shading none")
    add("gerris", "iso", "Iso-surface, fixed colour",
        "The iso-surface T = 0.1 on the reconstructed field, one fixed colour, no volume.",
        f"{G_CAM} --field T --no-volume --iso 0.1 --iso-color 1,0.6,0.3")
    add("gerris", "shells", "Several iso-values as translucent shells",
        "Three nested shells T = 0.05, 0.2, 0.5, each translucent and coloured by T "
        "itself (plasma), so each shell has its own colour.",
        f"{G_CAM} --field T --no-volume --iso 0.05 --iso 0.2 --iso 0.5 --iso-opacity 0.4 "
        "--iso-color-field T --iso-colormap plasma --iso-range 0 0.6")
    add("gerris", "iso-colored", "Iso-surface coloured by another field",
        "The iso-surface T = 0.1 coloured by the horizontal velocity W (coolwarm over "
        "+-0.06): on the side facing the camera the plume spreads outward (+z, red) at the top "
        "and draws fluid in (blue) below.",
        f"{G_CAM} --field T --no-volume --iso 0.1 --iso-color-field W --iso-colormap coolwarm "
        "--iso-range -0.06 0.06")
    add("gerris", "clip-box", "Clip box",
        "The iso-surface T = 0.08 (blue) around the volume of the hot core (T over [0.1, 0.8]), "
        "both kept inside a box (x < 64, z < 64): the far quarter, its two cut faces open "
        "onto the core.",
        f"{G_HIGH} {G_CORE} --iso 0.08 --iso-color 0.55,0.75,1 --clip-box 0 0 0 64 128 64")
    add("gerris", "clip-plane", "Clip plane",
        "The same iso-surface and volume cut by an oblique plane through the plume's axis "
        "(normal (-1, 0.6, -1)): the section of the cap.",
        f"{G_HIGH} {G_CORE} --iso 0.08 --iso-color 0.55,0.75,1 "
        "--clip-plane 64 33 64 -1 0.6 -1")
    add("gerris", "slices", "Axis-aligned slices with the volume",
        "Slices of T at x = 64 and y = 22 (YlGnBu over [0, 0.5]) behind and below the "
        "translucent volume of T; a clip box bounds the slices around the plume.",
        f"{G_HIGH} {G_TF} --slice 64 33 64 1 0 0 --slice 64 22 64 0 1 0 {G_SLICE}")
    add("gerris", "slice-oblique", "Oblique slice with the volume",
        "One slice of T on an oblique plane through the plume's axis (normal (1, 0.7, -0.5)) "
        "with the volume of T.",
        f"{G_HIGH} {G_TF} --slice 64 33 64 1 0.7 -0.5 {G_SLICE}")
    add("gerris", "ao-off", "Ambient occlusion off",
        "Iso-surfaces U = +-0.03 of the horizontal velocity (the vortex ring): four lobes, lit "
        "by the headlight only (4 samples per pixel).",
        f"{G_CAM} --field U --no-volume --iso -0.03 --iso 0.03 --iso-color 0.9,0.8,0.7 --spp 4")
    add("gerris", "ao-on", "Ambient occlusion on",
        "The same lobes with 16 ambient-occlusion rays per hit over 10 cells (the default "
        "distance): the faces that look at each other darken; 4 samples per pixel smooth the "
        "noise.",
        f"{G_CAM} --field U --no-volume --iso -0.03 --iso 0.03 --iso-color 0.9,0.8,0.7 "
        "--ao-samples 16 --spp 4")
    add("gerris", "gradient-analytic", "Analytic gradient",
        "A close-up of the iso-surface T = 0.3 with specular highlights and "
        "`--iso-gradient analytic`: the faint terraces at cell faces (docs/design.md, "
        "\"Surfaces, slices and clipping\").",
        f"{G_CLOSE} --field T --no-volume --iso 0.3 --iso-color 0.9,0.9,1 --specular 0.5 "
        "--iso-gradient analytic")
    add("gerris", "gradient-central", "Central-difference gradient",
        "The same close-up with the default normals, central differences of the reconstructed "
        "field at the hit: no terraces.",
        f"{G_CLOSE} --field T --no-volume --iso 0.3 --iso-color 0.9,0.9,1 --specular 0.5")
    add("gerris", "layers", "Two volume layers",
        f"Two media in one frame from the scene file `{EXAMPLES}/plume-layers.json`: T "
        "(inferno) and the horizontal velocity W (coolwarm, opaque only where |W| is large).",
        f"--scene {EXAMPLES}/plume-layers.json")
    add("gerris", "background", "Background colour",
        "The volume of the first shot composited over an opaque dark background.",
        f"{G_CAM} {G_TF} --background 0.05,0.05,0.08")
    add("gerris", "scene", "A scene file",
        f"Everything at once from `{EXAMPLES}/plume-scene.json`: the volume of the hot core, "
        "a translucent T = 0.08 shell coloured by W, an opaque T = 0.5 core, a horizontal "
        "slice of the vertical velocity V below the cap (viridis), a clip box and an oblique "
        "clip plane, specular, ambient occlusion and a dark background, at 4 samples per pixel.",
        f"--scene {EXAMPLES}/plume-scene.json")
    add("gerris", "annotated", "An annotated picture",
        "The same scene with `--annotate --title`: a colour bar per colour-mapped layer, "
        "surface and slice (the volume's with its opacity curve), a swatch for the fixed-colour "
        "surface, a scale bar and the axes, beside the untouched frame (docs/annotate.md).",
        f"--scene {EXAMPLES}/plume-scene.json --annotate --title 'Gerris buoyant plume'")

    # -- Athena++ blast ------------------------------------------------------
    add("athena", "volume", "Volume (headlight)",
        "The density rho over [1, 2.7] (viridis): the dense shell swept up by the blast, "
        "with the grid-aligned ridges of its wall.",
        f"{A_CAM} {A_TF}")
    add("athena", "volume-unshaded", "Volume without shading",
        "The same volume with `--shading none`: emission and absorption only, no relief.",
        f"{A_CAM} {A_TF} --shading none")
    add("athena", "iso", "Iso-surface, fixed colour",
        "The iso-surface rho = 1.5: the outside of the shell, just behind the shock.",
        f"{A_CAM} --field rho --no-volume --iso 1.5 --iso-color 0.7,0.8,1")
    add("athena", "shells", "Several iso-values as translucent shells",
        "Translucent shells of the pressure, press = 0.3, 0.7 and 1.0 (r = 0.08, 0.12, 0.16), "
        "coloured by press (inferno) and cut open by the plane x + z = 0.",
        f"{A_CAM} --field press --no-volume --iso 0.3 --iso 0.7 --iso 1.0 --iso-opacity 0.5 "
        "--iso-color-field press --iso-colormap inferno --iso-range 0 1.65 "
        "--clip-plane 0 0 0 -1 0 -1")
    add("athena", "iso-colored", "Iso-surface coloured by another field",
        "The iso-surface rho = 1.5 coloured by the pressure (inferno over [0.1, 1.65]) and cut "
        "open: low pressure on the outer face behind the shock, high on the inner face.",
        f"{A_CAM} --field rho --no-volume --iso 1.5 --iso-color-field press "
        "--iso-colormap inferno --iso-range 0.1 1.65 --clip-plane 0 0 0 -1 0 -1")
    add("athena", "clip-box", "Clip box",
        "The rho volume and the iso-surface rho = 1.5 kept inside the box x, z < 0: the "
        "far quarter of the shell, its wall in section on the two cut faces.",
        f"{A_CAM} {A_TF} --iso 1.5 --iso-color 0.7,0.8,1 --clip-box -0.5 -0.5 -0.5 0 0.5 0")
    add("athena", "clip-plane", "Clip plane",
        "The same volume and iso-surface cut by the plane x + z = 0: the inside of the "
        "shell, the wall's section in green.",
        f"{A_CAM} {A_TF} --iso 1.5 --iso-color 0.7,0.8,1 --clip-plane 0 0 0 -1 0 -1")
    add("athena", "slices", "Axis-aligned slices with the volume",
        "Slices of rho through the centre at x = 0, y = 0 and z = 0 (viridis over [0, 2.7]: "
        "the empty bubble, the dense wall, the ambient gas) behind a faint rho volume, in "
        "the clip box |x|, |y|, |z| < 0.3.",
        f"{A_CAM} {A_FAINT} --slice 0 0 0 1 0 0 --slice 0 0 0 0 1 0 --slice 0 0 0 0 0 1 "
        "--slice-colormap viridis --slice-range 0 2.7 --clip-box -0.3 -0.3 -0.3 0.3 0.3 0.3")
    add("athena", "slice-oblique", "Oblique slice with the volume",
        "One oblique slice of rho through the centre (normal (1, 2, 3)) with the faint "
        "volume in front of it.",
        f"{A_CAM} {A_FAINT} --slice 0 0 0 1 2 3 --slice-colormap viridis --slice-range 0 2.7 "
        "--clip-box -0.3 -0.3 -0.3 0.3 0.3 0.3")
    add("athena", "ao-off", "Ambient occlusion off",
        "The iso-surface rho = 1.5 with its near half clipped away: the inside of the far "
        "half, a bowl, lit by the headlight only (4 samples per pixel).",
        f"{A_CAM} --field rho --no-volume --iso 1.5 --iso-color 0.9,0.8,0.7 "
        "--clip-plane 0 0 0 0 0 -1 --spp 4")
    add("athena", "ao-on", "Ambient occlusion on",
        "The same bowl with 16 ambient-occlusion rays of length 0.05 per hit: the bowl's "
        "inside and the slot between the wall's two faces darken.",
        f"{A_CAM} --field rho --no-volume --iso 1.5 --iso-color 0.9,0.8,0.7 "
        "--clip-plane 0 0 0 0 0 -1 --ao-samples 16 --ao-distance 0.05 --spp 4")
    add("athena", "gradient-analytic", "Analytic gradient",
        "The iso-surface rho = 1.5 with specular highlights and `--iso-gradient analytic`: "
        "concentric terraces where the gradient jumps at cell faces.",
        f"{A_CAM} --field rho --no-volume --iso 1.5 --iso-color 0.7,0.8,1 --specular 0.5 "
        "--iso-gradient analytic")
    add("athena", "gradient-central", "Central-difference gradient",
        "The same with the default normals, central differences of the reconstructed field at "
        "the hit: the terraces are gone.",
        f"{A_CAM} --field rho --no-volume --iso 1.5 --iso-color 0.7,0.8,1 --specular 0.5")
    add("athena", "layers", "Two volume layers",
        f"The density (Blues) and the pressure (Reds) as two media in one frame, cut open "
        f"by a clip plane (`{EXAMPLES}/blast-layers.json`): the hot high-pressure interior "
        "inside the dense shell.",
        f"--scene {EXAMPLES}/blast-layers.json")
    add("athena", "background", "Background colour",
        "The density volume over an opaque dark background.",
        f"{A_CAM} {A_TF} --background 0.05,0.05,0.08")

    # -- AMReX advection -----------------------------------------------------
    add("amrex", "volume", "Volume (headlight)",
        "The advected scalar phi over [1, 1.97] (viridis, transparent below 1.24): a curved "
        "sheet along z, sharpest at its rolled-up edge.",
        f"{X_CAM} {X_TF}")
    add("amrex", "iso", "Iso-surface, fixed colour, with ambient occlusion",
        "The iso-surface phi = 1.5 with 8 ambient-occlusion rays per hit: the inside of the "
        "curl darkens.",
        f"{X_CAM} --field phi --no-volume --iso 1.5 --iso-color 1,0.6,0.3 --ao-samples 8")
    add("amrex", "shells", "Several iso-values as translucent shells",
        "Shells phi = 1.1, 1.5 and 1.9, translucent, coloured by phi (viridis): the sheet's "
        "layers, nested.",
        f"{X_CAM} --field phi --no-volume --iso 1.1 --iso 1.5 --iso 1.9 --iso-opacity 0.4 "
        "--iso-color-field phi --iso-colormap viridis --iso-range 1 1.97")
    add("amrex", "clip-plane", "Clip plane",
        "The volume and the iso-surface phi = 1.5 cut by the plane z = 0.5: the sheet's "
        "cross-section on the cut face.",
        f"{X_CAM} {X_TF} --iso 1.5 --iso-color 1,0.6,0.3 --clip-plane 0.5 0.5 0.5 0 0 -1")
    add("amrex", "slices", "Slices with the volume",
        "An axis-aligned slice (z = 0.25) and an oblique one (normal (1, 1, 0)) of phi "
        "with the volume, in a clip box around the sheet.",
        f"{X_CAM} {X_TF} --slice 0.5 0.5 0.25 0 0 1 --slice 0.68 0.59 0.5 1 1 0 "
        "--slice-colormap viridis --slice-range 1 1.97 --clip-box 0.45 0.25 0 0.9 0.95 1")
    add("amrex", "annotated", "An annotated picture",
        "The volume with `--annotate --title`: the simulation time from the plotfile's Header, "
        "the colour bar with the opacity curve, a scale bar and the axes. Beside yt's "
        "`save_annotated` of the same data (docs/examples/annotated_vs_yt.py): "
        "![exabricks and yt](images/annotated/amrex-exabricks-vs-yt.png)",
        f"{X_CAM} {X_TF} --annotate --title 'AMReX advection, phi'")

    # -- Enzo moving7 ----------------------------------------------------------
    add("enzo", "volume", "Volume (headlight)",
        "The gas Density over [1, 30] (viridis) around the collapsing clump, Density ~ r^-2 "
        "down 8 levels of refinement; `--unit-distance 0.01` (20 finest cells) sets how "
        "fast the opacity builds up.",
        f"{E_CAM} {E_TF}")
    add("enzo", "shells", "Several iso-values as translucent shells",
        "Nested shells Density = 3, 30 and 300 (r ~ 0.1, 0.03, 0.008), translucent, coloured "
        "by Density (magma over [0, 40]) and cut open by a plane: the nested refinement "
        "levels show as creases.",
        f"{E_CAM} --field Density --no-volume --iso 3 --iso 30 --iso 300 --iso-opacity 0.4 "
        "--iso-color-field Density --iso-colormap magma --iso-range 0 40 "
        "--clip-plane 0.75 0.75 0.75 -1 0 -1")
    add("enzo", "clip-box", "Clip box",
        "The volume and the iso-surface Density = 10 in the box x, z < 0.75 (the far quarter "
        "around the clump's centre).",
        f"{E_CLOSE} {E_TF} --iso 10 --iso-color 1,0.6,0.3 --clip-box 0 0 0 0.75 1 0.75")
    add("enzo", "slices", "Slices with the volume",
        "Slices of Density through the clump's centre (x = 0.75 and y = 0.75, viridis over "
        "[0, 10]) with the volume, in a clip box around the clump.",
        f"{E_CAM} {E_TF} --slice 0.75 0.75 0.75 1 0 0 --slice 0.75 0.75 0.75 0 1 0 "
        "--slice-colormap viridis --slice-range 0 10 --clip-box 0.55 0.55 0.55 0.95 0.95 0.95")

    # -- make_big.py thin shells ---------------------------------------------------
    add("shell", "volume", "Volume of octree-like data (merged regions)",
        "The generated thin-shell layout (20.6 M cells, 2.3 M bricks of 8.9 cells, 1.46 M "
        "merged regions): five spherical fronts, each a narrow ridge of rho refined two cells "
        "thick, crossing each other (the faint background and the hole, which lies in it, are "
        "transparent under this transfer function).",
        f"{S_CAM} {S_TF}")
    add("shell", "clip-iso", "Iso-surface and clip plane on octree-like data",
        "The iso-surface rho = 0.4 on the same data, cut open by a plane through the centre: "
        "the fronts' shells and where they cross; the rings on the surfaces are the terraces "
        "of the analytic gradient at cell faces (docs/design.md, \"Integration and images\").",
        f"{S_CAM} --field rho --no-volume --iso 0.4 --iso-color 0.9,0.7,0.4 "
        "--clip-plane 512 512 512 -1 0 -1")
    return s


# ---------------------------------------------------------------------------


def rel(path: Path) -> str:
    return os.path.relpath(path, ROOT)


def pipeline(dataset: benchdoc.Dataset) -> list[list[str]]:
    """The four stage commands of one dataset (paths relative to the repository root)."""
    d = rel(WORK / dataset.key)
    return [["exabricks", "ingest", rel(dataset.path), *dataset.ingest_flags, "-o", f"{d}/cells.npz"],
            ["exabricks", "brick", f"{d}/cells.npz", "-o", f"{d}/bricks.npz"],
            ["exabricks", "regions", f"{d}/bricks.npz", "-o", f"{d}/regions.npz"],
            ["exabricks", "bvh", f"{d}/regions.npz", "-o", f"{d}/bvh.npz"]]


def render_command(shot: Shot, image: str) -> list[str]:
    d = rel(WORK / shot.dataset)
    return ["exabricks", "render", f"{d}/bricks.npz", f"{d}/regions.npz", f"{d}/bvh.npz",
            *shot.flags, "-o", image]


def run(args: list[str]) -> float:
    """Run one `exabricks` command (from the repository root); wall seconds."""
    cmd = benchdoc.exabricks_command() + args[1:]
    t = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if proc.returncode:
        sys.exit(f"{shlex.join(args)} failed: {proc.stderr.strip()}")
    return time.perf_counter() - t


def ensure(dataset: benchdoc.Dataset) -> None:
    """bench-data/gallery/<key>/{cells,bricks,regions,bvh}.npz, made when missing."""
    (WORK / dataset.key).mkdir(parents=True, exist_ok=True)
    for cmd in pipeline(dataset):
        source = None if cmd[1] == "ingest" else ROOT / cmd[2]
        if not benchdoc.up_to_date(ROOT / cmd[-1], source):
            print("  " + shlex.join(cmd), flush=True)
            run(cmd)


def shell(args: list[str]) -> str:
    """A command as one shell line, wrapped before each flag group for reading."""
    words = [shlex.quote(a) for a in args]
    lines, line = [], []
    for w in words:
        if w.startswith("--") and len(" ".join(line + [w])) > 70 and line:
            lines.append(" ".join(line))
            line = []
        line.append(w)
    lines.append(" ".join(line))
    return " \\\n    ".join(lines)


NAMES = {"gerris": "Gerris buoyant plume (embedded, ExaJet cells)",
         "athena": "Athena++ blast wave (`.athdf`)",
         "amrex": "AMReX advection (plotfile)",
         "enzo": "Enzo moving7 (read through yt)",
         "shell": "Thin shells (generated octree-like layout, `make_big.py --thin-shell`)"}
ORDER = ("gerris", "athena", "amrex", "enzo", "shell")


def write_doc(all_shots: list[Shot], sets: dict) -> None:
    out = ["# Gallery: every render mode on the real datasets", "",
           "Made by `.venv/bin/python -m benchmarks.gallery` (it runs every command below; "
           "`--only KEY` re-renders some). `exabricks` is `.venv/bin/exabricks`; every path "
           "is relative to the repository root. Each dataset first goes through the four "
           "stage commands into `bench-data/gallery/<dataset>/` (git-ignored). Images are "
           "512 x 512 PNG (8-bit, opaque: composited over the background, black unless "
           "`--background` says otherwise), one sample per pixel unless the command or the scene file says "
           "otherwise. The flags and the scene file are described in [scene.md](scene.md); "
           "render times of every mode are in [benchmarks-render.md](benchmarks-render.md#render-modes). "
           "The faint terraces on shaded iso-surfaces are the analytic gradient's jumps at "
           "cell faces ([design.md](design.md), \"Integration and images\"; compare the two "
           "gradient shots).", ""]
    out += ["Contents: [The first picture](#defaults), "
            + ", ".join(f"[{NAMES[k].split(' (')[0]}](#{k})" for k in ORDER), ""]
    out += first_picture_section(all_shots)
    for key in ORDER:
        mine = [s for s in all_shots if s.dataset == key and s.mode not in ("defaults", "suggested-iso")]
        if not mine:
            continue
        out += [f'<a id="{key}"></a>', "", f"## {NAMES[key]}", "", "```sh"]
        out += [shlex.join(c) for c in pipeline(sets[key])]
        out += ["```", ""]
        for s in mine:
            image = f"docs/images/gallery-{s.key}.png"
            out += [f"### {s.title}", "", f"![{s.title}](images/gallery-{s.key}.png)", "",
                    s.text, "", "```sh", shell(render_command(s, image)), "```", ""]
    DOC.write_text("\n".join(out).rstrip() + "\n")


def _measures(png: Path) -> str:
    """"coverage, luminance σ, p99" of a picture (benchmarks.first_picture)."""
    import numpy as np
    from PIL import Image

    from benchmarks.first_picture import COVERED, luminance

    if not png.exists():
        return "(not drawn)"
    lum = luminance(np.asarray(Image.open(png).convert("RGBA")))
    seen = lum[lum > COVERED]
    if not seen.size:
        return "0.00, 0, 0"
    return f"{(lum > COVERED).mean():.2f}, {seen.std():.3f}, {np.quantile(seen, 0.99):.2f}"


def first_picture_section(all_shots: list[Shot]) -> list[str]:
    """The "first picture" section: each dataset's default picture beside what the
    defaults gave before (b0682ec) and yt's create_scene default, then the volume
    headlight before and after its weighting."""
    out = ['<a id="defaults"></a>', "", "## The first picture: what the defaults give", "",
           "`exabricks render SOURCE -o x.png` with no option but the field, beside yt 4.4's "
           "`create_scene(ds, field)` saved at 512 x 512 (`python -m benchmarks.first_picture "
           "--yt docs/images`; the Gerris cells through `exabricks.readers.yt_grids`), what the "
           "same command gave at b0682ec (transparent PNG, viridis ramp over the whole range, "
           "the whole domain framed), and the iso-surface the viewer suggests, alone. "
           "docs/scene.md, \"What the defaults give\", has every measure "
           "(`python -m benchmarks.first_picture --core DIR`).", "",
           "| dataset | now | yt create_scene | before (b0682ec) | the suggested iso-surface |",
           "|---|---|---|---|---|"]
    for s in all_shots:
        if s.mode == "defaults":
            out.append(f"| {NAMES[s.dataset].split(' (')[0]} | ![now](images/gallery-{s.key}.png) | "
                       f"![yt](images/defaults-yt-{s.dataset}.png) | "
                       f"![before](images/defaults-before-{s.dataset}.png) | "
                       f"![iso](images/gallery-{s.dataset}-suggested-iso.png) |")
    out += ["", "Measured on these PNGs (benchmarks.first_picture's measures over the covered "
            "pixels; issue 63 asks σ ≥ 0.08 and p99 ≥ 0.6 of the default picture):", "",
            "| dataset | now: coverage, luminance σ, p99 | yt: coverage, luminance σ, p99 |",
            "|---|---|---|"]
    for s in all_shots:
        if s.mode == "defaults":
            now = _measures(IMAGES / f"gallery-{s.key}.png")
            yt = _measures(IMAGES / f"defaults-yt-{s.dataset}.png")
            out.append(f"| {NAMES[s.dataset].split(' (')[0]} | {now} | {yt} |")
    out += ["", "The commands of the pictures on the left and on the right:", "", "```sh"]
    out += [shell(render_command(s, f"docs/images/gallery-{s.key}.png")) for s in all_shots
            if s.mode in ("defaults", "suggested-iso")]
    out += ["```", "", "### The volume's headlight, before and after", "",
            "The same transfer function and camera drawn with the headlight of b0682ec (the diffuse "
            "term of every sample's normalised gradient), with today's (weighted by the gradient's "
            "strength against the transfer function's range, docs/design.md \"Volume shading\") and "
            "without shading. The rings and the dotted zipper along the crescent were the normals of "
            "weak, cell-scale gradients; the high-frequency energy the headlight adds over "
            "`--shading none` fell from 1.2 % to 0.27 % of the mean luminance on AMReX and from "
            "1.9 % to 0.25 % on Athena++ (`benchmarks.bench_shading.added_detail` of these pictures; "
            "docs/benchmarks.md, \"Volume shading\", measures each build's own default pictures).", "",
            "| | before (b0682ec) | now | `--shading none` |", "|---|---|---|---|"]
    for key, name in (("amrex", "AMReX phi"), ("athena", "Athena++ rho")):
        out.append(f"| {name} | ![before](images/shading-{key}-before.png) | "
                   f"![now](images/shading-{key}-after.png) | ![none](images/shading-{key}-none.png) |")
    out += ["", "```sh", *SHADING_COMMANDS, "```", ""]
    return out + SHADOWS_SECTION + PATH_SECTION


# The shadow integrator's sheet (docs/pictures/shadows_picture.py makes its picture).
SHADOWS_SECTION = [
    '<a id="shadows"></a>', "", "### Lit from one side, with shadows", "",
    "Each dataset's default picture under today's headlight (left), under `--integrator shadow` "
    "(middle), and with an opaque iso-surface added (right: T = 0.45, phi = 1.5, rho = 1.5, Density = 3), "
    "whose shadow falls on itself and on the volume: the default key light, 35° above the view and 60° to its left, "
    "its transmittance through the volume lighting every sample, plus an ambient 0.2 "
    "(docs/design-rendering.md, \"Lights and shadows\"). 320 x 320, 4 samples per pixel; rows: "
    "Gerris plume, AMReX advection, Athena++ blast, Enzo moving7.", "",
    "![Headlight and shadow, four datasets](images/shadows.png)", "",
    "```sh", ".venv/bin/python docs/pictures/shadows_picture.py", "```", ""]


# The path integrator's sheet (docs/pictures/path_picture.py makes its picture).
PATH_SECTION = [
    '<a id="path"></a>', "", "### Path-traced: light that scatters", "",
    "Each dataset's default picture under `--integrator shadow` (left: single scattering of the key "
    "light, integrated exactly), and path-traced with up to 8 scattering events under the same light "
    "and a uniform environment of radiance 0.2, isotropic (middle) and forward-scattering "
    "(right, `--anisotropy 0.6`): light that enters the matter bounces on inside it, so the matter is "
    "brighter than under single scattering; forward scattering carries the key light, which comes from the "
    "camera's side, away from the camera, so that frame is darker (docs/design-rendering.md, "
    "\"Path tracing\"). 192 x 192, 64 samples per pixel for the path-traced frames (still noisy: "
    "about 15 % RMSE); rows: Gerris plume, AMReX advection, Athena++ blast, Enzo moving7.", "",
    "![Shadow and path-traced, four datasets](images/path.png)", "",
    "```sh", ".venv/bin/python docs/pictures/path_picture.py", "```", ""]


# The shading comparison's commands (run at b0682ec for "before", as they are for the others).
SHADING_COMMANDS = (
    "exabricks render ../shared/data/amrex-advection3d/plt00020 --colormap viridis --range 0.99 1.98 "
    "--opacity 0,0,0.02,0.1,0.4 --position 1.654 1.084 1.788 --look-at 0.7303 0.5298 0.4943 "
    "--background 0,0,0 -o docs/images/shading-amrex-after.png",
    "exabricks render ../shared/data/athena-blast3d/Blast.out2.00001.athdf --field rho --colormap viridis "
    "--range 0.03 2.75 --opacity 0.3,0.05,0,0.05,0.3,0.6 --position 0.5086 0.3051 0.712 --look-at 0 0 0 "
    "--background 0,0,0 -o docs/images/shading-athena-after.png",
)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", metavar="KEY",
                        help="datasets or shots (dataset-mode), repeatable or comma-separated")
    parser.add_argument("--list", action="store_true", help="list the shots and stop")
    parser.add_argument("--size", type=int, help="render N x N instead (leaves the docs alone)")
    parser.add_argument("--out", type=Path, help="write the images here instead "
                        "(leaves the docs alone)")
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite docs/gallery.md")
    args = parser.parse_args(argv)

    all_shots = shots()
    if args.list:
        for s in all_shots:
            print(f"{s.key:28s} {s.title}")
        return 0
    wanted = None
    if args.only:
        wanted = {k.strip() for item in args.only for k in item.split(",") if k.strip()}
        known = {s.key for s in all_shots} | {s.dataset for s in all_shots}
        if wanted - known:
            parser.error(f"unknown --only key(s): {', '.join(sorted(wanted - known))}")
    todo = [s for s in all_shots if wanted is None or s.key in wanted or s.dataset in wanted]

    sets = benchdoc.datasets()
    out_dir = args.out or IMAGES
    out_dir.mkdir(parents=True, exist_ok=True)
    for key in ORDER:
        if any(s.dataset == key for s in todo):
            ensure(sets[key])
    total = 0.0
    for s in todo:
        path = out_dir / f"gallery-{s.key}.png"
        cmd = render_command(s, rel(path) if path.resolve().is_relative_to(ROOT) else str(path))
        if args.size:
            cmd[-2:-2] = ["--size", str(args.size), str(args.size)]
        seconds = run(cmd)
        total += seconds
        print(f"{s.key:28s} {seconds:6.1f} s  {path.stat().st_size / 1024:6.0f} KiB", flush=True)
    print(f"{len(todo)} images in {total:.0f} s")
    if not (args.no_docs or args.size or args.out):
        write_doc(all_shots, sets)
        print(f"wrote {rel(DOC)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
