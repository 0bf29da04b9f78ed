"""`mpiexec -n N exabricks render` (exabricks/parallel.py, issue 12) with pip's
MPICH: the image of N ranks equals the one-process image (data-parallel: RMSE
at most 1e-5 of the maximum with early termination off; image-parallel: the
same pixels, since every pixel is the same kernel's), and a failing run ends
every rank with one `error:` line and no output."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from exabricks.film.image_io import read_image

from helpers import AMREX, GERRIS, assert_one_error_line
from helpers.mpi import EB, FLAGS, MPIEXEC, files_of, mpirun, same_image


@pytest.fixture(scope="module")
def gerris(tmp_path_factory):
    return files_of(tmp_path_factory, GERRIS, "T")


@pytest.fixture(scope="module")
def amrex(tmp_path_factory):
    return files_of(tmp_path_factory, AMREX, "phi")


def test_mpi_is_installed():
    """CI has pip's MPICH and mpi4py (the dev and mpi extras): no MPI test is skipped."""
    assert MPIEXEC.exists(), MPIEXEC
    import mpi4py  # noqa: F401


@pytest.mark.parametrize("dataset,n", [("gerris", 2), pytest.param("gerris", 3, marks=pytest.mark.slow),
                                       pytest.param("amrex", 2, marks=pytest.mark.slow),
                                       pytest.param("amrex", 3, marks=pytest.mark.slow)])
def test_data_parallel_equals_one_process(request, dataset, n, cli, tmp_path):
    files = request.getfixturevalue(dataset)
    extra = ["--spp", 2, "--gradient", "central", "--slice", 0.5, 0.5, 0.5, 0, 0, 1] \
        if dataset == "amrex" else ["--shading", "none"]
    cli("render", *files, "-o", tmp_path / "one.exr", *FLAGS, *extra, check=0)
    proc = mpirun(n, "render", *files, "-o", tmp_path / "many.exr", *FLAGS, *extra)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    same_image(tmp_path / "many.exr", tmp_path / "one.exr")
    meta = read_image(tmp_path / "many.exr")[1]
    assert meta["settings"]["mpi"] == {"ranks": n, "mode": "data"}


@pytest.mark.slow  # 7 s: two ranks and one process
def test_shadows_in_data_mode_are_the_one_process_frame(gerris, cli, tmp_path):
    """Each rank adds its domain's part of the light's cached transmittance, and the
    ranks sum them (exabricks.engine.light_volume): the one-process frame, to where
    each part's march stops on its own past T = 10^-3 (tests/engine/test_light_volume.py)."""
    flags = [*FLAGS, "--integrator", "shadow"]
    cli("render", *gerris, "-o", tmp_path / "one.exr", *flags, check=0)
    proc = mpirun(2, "render", *gerris, "-o", tmp_path / "many.exr", *flags)
    assert proc.returncode == 0, proc.stderr
    (many, meta), (one, _) = read_image(tmp_path / "many.exr"), read_image(tmp_path / "one.exr")
    assert meta["settings"]["mpi"] == {"ranks": 2, "mode": "data"}
    assert one[..., 3].max() > 0.1
    assert float(np.sqrt(np.mean((many - one) ** 2))) <= 1e-4 * float(np.abs(one).max())


@pytest.mark.parametrize("mode", ["data", "image"])
@pytest.mark.slow
def test_exposure_under_mpi_is_the_one_process_frame(gerris, cli, tmp_path, mode):
    """The film develops the composite of every rank once (tests/film/test_film.py holds
    the one-process frame to the definition)."""
    film = ["--exposure", 1.5, "--background", "0.1,0.2,0.3", "--shading", "none"]
    cli("render", *gerris, "-o", tmp_path / "one.exr", *FLAGS, *film, check=0)
    proc = mpirun(2, "render", *gerris, "-o", tmp_path / "many.exr", *FLAGS, *film, "--mpi-mode", mode)
    assert proc.returncode == 0, proc.stderr
    same_image(tmp_path / "many.exr", tmp_path / "one.exr", exact=mode == "image")


@pytest.mark.slow
def test_image_parallel_and_fallback(amrex, cli, tmp_path):
    iso = ["--iso", 0.5, "--depth", "--ao-samples", 2]
    cli("render", *amrex, "-o", tmp_path / "one.exr", *FLAGS, *iso, check=0)
    for mode in ("image", "data"):  # data mode takes image mode for iso-surfaces and AO
        out = tmp_path / f"{mode}.exr"
        proc = mpirun(3, "render", *amrex, "-o", out, *FLAGS, *iso, "--mpi-mode", mode)
        assert proc.returncode == 0, proc.stderr
        same_image(out, tmp_path / "one.exr", exact=True)
        mpi = read_image(out)[1]["settings"]["mpi"]
        assert mpi["mode"] == "image" and mpi["ranks"] == 3
    assert mpi["image_mode_for"] == "iso-surfaces"


def test_camera_path_frames_under_mpi(gerris, cli, tmp_path):
    path = tmp_path / "orbit.json"
    cli("camera", "orbit", gerris[0], "--frames", 4, "-o", path, check=0)
    proc = mpirun(2, "render", *gerris, "--camera-path", path, "--frames", "1:3",
                  "-o", tmp_path / "f%d.png", "--size", 40, 30)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in tmp_path.glob("f*.png")) == ["f1.png", "f2.png"]


