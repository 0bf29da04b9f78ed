"""The hostile cases of issue 49 (round 3) that are not the cache's or the viewer's,
each reproduced once and kept as a regression test: FIFOs that hung format
detection, options that overflow the float32 the kernels read, mesh cache entries
swapped with each other, meshes refused with the parser's internals, the library's
kinds of error, messages that blamed the wrong thing, and the compiler's line before
the interrupted one. Each ends in success or one `error:` line with exit 1, with
nothing half-written."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from exabricks.util.errors import ExabricksError

from helpers import DEVICES, GERRIS, assert_one_error_line

TIMEOUT = 120


def run(*args, timeout=TIMEOUT, **kw):
    """`exabricks ARGS` with a time limit: a hang fails the test instead of blocking it."""
    return subprocess.run([sys.executable, "-m", "exabricks.cli.main", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, **kw)


# ---------------------------------------------------------------------------
# 7. a FIFO where format detection looks


def fifo_plotfile(tmp_path: Path, *, level0: bool = True) -> Path:
    plt = tmp_path / "plt00000"
    plt.mkdir()
    if level0:
        (plt / "Level_0").mkdir()
    os.mkfifo(plt / "Header")
    return plt


@pytest.mark.parametrize("level0", [True, False], ids=["plotfile", "bare-dir"])
@pytest.mark.parametrize("command", ["ingest", "values", "surface", "render"])
def test_a_fifo_header_is_refused_not_waited_on(plume_trio, tmp_path, command, level0):
    plt = fifo_plotfile(tmp_path, level0=level0)
    out = tmp_path / {"ingest": "c.npz", "values": "v.npz", "surface": "s.ply",
                      "render": "r.png"}[command]
    extra = {"values": ["--bricks", plume_trio[0]], "surface": ["--value", "1"],
             "render": ["--size", "8", "8"]}.get(command, [])
    proc = run(command, plt, *extra, "-o", out, timeout=60)
    assert_one_error_line(proc, "Header", "FIFO")
    assert not out.exists()


def test_format_detection_never_opens_a_fifo(tmp_path):
    from exabricks.readers import guess_format
    fifo = tmp_path / "data.hdf5"
    os.mkfifo(fifo)
    with pytest.raises(ExabricksError, match="FIFO"):
        guess_format(fifo)
    with pytest.raises(ExabricksError, match="FIFO"):
        guess_format(fifo_plotfile(tmp_path, level0=False))


# ---------------------------------------------------------------------------
# 3. options that overflow the float32 the kernels read


@pytest.mark.parametrize("flag", ["--lod", "--specular", "--sampling-rate", "--iso"])
def test_a_float_option_beyond_float32_is_refused(tmp_path, flag):
    out = tmp_path / "r.png"
    proc = run("render", GERRIS, flag, "1e39", "--size", "8", "8", "-o", out)
    assert proc.returncode == 2, proc.stderr
    assert flag in proc.stderr and "float32" in proc.stderr
    assert not out.exists()


def test_lod_beyond_float32_is_refused_in_a_scene_file_and_the_library(tmp_path):
    scene = tmp_path / "scene.json"
    scene.write_text('{"lod": 1e39}')
    out = tmp_path / "r.png"
    assert_one_error_line(run("render", GERRIS, "--scene", scene, "--size", "8", "8", "-o", out),
                          "lod")
    assert not out.exists()
    from exabricks.scene.options import SCENE_OPTIONS
    lod = next(o for o in SCENE_OPTIONS if o.name == "lod")
    assert lod.coerce(3e38) == 3e38
    with pytest.raises(ExabricksError, match="lod.*float32"):
        lod.coerce(1e39)


# ---------------------------------------------------------------------------
# 18. messages that named the wrong problem


def test_a_far_camera_is_not_called_the_same_point(tmp_path):
    from exabricks.picture.camera import Camera
    out = tmp_path / "r.png"
    proc = run("render", GERRIS, "--position", "1e300", "1e300", "1e300", "--size", "8", "8",
               "-o", out)
    assert_one_error_line(proc, "position", "float32")
    assert "same point" not in proc.stderr
    with pytest.raises(ExabricksError, match="too far apart"):
        Camera(position=(3e38, 3e38, 3e38), look_at=(-3e38, -3e38, -3e38), up=(0, 1, 0))


def test_a_huge_range_names_the_range_not_a_nan_in_the_colour_map(tmp_path):
    from exabricks.picture.transfer_function import TransferFunction
    with pytest.raises(ExabricksError, match=r"range \[-1e\+308, 1e\+308\].*float32"):
        TransferFunction.from_colormap("viridis", (-1e308, 1e308))
    scene = tmp_path / "scene.json"
    scene.write_text('{"volumes": [{"field": "T", "transfer_function": "default", "range": [-1e308, 1e308]}]}')
    out = tmp_path / "r.png"
    proc = run("render", GERRIS, "--scene", scene, "--size", "8", "8", "-o", out)
    assert_one_error_line(proc, "range", "float32")
    assert "NaN" not in proc.stderr and "non-finite" not in proc.stderr


def test_a_block_device_output_is_called_a_block_device():
    import stat
    blocks = [p for p in ("/dev/loop0", "/dev/vda", "/dev/sda", "/dev/nvme0n1")
              if os.path.exists(p) and stat.S_ISBLK(os.stat(p).st_mode)]
    if not blocks:
        pytest.skip("no block device here")
    from exabricks.util.output import check_output
    with pytest.raises(ExabricksError, match="a block device") as info:
        check_output(blocks[0], ())
    assert "not a regular file, device" not in str(info.value)


# ---------------------------------------------------------------------------
# 1 (meshes). a mesh cache entry swapped with another's


def tetrahedron(path: Path, shift: float) -> Path:
    path.write_text("".join(f"v {x + shift} {y} {z}\n" for x, y, z in
                            ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)))
                    + "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    return path


@pytest.mark.parametrize("how", ["copy", "symlink"])
def test_a_mesh_entry_swapped_with_anothers_is_rebuilt(tmp_path, monkeypatch, caplog, how):
    import shutil

    from exabricks import cache, mesh

    monkeypatch.setenv("EXABRICKS_CACHE", str(tmp_path / "cache"))
    a, b = tetrahedron(tmp_path / "a.obj", 0.0), tetrahedron(tmp_path / "b.obj", 5.0)
    mesh._mesh_set.cache_clear()
    built_a = mesh.mesh_set((str(a),))
    built_b = mesh.mesh_set((str(b),))
    store = cache.Cache(tmp_path / "cache")
    entry_a = store.paths(cache.mesh_key([a]), cache.MESH_FILES)[0]
    entry_b = store.paths(cache.mesh_key([b]), cache.MESH_FILES)[0]
    entry_a.unlink()
    if how == "copy":
        shutil.copyfile(entry_b, entry_a)
    else:
        entry_a.symlink_to(entry_b)
    mesh._mesh_set.cache_clear()
    caplog.clear()
    again = mesh.mesh_set((str(a),))
    np.testing.assert_array_equal(again.triangles, built_a.triangles)
    assert not np.array_equal(again.triangles, built_b.triangles)
    assert any("another cache entry" in r.getMessage() for r in caplog.records), \
        [r.getMessage() for r in caplog.records]


# ---------------------------------------------------------------------------
# 15. valid meshes refused with the parser's internals, and lies named


TETRA_V = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
TETRA_F = "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def ply_text(comment: bytes = b"", vertices: int = 4) -> bytes:
    return (b"ply\nformat ascii 1.0\n" + comment +
            f"element vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 4\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n".encode())


@pytest.mark.parametrize("name,data", [
    ("latin1.obj", b"# caf\xe9\n" + (TETRA_V + TETRA_F).encode()),
    ("bom.obj", b"\xef\xbb\xbf" + (TETRA_V + TETRA_F).encode()),
    ("latin1.ply", ply_text(b"comment caf\xe9\n")),
])
def test_valid_meshes_with_odd_bytes_load(tmp_path, name, data):
    from exabricks.mesh import read_mesh
    path = tmp_path / name
    path.write_bytes(data)
    m = read_mesh(path)
    assert len(m.vertices) == 4 and len(m.faces) == 4


@pytest.mark.parametrize("name,data,needles", [
    ("zero.obj", (TETRA_V + "f 0 1 2\n").encode(), ("line 5", "index 0")),
    ("lying.ply", ply_text(vertices=100), ("'vertex'", "100")),
])
def test_broken_meshes_name_the_real_problem(tmp_path, name, data, needles):
    from exabricks.mesh import read_mesh
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(ExabricksError) as info:
        read_mesh(path)
    for n in needles:
        assert n in str(info.value), str(info.value)


# ---------------------------------------------------------------------------
# 16. the library's kinds of error: ExabricksError naming the input, never a
# ValueError from deep inside


@pytest.fixture(scope="module")
def plume_dataset():
    import exabricks as eb
    return eb.open(GERRIS)


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("call,needles", [
    (lambda eb, ds, tmp: eb.open(""), ("empty path",)),
    (lambda eb, ds, tmp: eb.render(ds, spp=NAN, size=(8, 8)), ("spp", "nan")),
    (lambda eb, ds, tmp: eb.Renderer(ds).scene(spp=NAN), ("spp", "nan")),
    (lambda eb, ds, tmp: eb.render(ds, size=(NAN, 8)), ("size", "nan")),
    (lambda eb, ds, tmp: eb.render(ds, seed=INF, size=(8, 8)), ("seed", "inf")),
    (lambda eb, ds, tmp: eb.render(ds, spp=1 + 2j, size=(8, 8)), ("spp", "(1+2j)")),
    (lambda eb, ds, tmp: eb.render_job(ds, tmp / "r.png", spp=NAN, size=(8, 8)), ("spp", "nan")),
    (lambda eb, ds, tmp: eb.render_job(ds, tmp / "r.txt", size=(8, 8)), (".exr or .png",)),
    (lambda eb, ds, tmp: eb.render_job(ds, tmp / "r.png", title="t", size=(8, 8)), ("--annotate",)),
    (lambda eb, ds, tmp: eb.probe(ds, "pts"), ("points", "'pts'", "numpy.load")),
    (lambda eb, ds, tmp: eb.probe(ds, [[0, 0, 0], [1, 2]]), ("points", "(N, 3)")),
    (lambda eb, ds, tmp: eb.probe(ds, [[None, 0, 0]]), ("points", "object")),
], ids=["open-empty", "render-spp-nan", "scene-spp-nan", "size-nan", "seed-inf", "spp-complex",
        "job-spp-nan", "job-suffix", "job-title", "probe-string", "probe-ragged", "probe-none"])
def test_the_library_raises_exabricks_errors_naming_the_input(plume_dataset, tmp_path, call,
                                                              needles):
    import exabricks as eb
    with pytest.raises(eb.ExabricksError) as info:
        call(eb, plume_dataset, tmp_path)
    for n in needles:
        assert n in str(info.value), str(info.value)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("points", [np.array([[1 + 1j, 0, 0]]), [[0.5, 0.5, 0.5j]],
                                    np.zeros((2, 3), np.complex64)], ids=["array", "list", "zero-imag"])
def test_complex_points_are_refused_not_cut_to_their_real_part(plume_dataset, points):
    import warnings

    import exabricks as eb
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's ComplexWarning: the cast must not happen
        with pytest.raises(eb.ExabricksError, match="points: complex"):
            eb.probe(plume_dataset, points)


def test_a_fifo_given_as_a_mesh_is_not_called_missing(plume_dataset, tmp_path):
    import exabricks as eb
    fifo = tmp_path / "m.obj"
    os.mkfifo(fifo)
    with pytest.raises(eb.ExabricksError) as info:
        eb.Renderer(plume_dataset).scene(mesh=str(fifo))
    assert "a FIFO" in str(info.value) and "no such file" not in str(info.value), str(info.value)
    with pytest.raises(eb.ExabricksError, match="mesh: .*no such file"):
        eb.Renderer(plume_dataset).scene(mesh=str(tmp_path / "gone.obj"))
    out = tmp_path / "r.png"
    assert_one_error_line(run("render", GERRIS, "--mesh", fifo, "--size", "8", "8", "-o", out),
                          str(fifo), "a FIFO, not a regular file")
    assert not out.exists()


def test_a_title_longer_than_a_line_is_refused_before_drawing(plume_dataset, tmp_path):
    import exabricks as eb
    from exabricks.util.constants import MAX_TITLE_CHARS
    image = eb.Image(np.zeros((8, 8, 4), np.float32), scene=eb.Renderer(plume_dataset).scene(
        size=(8, 8)))
    out = tmp_path / "t.png"
    with pytest.raises(eb.ExabricksError, match=f"title: 100,000 characters.*{MAX_TITLE_CHARS}"):
        image.save(out, annotate=True, title="x" * 100_000)
    assert not out.exists()
    image.save(out, annotate=True, title="x" * MAX_TITLE_CHARS)  # the longest allowed is drawn
    assert out.is_file()
    out.unlink()
    proc = run("render", GERRIS, "--annotate", "--title", "x" * 100_000, "--size", "8", "8",
               "-o", out)
    assert proc.returncode == 2 and "--title" in proc.stderr and "Traceback" not in proc.stderr, \
        proc.stderr
    assert not out.exists()


# ---------------------------------------------------------------------------
# 17. a signal during a kernel build: the compiler's "1 error generated." stays unsaid


def test_a_signal_during_a_kernel_build_leaves_one_error_line(plume_trio, tmp_path):
    """PoCL compiles in the process with clang, whose own handlers of SIGINT and SIGTERM
    remove the temporary file it is writing: a signal then makes the build fail with
    "1 error generated." on stderr, before the run's `error: interrupted`. The signals
    go, in a burst, from the moment that temporary file appears in PoCL's (empty)
    kernel cache until the process ends."""
    import signal

    if not DEVICES:
        pytest.skip("no OpenCL device")
    cache = tmp_path / "pocl"
    cache.mkdir()
    env = {**os.environ, "POCL_CACHE_DIR": str(cache), "PYOPENCL_NO_CACHE": "1"}
    out = tmp_path / "r.png"
    proc = subprocess.Popen([sys.executable, "-m", "exabricks.cli.main", "render", *plume_trio,
                             "--size", "8", "8", "-o", out], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        firing = False
        while proc.poll() is None:
            firing = firing or any(name.endswith(".tmp") for name in os.listdir(cache))
            if firing:
                proc.send_signal(signal.SIGINT)
            time.sleep(0.0005)
        stderr = proc.communicate(timeout=TIMEOUT)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    if not firing:
        pytest.skip("the driver wrote no compiler temporary file (not PoCL's in-process clang)")
    assert proc.returncode == 130 and stderr.splitlines() == ["error: interrupted (SIGINT)"], \
        (proc.returncode, stderr)
    assert not out.exists()
