"""Outputs through open descriptors (exabricks/util/output.py; issue 32): `-o
/dev/stdout`, `/dev/fd/N` and `/proc/self/fd/N` write through the descriptor,
whatever it is open on, never replacing the file behind it and never needing a
temporary directory."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from exabricks import schema

from helpers import assert_one_error_line
from helpers.hostile import TIMEOUT, run

EB = [sys.executable, "-m", "exabricks.cli.main"]


def regions_from(data: bytes, tmp_path) -> schema.Regions:
    path = tmp_path / "back.npz"
    path.write_bytes(data)
    return schema.load(path, "regions")


def test_stdout_appended_to_a_log_keeps_the_log(plume_trio, tmp_path):
    log = tmp_path / "log.txt"
    log.write_bytes(b"first line\n")
    with open(log, "ab") as out:
        proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", "/dev/stdout"], stdout=out,
                              stderr=subprocess.PIPE, timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr
    data = log.read_bytes()
    assert data.startswith(b"first line\nPK\x03\x04")
    regions = regions_from(data[len(b"first line\n"):], tmp_path)
    assert regions.n_regions == schema.load(plume_trio[1], "regions").n_regions


def test_stdout_into_a_pipe(plume_trio, tmp_path):
    proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", "/dev/stdout"], capture_output=True,
                          timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr
    assert zipfile.is_zipfile(io.BytesIO(proc.stdout))
    regions_from(proc.stdout, tmp_path)


@pytest.mark.parametrize("name", ["/dev/fd/{fd}", "/proc/self/fd/{fd}", "link"])
def test_a_numbered_descriptor_is_written_through(name, plume_trio, tmp_path):
    target = tmp_path / "target.bin"
    target.write_bytes(b"kept")
    fd = os.open(target, os.O_WRONLY | os.O_APPEND)
    try:
        output = name.format(fd=fd)
        if name == "link":
            output = tmp_path / "out.npz"
            output.symlink_to(f"/dev/fd/{fd}")
        proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", output], pass_fds=(fd,),
                              capture_output=True, text=True, timeout=TIMEOUT)
    finally:
        os.close(fd)
    assert proc.returncode == 0, proc.stderr
    assert target.read_bytes().startswith(b"keptPK\x03\x04")
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_no_temporary_directory_is_needed(plume_trio, tmp_path):
    proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", "/dev/stdout"], capture_output=True,
                          timeout=TIMEOUT, env={**os.environ, "TMPDIR": str(tmp_path / "none")})
    assert proc.returncode == 0, proc.stderr
    regions_from(proc.stdout, tmp_path)


def test_a_png_through_a_named_link_to_stdout(plume_trio, tmp_path):
    link = tmp_path / "x.png"
    link.symlink_to("/dev/stdout")
    proc = subprocess.run([*EB, "render", *plume_trio, "-o", link, "--size", "16", "16"],
                          capture_output=True, timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(b"\x89PNG")
    assert link.is_symlink()


def test_a_closed_descriptor_is_refused(plume_trio):
    proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", "/dev/fd/9"], capture_output=True,
                          text=True, timeout=TIMEOUT)
    assert_one_error_line(proc, "/dev/fd/9", "not open")


def test_a_read_only_descriptor_is_refused(plume_trio, tmp_path):
    src = tmp_path / "ro.txt"
    src.write_text("x")
    with open(src) as f:
        proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", "/dev/stdout"], stdout=f,
                              stderr=subprocess.PIPE, text=True, timeout=TIMEOUT)
    assert_one_error_line(proc, "/dev/stdout", "not open for writing")
    assert src.read_text() == "x"


def test_a_descriptor_open_on_an_input_is_refused(plume_trio):
    with open(plume_trio[0], "ab") as f:
        before = os.fstat(f.fileno()).st_size
        proc = subprocess.run([*EB, "regions", plume_trio[0], "-o", "/dev/stdout"], stdout=f,
                              stderr=subprocess.PIPE, text=True, timeout=TIMEOUT)
    assert_one_error_line(proc, "would overwrite the input")
    assert os.stat(plume_trio[0]).st_size == before


def test_a_descriptor_of_another_process_is_refused(plume_trio):
    proc = run("regions", plume_trio[0], "-o", "/proc/1/fd/1")
    assert_one_error_line(proc, "/proc/1/fd/1", "another process")


def test_probe_values_through_stdout(plume_trio, tmp_path):
    points = tmp_path / "p.npy"
    np.save(points, np.full((4, 3), 0.5))
    proc = subprocess.run([*EB, "probe", *plume_trio, "--points", points, "-o", "/dev/stdout"],
                          capture_output=True, timeout=TIMEOUT)
    assert proc.returncode == 0, proc.stderr
    assert np.load(io.BytesIO(proc.stdout)).shape == (4,)
