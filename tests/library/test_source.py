"""`render SOURCE` and `probe SOURCE`: structures built with the builders' defaults
(bit for bit the staged pipeline's image), kept in the content cache
(exabricks.cache), and `exabricks cache info|clear`."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from helpers import AMREX, ATHENA, ENZO, GERRIS, assert_one_error_line, run_cli

FRAME = ("--size", "96", "80", "--spp", "1")
SOURCES = {"gerris": (GERRIS, ("--field", "T")), "amrex": (AMREX, ("--field", "phi")),
           "athena": (ATHENA, ("--field", "rho")), "enzo": (ENZO, ("--field", "Density"))}


def staged(tmp_path, source, ingest_args=()):
    """The three structure files of `source` by the staged commands."""
    cells, b, r, v = (tmp_path / n for n in ("cells.npz", "bricks.npz", "regions.npz", "bvh.npz"))
    run_cli("ingest", source, "-o", cells, *ingest_args, check=0)
    run_cli("brick", cells, "-o", b, check=0)
    run_cli("regions", b, "-o", r, check=0)
    run_cli("bvh", r, "-o", v, check=0)
    return b, r, v


def pixels(path):
    from exabricks.film.image_io import read_image

    return read_image(path)[0]


def entries(cache):
    return sorted(p.name for p in cache.iterdir() if (p / "entry.json").is_file())


@pytest.mark.parametrize("name", ["gerris", "amrex", "athena", "enzo"])
@pytest.mark.slow
def test_render_source_is_the_staged_image_bit_for_bit(tmp_path, name):
    source, view = SOURCES[name]
    trio = staged(tmp_path, source)
    cache = tmp_path / "cache"
    run_cli("render", *trio, "-o", tmp_path / "staged.exr", *view, *FRAME, "--iso", "0.5",
            "--iso-opacity", "0.4", check=0)
    args = (source, *view, *FRAME, "--iso", "0.5", "--iso-opacity", "0.4")
    run_cli("render", *args, "-o", tmp_path / "cold.exr", "--cache", cache, check=0)
    run_cli("render", *args, "-o", tmp_path / "warm.exr", "--cache", cache, check=0)
    run_cli("render", *args, "-o", tmp_path / "memory.exr", "--no-cache", check=0)
    expected = pixels(tmp_path / "staged.exr")
    assert expected[..., 3].max() > 0.1
    for image in ("cold", "warm", "memory"):
        np.testing.assert_array_equal(pixels(tmp_path / f"{image}.exr"), expected, err_msg=image)
    assert len(entries(cache)) == 1


@pytest.mark.slow
def test_probe_source_equals_staged_and_ingest_options_reach_the_build(tmp_path):
    derived = ("--magnitude", "speed=U,V,W", "--derive", "hot=where(T > 0.3, speed * 2 + T, 0)")
    trio = staged(tmp_path, GERRIS, ("--fields", "T,speed,hot", *derived))
    rng = np.random.default_rng(7)
    from exabricks import schema

    lo, hi = (np.array(x) for x in schema.world_bounds(schema.load(trio[0])))
    np.save(tmp_path / "p.npy", lo + rng.random((500, 3)) * (hi - lo))
    for field in ("hot",):  # made of a magnitude and an expression
        run_cli("probe", *trio, "--points", tmp_path / "p.npy", "--field", field, "-o",
                tmp_path / "staged.npy", check=0)
        run_cli("probe", GERRIS, "--fields", "T,speed,hot", *derived, "--points", tmp_path / "p.npy",
                "--field", field, "-o", tmp_path / "source.npy", check=0)
        expected = np.load(tmp_path / "staged.npy")
        assert np.isfinite(expected).sum() > 400 and np.abs(expected).max() > 0
        np.testing.assert_array_equal(np.load(tmp_path / "source.npy"), expected)
        # the cells file is a source too
        run_cli("probe", tmp_path / "cells.npz", "--points", tmp_path / "p.npy", "--field", field,
                "-o", tmp_path / "cells.npy", check=0)
        np.testing.assert_array_equal(np.load(tmp_path / "cells.npy"), expected)
    assert_one_error_line(run_cli("render", GERRIS, "--derive", "bad=T +", "-o", tmp_path / "x.png"),
                          str(GERRIS), "derived field 'bad'")


@pytest.fixture
def own_plume(tmp_path):
    """A copy of the Gerris plume that a test may change."""
    d = tmp_path / "plume"
    shutil.copytree(GERRIS.parent, d)
    return d / GERRIS.name


@pytest.mark.slow
def test_the_cache_keys_by_content_and_options(tmp_path, own_plume):
    cache = tmp_path / "cache"
    render = lambda *extra: run_cli("render", own_plume, "--field", "T", *FRAME, "-o",  # noqa: E731
                                    tmp_path / "a.png", "--cache", cache, *extra, check=0)
    render()
    first = entries(cache)
    built = (cache / first[0] / "bricks.npz").stat().st_mtime_ns
    render()
    assert entries(cache) == first  # a hit: nothing built again
    assert (cache / first[0] / "bricks.npz").stat().st_mtime_ns == built
    render("--fields", "T")  # other options: another entry
    assert len(entries(cache)) == 2
    # a sibling that the reader reads (a .scalars file) changes: a miss, never a stale entry
    scalars = own_plume.with_name("plume7-1.T.scalars")
    data = bytearray(scalars.read_bytes())
    data[-1] ^= 1
    scalars.write_bytes(bytes(data))
    render()
    assert len(entries(cache)) == 3
    info = json.loads(run_cli("cache", "info", "--json", "--cache", cache, check=0).stdout)
    assert info["entries"] == 3 and info["bytes"] > 3 * 1_000_000
    assert {s["path"] for s in info["sources"]} == {str(own_plume)}


def test_cache_clear_removes_only_its_own(tmp_path):
    cache = tmp_path / "cache"
    run_cli("render", GERRIS, "--field", "T", *FRAME, "-o", tmp_path / "a.png", "--cache", cache,
            check=0)
    (cache / "notes.txt").write_text("mine")
    (cache / "results").mkdir()
    (cache / ("a" * 64)).mkdir()  # looks like a key but holds no entry.json: not ours
    out = run_cli("cache", "clear", "--cache", cache, check=0).stdout
    assert "removed 1 entry" in out
    assert sorted(p.name for p in cache.iterdir()) == sorted(["notes.txt", "results", "a" * 64])
    assert "0 entries" in run_cli("cache", "info", "--cache", cache, check=0).stdout


def test_a_damaged_entry_is_built_again(tmp_path):
    cache = tmp_path / "cache"
    args = (GERRIS, "--field", "T", *FRAME, "--cache", cache)
    run_cli("render", *args, "-o", tmp_path / "a.exr", check=0)
    (entry,) = entries(cache)
    bricks = cache / entry / "bricks.npz"
    data = bytearray(bricks.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bricks.write_bytes(bytes(data))
    proc = run_cli("render", *args, "-o", tmp_path / "b.exr", check=0)
    assert "damaged cache entry" in proc.stderr and "building it again" in proc.stderr
    np.testing.assert_array_equal(pixels(tmp_path / "b.exr"), pixels(tmp_path / "a.exr"))
    assert entries(cache) == [entry]


def test_two_renders_of_one_source_at_once(tmp_path):
    cache = tmp_path / "cache"
    procs = [subprocess.Popen([sys.executable, "-m", "exabricks.cli.main", "render", str(GERRIS),
                               "--field", "T", *FRAME, "-o", str(tmp_path / f"{i}.exr"),
                               "--cache", str(cache)], stderr=subprocess.PIPE, text=True)
             for i in range(2)]
    for p in procs:
        assert p.wait(timeout=300) == 0, p.stderr.read()
    assert len(entries(cache)) == 1
    assert not [p for p in cache.iterdir() if p.name.startswith(".eb-")]
    np.testing.assert_array_equal(pixels(tmp_path / "0.exr"), pixels(tmp_path / "1.exr"))


@pytest.mark.slow
def test_source_usage_errors(tmp_path, plume_trio):
    out = tmp_path / "x.png"
    proc = run_cli("render", *plume_trio[:2], "-o", out)
    assert proc.returncode == 2 and "give one source or the three structure files" in proc.stderr
    proc = run_cli("render", *plume_trio, "--fields", "T", "-o", out)
    assert proc.returncode == 2 and "--fields: only with a source" in proc.stderr
    proc = run_cli("render", GERRIS, "--cache", tmp_path, "--no-cache", "-o", out)
    assert proc.returncode == 2 and "exclude each other" in proc.stderr
    assert_one_error_line(run_cli("render", plume_trio[0], "-o", out), str(plume_trio[0]),
                          "a bricks file is not a source")
    (tmp_path / "file").write_text("")
    assert_one_error_line(run_cli("render", GERRIS, "--cache", tmp_path / "file" / "c", "-o", out),
                          "cannot write the cache")
    assert_one_error_line(run_cli("render", GERRIS, "--fields", "nope", "--no-cache", "-o", out),
                          str(GERRIS), "nope")
    assert_one_error_line(run_cli("render", "/dev/zero", "-o", out), "/dev/zero",
                          "not a regular file or a directory")
    assert not out.exists()
    # the output may not replace the source
    assert_one_error_line(run_cli("render", tmp_path / "file", "-o", tmp_path / "file"), "file")


@pytest.mark.slow
def test_a_source_under_a_memory_budget(tmp_path):
    args = (GERRIS, "--field", "T", *FRAME)
    run_cli("render", *args, "-o", tmp_path / "a.exr", check=0)
    run_cli("render", *args, "--memory-budget", "3M", "-o", tmp_path / "b.exr", check=0)
    np.testing.assert_allclose(pixels(tmp_path / "b.exr"), pixels(tmp_path / "a.exr"), atol=2e-6)
    proc = run_cli("render", *args, "--memory-budget", "3M", "--no-cache", "-o", tmp_path / "c.exr")
    assert_one_error_line(proc, "--memory-budget", "--no-cache")


def test_open_source_in_memory_equals_the_cached_files(tmp_path):
    from exabricks.dataset import open_source

    memory = open_source(GERRIS, {"fields": ("T",)}, cache=False)
    cached = open_source(GERRIS, {"fields": ("T",)}, cache=tmp_path)
    assert memory.paths is None and cached.paths[0].parent.parent == tmp_path
    for a, b in zip(memory.structures(), cached.structures()):
        for name, array in a.arrays().items():
            np.testing.assert_array_equal(np.asarray(getattr(b, name)), array, err_msg=name)
    assert memory.fields == ("T",) and memory.levels >= 2
    assert os.fspath(GERRIS) in memory.inputs


def test_the_commands_ingest_defaults_are_the_stages():
    """What the command line takes as "not given" is the ingest stage's own default."""
    from exabricks.cli.options import ingest_defaults as declared
    from exabricks.dataset import ingest_defaults

    assert declared() == ingest_defaults()
