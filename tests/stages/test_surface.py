"""`exabricks surface`: iso-surfaces as triangle meshes (exabricks.stages.surface).

A linear field, which the basis reconstruction reproduces exactly inside a
level, gives a plane whose every vertex lies on the iso-value (float64
reference: the field itself); on the AMReX plotfile the field probed at the
vertices is the iso-value; normals point toward lower values; bad requests end in
one error line and no file."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import AMREX, assert_one_error_line, build, run_cli
from exabricks import schema
from exabricks.stages.surface import iso_mesh

GRADIENT = np.array([1.0, 2.0, 3.0])


def linear_cells() -> schema.Cells:
    """A 16^3 lattice of level-0 cells with f = x + 2y + 3z at the cell centres
    (world = lattice * 0.5 + 1): the basis reconstruction reproduces it exactly
    inside one level (docs/design.md), away from the outer cells."""
    lower = np.stack(np.meshgrid(*[np.arange(16)] * 3, indexing="ij"), -1).reshape(-1, 3).astype(np.int32)
    level = np.zeros(len(lower), np.int8)
    origin, spacing = np.ones(3), np.full(3, 0.5)
    centre = origin + spacing * (lower + 0.5)
    values = (centre @ GRADIENT)[None].astype(np.float32)
    return schema.Cells(fields=("f",), origin_world=origin, spacing_world=spacing,
                        lower_lattice=lower, level=level, values=values)


def test_a_linear_field_gives_its_plane_with_normals_toward_lower_values():
    built = build(linear_cells())
    value = 1.0 * 4.1 + 2.0 * 3.3 + 3.0 * 5.2
    mesh = iso_mesh(built.bricks, built.regions, built.bvh, "f", value)
    assert mesh.level == 0 and mesh.grid == (16, 16, 16)
    assert len(mesh.faces) > 100
    inside = interior(mesh.vertices)  # next to the outer cells the basis extrapolates
    assert inside.sum() > 0.5 * len(inside)
    np.testing.assert_allclose(mesh.vertices[inside] @ GRADIENT, value, atol=2e-4)
    v = mesh.vertices[mesh.faces]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert np.all(normals @ GRADIENT < 0)
    coarse = iso_mesh(built.bricks, built.regions, built.bvh, "f", value, level=1)
    assert coarse.grid == (8, 8, 8) and len(coarse.faces) < len(mesh.faces)


def interior(points, margin=1.0):
    """Points at least `margin` (world units) inside the data's box [1, 9]^3."""
    return np.all((points >= 1 + margin) & (points <= 9 - margin), axis=1)


@pytest.mark.slow
def test_the_amrex_surface_lies_on_its_value(tmp_path):
    import trimesh

    import exabricks as eb

    out = tmp_path / "phi.ply"
    run_cli("surface", AMREX, "--field", "phi", "--value", 1.2, "-o", out, check=0)
    mesh = trimesh.load(out, process=False)
    assert len(mesh.faces) > 10_000 and mesh.volume != 0
    values = eb.probe(eb.open(AMREX), np.asarray(mesh.vertices), "phi")
    assert np.all(np.isfinite(values))
    assert np.abs(values - 1.2).max() < 0.02, np.abs(values - 1.2).max()  # phi spans 0.99-1.97
    run_cli("surface", AMREX, "--field", "phi", "--value", 1.2, "-o", tmp_path / "phi.obj",
            "--level", 1, check=0)
    assert len(trimesh.load(tmp_path / "phi.obj", process=False).faces) < len(mesh.faces)


@pytest.mark.parametrize("args,needles", [
    (("--value", 5.0), ("no iso-surface of phi at 5", "ranges over")),
    (("--value", 1.2, "--level", 7), ("too coarse to mesh",)),
    (("--value", 1.2, "--max-points", 1000, "--level", 0), ("more than --max-points",)),
])
def test_bad_requests_end_in_one_line_and_no_file(tmp_path, args, needles):
    out = tmp_path / "x.ply"
    assert_one_error_line(run_cli("surface", AMREX, "--field", "phi", *args, "-o", out), *needles)
    assert not out.exists()


def test_bad_outputs_are_refused(tmp_path):
    assert_one_error_line(run_cli("surface", AMREX, "--field", "phi", "--value", 1.2, "-o",
                                  tmp_path / "x.txt"), "x.txt", ".ply, .obj or .stl")
    proc = run_cli("surface", AMREX, "--field", "phi", "--value", "nan", "-o", tmp_path / "y.ply")
    assert proc.returncode == 2
    assert not list(tmp_path.iterdir())
