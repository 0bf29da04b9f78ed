"""The scripts of workflows/ run for real (issue 12): the Make pipelines with
`make -j`, and the SLURM job scripts on a one-node cluster (tests marked `slurm`:
`make test-slurm` brings the cluster up with workflows/slurm/up.sh first, and CI
runs them). Every movie and frame is checked against one-process renders."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from exabricks.film.image_io import read_image

from helpers import GERRIS, ROOT

WORKFLOWS = ROOT / "workflows"
BIN = Path(sys.executable).parent
ENV = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}


def run(*cmd, cwd=None, timeout=900):
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, env=ENV,
                          cwd=cwd, timeout=timeout)
    assert proc.returncode == 0, f"{cmd}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


def eb(*args):
    return run(BIN / "exabricks", *args)


def movie_frames(path) -> int:
    import imageio.v3 as iio

    return sum(1 for _ in iio.imiter(path))


def assert_same_png(a, b):
    np.testing.assert_array_equal(read_image(a)[0], read_image(b)[0])


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    d = tmp_path_factory.mktemp("series")
    run(sys.executable, WORKFLOWS / "make_series.py", d, "--steps", 3)
    return sorted(d.glob("plt*"))


@pytest.mark.slow  # the orbit pipeline runs the same Makefile in the fast suite
def test_make_series_pipeline(series, tmp_path):
    out = tmp_path / "out"
    make = ["make", "-f", WORKFLOWS / "Makefile", "-j2", "series", f"SERIES={series[0].parent}/plt*",
            "FIELD=phi", f"OUT={out}", "RENDER=--size 64 48", "FPS=5"]
    run(*make)
    assert movie_frames(out / "movie.mp4") == 3
    lo, hi = (float(x) for x in (out / "range.txt").read_text().split())
    assert 0.0 <= lo < hi <= 1.0
    step = out / "steps" / series[1].name
    eb("render", step / "bricks.npz", step / "regions.npz", step / "bvh.npz", "-o",
       tmp_path / "direct.png", "--field", "phi", "--range", lo, hi, "--size", 64, 48)
    assert_same_png(out / "frames" / f"{series[1].name}.png", tmp_path / "direct.png")
    # everything is up to date: a second make has nothing to do
    assert subprocess.run([str(c) for c in make] + ["-q"], env=ENV).returncode == 0


@pytest.fixture(scope="module")
def fixed_series(tmp_path_factory):
    d = tmp_path_factory.mktemp("fixed")
    run(sys.executable, WORKFLOWS / "make_series.py", d, "--steps", 3, "--fixed-hierarchy")
    return sorted(d.glob("plt*"))


def assert_frame_is_a_full_rebuild(series, k, frame, range_file, tmp_path):
    """The frame of step k equals a render of that step's own structures."""
    lo, hi = range_file.read_text().split()
    d = tmp_path / f"rebuild{k}"
    d.mkdir()
    eb("ingest", series[k], "-o", d / "cells.npz")
    eb("brick", d / "cells.npz", "-o", d / "bricks.npz")
    eb("regions", d / "bricks.npz", "-o", d / "regions.npz")
    eb("bvh", d / "regions.npz", "-o", d / "bvh.npz")
    eb("render", d / "bricks.npz", d / "regions.npz", d / "bvh.npz", "-o", d / "direct.png",
       "--field", "phi", "--range", lo, hi, "--size", 64, 48)
    assert_same_png(frame, d / "direct.png")


@pytest.mark.slow
def test_make_series_on_a_fixed_hierarchy_takes_values(fixed_series, tmp_path):
    """Steps whose leaf cells are the first step's are only their values on its
    structures (workflows/series_step.sh), and their frames equal full rebuilds."""
    out = tmp_path / "out"
    make = ["make", "-f", WORKFLOWS / "Makefile", "-j2", "series",
            f"SERIES={fixed_series[0].parent}/plt*", "FIELD=phi", f"OUT={out}",
            "RENDER=--size 64 48", "FPS=5"]
    run(*make)
    first = out / "steps" / fixed_series[0].name
    for step in fixed_series[1:]:
        d = out / "steps" / step.name
        assert (d / "step.txt").read_text().split() == [str(first), str(d / "values.npz")]
        assert not (d / "bricks.npz").exists()
    assert movie_frames(out / "movie.mp4") == 3
    assert_frame_is_a_full_rebuild(fixed_series, 2, out / "frames" / f"{fixed_series[2].name}.png",
                                   out / "range.txt", tmp_path)
    assert subprocess.run([str(c) for c in make] + ["-q"], env=ENV).returncode == 0


