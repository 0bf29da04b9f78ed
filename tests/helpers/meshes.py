"""Triangle meshes written for the mesh tests."""

from __future__ import annotations

import trimesh


def icosphere_file(tmp_path, centre, radius, subdivisions=5):
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    sphere.apply_translation(centre)
    path = tmp_path / "sphere.ply"
    sphere.export(path)
    return path, sphere