def test_an_error_on_every_rank_is_one_line(gerris, tmp_path):
    out = tmp_path / "x.png"
    proc = mpirun(3, "render", *gerris, "-o", out, "--field", "nope")
    assert_one_error_line(proc, "nope")
    proc = mpirun(3, "render", gerris[0], gerris[1], gerris[0], "-o", out)
    assert_one_error_line(proc, "expected a bvh file")
    proc = mpirun(2, "render", *gerris, "-o", out, "--no-such-flag")
    assert proc.returncode == 2 and proc.stderr.count("No such option") == 1
    assert not out.exists()


def test_an_error_on_one_rank_ends_every_rank(gerris, tmp_path):
    """Rank 1 alone cannot find its device (MPMD: its own environment): every rank
    stops, rank 0 reports rank 1's error, no image is written."""
    out = tmp_path / "x.png"
    args = [*EB, "render", *map(str, gerris), "-o", str(out)]
    cmd = [str(MPIEXEC), "-n", "1", *args, ":", "-n", "1", "-env", "EXABRICKS_DEVICE", "9:9",
           *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert_one_error_line(proc, "rank 1:", "9:9")
    assert not out.exists()


def test_srun_without_mpi_is_refused(gerris, tmp_path):
    """Several tasks of `srun` without `--mpi=pmi2` would each write the whole frame."""
    from helpers import run_cli

    proc = run_cli("render", *gerris, "-o", tmp_path / "x.png",
                   env={"SLURM_STEP_NUM_TASKS": "3"})
    assert_one_error_line(proc, "srun", "--mpi=pmi2")


@pytest.mark.parametrize("array, value, needle", [
    ("brick_ids", 10**6, "lists brick 1000000"),
    ("brick_start", -5, "out of order"),
])
def test_crafted_regions_under_data_parallel_mpi(gerris, tmp_path, array, value, needle):
    """A rank maps the files and checks only what its domain takes: a corrupt list
    is still caught before any kernel reads it, with one error line."""
    with np.load(gerris[1]) as z:
        arrays = {k: z[k].copy() for k in z.files}
    arrays[array][len(arrays[array]) // 2] = value
    bad = tmp_path / "regions.npz"
    np.savez(bad, **arrays)
    out = tmp_path / "x.png"
    proc = mpirun(2, "render", gerris[0], bad, gerris[2], "-o", out)
    assert_one_error_line(proc, str(bad), needle)
    assert not out.exists()


@pytest.mark.slow
def test_the_library_and_a_source_under_mpiexec(tmp_path):
    """`mpiexec -n 2 python script.py` with eb.render_job of a source: rank 0 builds
    it into the cache, the other rank loads that entry, and the frame is one
    process's; `eb.render` refuses to run under MPI."""
    script = tmp_path / "job.py"
    script.write_text(
        "import sys\nimport exabricks as eb\n"
        "ds = eb.open(sys.argv[1])\n"
        "eb.render_job(ds, sys.argv[2], field='T', size=(72, 48), max_opacity=1)\n"
        "try:\n    eb.render(ds, field='T')\nexcept eb.ExabricksError as e:\n    print(f'refused: {e}', flush=True)\n")
    env = {**os.environ, "EXABRICKS_CACHE": str(tmp_path / "cache")}
    proc = subprocess.run([str(MPIEXEC), "-n", "2", sys.executable, str(script), str(GERRIS),
                           str(tmp_path / "mpi.exr")], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr
    # each rank's line (the launcher may interleave the two ranks' writes)
    assert proc.stdout.count("under MPI a frame is drawn by every rank together") == 2
    entries = [p for p in (tmp_path / "cache").iterdir() if (p / "entry.json").is_file()]
    assert len(entries) == 1
    subprocess.run([*EB, "render", str(GERRIS), "--field", "T", "--size", "72", "48", "--max-opacity",
                    "1", "-o", str(tmp_path / "one.exr")], check=True, env=env)
    same_image(tmp_path / "mpi.exr", tmp_path / "one.exr")


@pytest.mark.slow
@pytest.mark.parametrize("what", ["meshes", "instances", "mixture"])
def test_meshes_and_instances_under_mpi_take_image_mode(gerris, cli, tmp_path, what):
    """A frame with a mesh (which reaches beyond the data, where no domain is), a
    mirrored copy (drawn from the whole dataset), or a mirror through the data
    (a mixture) is split by the image: the same image as one process."""
    if what == "meshes":
        import trimesh

        sphere = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
        sphere.apply_translation((64.0, 40.0, 64.0))
        mesh = tmp_path / "sphere.ply"
        sphere.export(mesh)
        extra = ["--mesh", mesh, "--mesh-opacity", 0.6]
    else:
        extra = ["--mirror", "x", 0 if what == "instances" else 60]
    flags = [*FLAGS, *extra, "--shading", "none"]
    cli("render", *gerris, "-o", tmp_path / "one.exr", *flags, check=0)
    out = tmp_path / "data.exr"
    proc = mpirun(2, "render", *gerris, "-o", out, *flags)
    assert proc.returncode == 0, proc.stderr
    same_image(out, tmp_path / "one.exr", exact=True)
    settings = read_image(out)[1]["settings"]
    assert settings["mpi"]["image_mode_for"] == ("meshes" if what == "meshes" else "instances")
    assert (settings.get("instance_order") == "mixture") == (what == "mixture")