@pytest.mark.slow
def test_make_orbit_pipeline(tmp_path):
    out = tmp_path / "out"
    run("make", "-f", WORKFLOWS / "Makefile", "-j2", "orbit", f"DATASET={GERRIS}", "FIELD=T",
        f"OUT={out}", "FRAMES=4", "RANGE=0 0.6", "RENDER=--size 48 32")
    assert movie_frames(out / "movie.mp4") == 4
    eb("render", out / "bricks.npz", out / "regions.npz", out / "bvh.npz", "--camera-path",
       out / "orbit.json", "--frame", 3, "-o", tmp_path / "f3.png", "--field", "T",
       "--range", 0, 0.6, "--size", 48, 32)
    assert_same_png(out / "frames" / "frame_00003.png", tmp_path / "f3.png")


# ---- SLURM ---------------------------------------------------------------------------

def _cluster_up() -> bool:
    if shutil.which("sinfo") is None:
        return False
    proc = subprocess.run(["sinfo", "-h", "-o", "%t"], capture_output=True, text=True)
    return proc.returncode == 0 and proc.stdout.split() and proc.stdout.split()[0] in (
        "idle", "mix", "alloc")


# CI sets EXABRICKS_SLURM=1 after bringing the cluster up: there these tests never skip.
needs_cluster = pytest.mark.skipif(
    not _cluster_up() and not os.environ.get("EXABRICKS_SLURM"),
    reason="no SLURM cluster here (make test-slurm brings one up)")


def sbatch(*args, cwd) -> str:
    """Submit, wait, and check that the job and all its array tasks COMPLETED
    (`sbatch --wait` can return 0 for a cancelled job)."""
    proc = run("sbatch", "--parsable", "--wait", *args, cwd=cwd)
    job = proc.stdout.strip().split(";")[0]
    assert_completed(job)
    return job


def assert_completed(job: str) -> None:
    proc = subprocess.run(["scontrol", "-o", "show", "job", job], capture_output=True, text=True)
    states = re.findall(r"JobState=(\S+)", proc.stdout)
    assert states and all(s == "COMPLETED" for s in states), proc.stdout


@pytest.fixture(scope="module")
def gerris_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("gerris")
    eb("ingest", GERRIS, "-o", d / "cells.npz")
    eb("brick", d / "cells.npz", "-o", d / "bricks.npz")
    eb("regions", d / "bricks.npz", "-o", d / "regions.npz")
    eb("bvh", d / "regions.npz", "-o", d / "bvh.npz")
    return [d / f"{n}.npz" for n in ("bricks", "regions", "bvh")]


