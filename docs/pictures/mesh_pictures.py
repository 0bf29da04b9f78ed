"""The pictures of docs/design-rendering.md "Meshes" and docs/gallery.md "Meshes": meshes
drawn with the volume by `exabricks render --mesh`, each mesh made by
`exabricks surface` from the data itself (the shared datasets hold no
embedded-boundary body).

    .venv/bin/python docs/pictures/mesh_pictures.py

Writes into docs/images/mesh/:

- amrex-body.png: the AMReX advection plotfile; its phi = 1.2 surface as an
  opaque grey body inside the volume of phi, with ambient occlusion;
- amrex-body-clipped.png: the same, the half z > 0.5 clipped away (the body too);
- amrex-mirrored.png: the same body and volume with their mirror image across
  the data's face y = 0 (`--mirror y 0`);
- amrex-mixture.png: the volume with its mirror image across the plane y = 0.3
  through the data (`--mirror y 0.3`): the overlapping copies' media mix;
- gerris-shell.png: the Gerris plume; its T = 0.1 surface as a translucent shell
  coloured by the vertical velocity W, around the volume of T;
- amrex-sheet.png: a wavy sheet of a million triangles (benchmarks/bench_mesh.py's)
  at opacity 0.5 through the AMReX volume.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

from sheet import AMREX, GERRIS, ROOT

OUT = ROOT / "docs" / "images" / "mesh"


def exabricks(*args) -> None:
    subprocess.run([sys.executable, "-m", "exabricks.cli.main", *map(str, args)], check=True)


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        body = Path(tmp) / "body.ply"
        exabricks("surface", AMREX, "--field", "phi", "--value", 1.2, "-o", body)
        look = ("--field", "phi", "--colormap", "viridis", "--opacity", "0,0.3", "--mesh", body,
                "--mesh-color", "0.8,0.8,0.82", "--ao-samples", 16, "--ao-distance", 0.1,
                "--specular", 0.3, "--size", 640, 640, "--spp", 4, "--background", "1,1,1")
        exabricks("render", AMREX, *look, "-o", OUT / "amrex-body.png")
        exabricks("render", AMREX, *look, "--clip-plane", 0.5, 0.5, 0.5, 0, 0, -1,
                  "-o", OUT / "amrex-body-clipped.png")
        exabricks("render", AMREX, *look, "--mirror", "y", 0, "--position", 3.2, -2.6, 2.3,
                  "--look-at", 0.45, 0, 0.4, "--up", 0, 0, 1, "--size", 640, 480,
                  "-o", OUT / "amrex-mirrored.png")
        exabricks("render", AMREX, "--field", "phi", "--colormap", "viridis", "--opacity", "0,0.3",
                  "--spp", 4, "--background", "1,1,1", "--mirror", "y", 0.3,
                  "--position", 3.2, -2.6, 2.3, "--look-at", 0.45, 0.3, 0.4, "--up", 0, 0, 1,
                  "--size", 640, 480, "-o", OUT / "amrex-mixture.png")
        shell = Path(tmp) / "shell.ply"
        exabricks("surface", GERRIS, "--field", "T", "--value", 0.1, "-o", shell)
        scene = Path(tmp) / "scene.json"
        scene.write_text('{"volumes": [{"field": "T", "transfer_function": {"colormap": "inferno", '
                         '"opacity": [0, 0.5]}, "range": [0, 0.6]}], "meshes": [{"path": "shell.ply", '
                         '"opacity": 0.35, "color": {"field": "W", "colormap": "coolwarm", '
                         '"range": [-0.06, 0.06]}}]}')
        exabricks("render", GERRIS, "--scene", scene, "--position", 129, 63, 148, "--look-at", 64, 33,
                  64, "--up", 0, 1, 0, "--size", 640, 640, "--spp", 4, "--background", "1,1,1",
                  "-o", OUT / "gerris-shell.png")
        # a million triangles: bench_mesh's wavy sheet through the AMReX data
        import exabricks as eb
        from benchmarks.bench_mesh import ensure_sheet

        sheet = ensure_sheet(10 ** 6, *eb.open(AMREX).bounds)
        exabricks("render", AMREX, "--field", "phi", "--colormap", "viridis", "--opacity", "0,0.3",
                  "--mesh", sheet, "--mesh-color", "0.95,0.6,0.3", "--mesh-opacity", 0.5,
                  "--size", 640, 640, "--spp", 4, "--background", "1,1,1",
                  "-o", OUT / "amrex-sheet.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
