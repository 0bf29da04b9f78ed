"""The pictures of docs/surface.md: meshes written by `exabricks surface`, drawn
with matplotlib (front faces only, lit by a fixed light).

    .venv/bin/python docs/pictures/surface_pictures.py

Writes into docs/images/surface/:

- amrex-phi-1.2.png: the AMReX advection plotfile, phi = 1.2, in its unit domain;
- gerris-T-0.25.png: the Gerris plume, T = 0.25.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from sheet import AMREX, GERRIS, ROOT

OUT = ROOT / "docs" / "images" / "surface"

CASES = [("amrex-phi-1.2.png", AMREX, "phi", 1.2, ((0, 0, 0), (1, 1, 1)), (25, -35)),
         ("gerris-T-0.25.png", GERRIS, "T", 0.25, None, (22, -60))]


def draw(mesh_path: Path, out: Path, title: str, box, view) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    mesh = trimesh.load(mesh_path, process=False)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    lo, hi = (np.asarray(b, float) for b in box) if box else (v.min(0), v.max(0))
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-30
    elev, azim = np.radians(view)
    eye = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    scale = hi - lo
    facing = ((n / scale) @ eye) > 0  # normals toward lower values: outward here
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.3 + 0.7 * np.clip(n[facing] @ light, 0, 1)
    colour = np.asarray(plt.cm.viridis(0.6))[:3]
    fig = plt.figure(figsize=(6, 5), dpi=110)
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(v[f[facing]], facecolors=colour * shade[:, None],
                                         edgecolor="none"))
    ax.set_xlim(lo[0], hi[0]), ax.set_ylim(lo[1], hi[1]), ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    ax.set_xlabel("x"), ax.set_ylabel("y"), ax.set_zlabel("z")
    ax.set_title(title, fontsize=10)
    ax.view_init(elev=view[0], azim=view[1])
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name, source, field, value, box, view in CASES:
            mesh = Path(tmp) / "mesh.ply"
            subprocess.run([sys.executable, "-m", "exabricks.cli.main", "surface", str(source),
                            "--field", field, "--value", str(value), "-o", str(mesh)], check=True)
            faces = len(np.asarray(__import__("trimesh").load(mesh, process=False).faces))
            draw(mesh, OUT / name, f"{source.parent.name}: {field} = {value} ({faces:,} triangles)",
                 box, view)
            print(OUT / name)


if __name__ == "__main__":
    main()