@pytest.mark.parametrize("per_task", [1, 2])
@pytest.mark.slurm
@needs_cluster
def test_slurm_frames_array_and_movie(gerris_files, tmp_path, per_task):
    path = tmp_path / "orbit.json"
    eb("camera", "orbit", gerris_files[0], "--frames", 5, "-o", path)
    opts = ["--field", "T", "--size", 40, 32]
    tasks = -(-5 // per_task)
    env_prefix = f"--export=ALL,FRAMES_PER_TASK={per_task}"
    job = sbatch(env_prefix, f"--array=0-{tasks - 1}", "-o", tmp_path / "task-%a.log",
                 WORKFLOWS / "slurm" / "render_frames.sbatch", path, tmp_path / "frames",
                 *gerris_files, *opts, cwd=tmp_path)
    sbatch(f"--dependency=afterok:{job}", "--kill-on-invalid-dep=yes", "-o", tmp_path / "movie.log", "--wrap",
           f"{BIN / 'exabricks'} movie '{tmp_path}/frames/*.png' -o {tmp_path / 'orbit.mp4'}",
           cwd=tmp_path)
    assert movie_frames(tmp_path / "orbit.mp4") == 5
    frames = sorted((tmp_path / "frames").glob("*.png"))
    assert [f.name for f in frames] == [f"frame_{i:05d}.png" for i in range(5)]
    eb("render", *gerris_files, "--camera-path", path, "--frame", 4, "-o", tmp_path / "f4.png", *opts)
    assert_same_png(frames[4], tmp_path / "f4.png")


@pytest.mark.parametrize("launch", ["srun --mpi=pmi2", "mpiexec"])
@pytest.mark.slurm
@needs_cluster
def test_slurm_mpi_frame(gerris_files, tmp_path, launch):
    opts = ["--field", "T", "--size", 64, 48, "--max-opacity", 1]
    sbatch("-n", 3, f"--export=ALL,MPI_LAUNCH={launch}", "-o", tmp_path / "mpi.log",
           WORKFLOWS / "slurm" / "render_mpi.sbatch", tmp_path / "mpi.exr", *gerris_files, *opts,
           cwd=tmp_path)
    eb("render", *gerris_files, "-o", tmp_path / "one.exr", *opts)
    a, meta = read_image(tmp_path / "mpi.exr")
    b, _ = read_image(tmp_path / "one.exr")
    assert meta["settings"]["mpi"]["ranks"] == 3
    assert float(np.sqrt(np.mean((a - b) ** 2))) <= 1e-5 * float(np.abs(b).max())


@pytest.mark.slurm
@needs_cluster
def test_slurm_series_with_dependencies(fixed_series, tmp_path):
    """Step 0's task first, the others on its structures (a fixed hierarchy: their
    values only), then the range, the frames and the movie."""
    out = tmp_path / "out"
    env = {**ENV, "FIELD": "phi", "RENDER_OPTIONS": "--size 64 48", "WAIT": "1", "FPS": "5"}
    proc = subprocess.run([str(WORKFLOWS / "slurm" / "series.sh"), str(out), *map(str, fixed_series)],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    jobs = dict(part.split("=") for part in proc.stdout.split())
    assert set(jobs) == {"hierarchy", "preprocess", "range", "render", "movie"}
    for job in jobs.values():
        assert_completed(job)
    assert movie_frames(out / "movie.mp4") == 3
    assert (out / "step_00002" / "step.txt").read_text().split() == [
        str(out / "step_00000"), str(out / "step_00002" / "values.npz")]
    assert_frame_is_a_full_rebuild(fixed_series, 2, out / "frames" / "frame_00002.png",
                                   out / "range.txt", tmp_path)


@pytest.mark.slurm
@needs_cluster
def test_slurm_failed_task_stops_what_depends_on_it(tmp_path):
    """A preprocessing task that fails (an input that is not a dataset) leaves the
    render and movie jobs never run, and series.sh with WAIT=1 fails."""
    bogus = tmp_path / "plt_bogus"
    bogus.write_text("not a plotfile")
    env = {**ENV, "FIELD": "phi", "WAIT": "1"}
    proc = subprocess.run([str(WORKFLOWS / "slurm" / "series.sh"), str(tmp_path / "out"), str(bogus)],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert proc.returncode != 0
    assert not (tmp_path / "out" / "movie.mp4").exists()
    assert not list((tmp_path / "out").glob("step_*/cells.npz"))


@pytest.mark.slow
def test_field_range_over_a_series(series, tmp_path, cli):
    """`info --field-range` is the union of the files' ranges; a field one file lacks
    is one error line naming that file."""
    from helpers import assert_one_error_line

    from exabricks import schema

    cells = []
    for k, plotfile in enumerate(series):
        cells.append(tmp_path / f"c{k}.npz")
        cli("ingest", plotfile, "-o", cells[-1], check=0)
    lo, hi = (float(x) for x in cli("info", "--field-range", "phi", *cells, check=0).stdout.split())
    each = [schema.load(c).values[0] for c in cells]
    assert lo == min(float(v.min()) for v in each) and hi == max(float(v.max()) for v in each)
    proc = cli("info", "--field-range", "rho", *cells)
    assert_one_error_line(proc, str(cells[0]), "no field 'rho'")


@pytest.mark.slurm
@needs_cluster
def test_slurm_build_by_pieces(tmp_path):
    """build_pieces.sh: brick, regions and bvh each as a 3-task array and a join,
    chained by dependencies, on the thin-shell layout (every stage really splits);
    the three files equal the one-process build array for array."""
    from benchmarks.make_big import thin_shell_cells

    from exabricks import schema

    schema.save(tmp_path / "cells.npz", thin_shell_cells(256))
    out = tmp_path / "out"
    proc = subprocess.run([str(WORKFLOWS / "slurm" / "build_pieces.sh"), str(tmp_path / "cells.npz"),
                           str(out), "3"], capture_output=True, text=True,
                          env={**ENV, "WAIT": "1"}, cwd=tmp_path, timeout=900)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    jobs = dict(part.split("=") for part in proc.stdout.split())
    assert set(jobs) == {f"{n}{j}" for n in ("bricks", "regions", "bvh") for j in ("", "-join")}
    for job in jobs.values():
        assert_completed(job)
    src = tmp_path / "cells.npz"
    for stage, name in (("brick", "bricks"), ("regions", "regions"), ("bvh", "bvh")):
        eb(stage, src, "-o", tmp_path / f"{name}.npz")
        src = tmp_path / f"{name}.npz"
        whole, joined = schema.load(src, name), schema.load(out / f"{name}.npz", name)
        for k, v in whole.arrays().items():
            np.testing.assert_array_equal(v, joined.arrays()[k], err_msg=f"{name} {k}")
        assert len(list((out / "pieces").glob(f"{name}.*.npz"))) == 3
