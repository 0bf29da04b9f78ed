"""A signal ends a long frame within a second, whatever its integrator, size and
spp (README; exabricks/engine/pacing.py; issue 65 item 16): the renderer waits
for the device after about 0.25 s of work at a time. A band of rows with all
its samples per pixel was one wait, and SIGTERM ended such frames 4 to 76 s
after it came."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from helpers.hostile import TIMEOUT

# Frames that take minutes uninterrupted on 2 CPU cores (and far over 10 s on
# any device), each band of rows of them many waits: the path integrator's
# work is its spp, the shadow integrator's its size.
FRAMES = {
    "path": ["--integrator", "path", "--size", "64", "64", "--spp", "4096"],
    "shadow": ["--integrator", "shadow", "--size", "256", "256", "--spp", "256"],
}


@pytest.mark.parametrize("frame", sorted(FRAMES))
def test_sigterm_ends_a_long_frame_within_a_second(frame, plume_trio, tmp_path):
    out = tmp_path / "frame.png"
    proc = subprocess.Popen([sys.executable, "-m", "exabricks.cli.main", "-vv", "render", *plume_trio,
                             *FRAMES[frame], "-o", out],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    # -vv logs the frame's first kernel launch once it runs; a second later the
    # frame is several waits in.
    for line in proc.stderr:
        if "work-group function of eb_render" in line:
            break
    else:
        pytest.fail(f"the frame never started (exit {proc.wait()})")
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    sent = time.perf_counter()
    err = proc.communicate(timeout=TIMEOUT)[1]
    took = time.perf_counter() - sent
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert [line for line in err.splitlines() if line.strip()] == ["error: interrupted (SIGTERM)"], err
    assert took < 1.5, f"{frame}: exit {took:.2f} s after SIGTERM"
    assert os.listdir(tmp_path) == []
