"""A signal that arrives once the output is in place (exabricks/cli/main.py,
exabricks/util/interrupt.py; issue 32) ends the run with exit 0, or with the
interrupted line and 128 + N: never with death by the signal, which would lie to
a scheduler about a complete output."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time

import pytest

from helpers import FUZZ_EXAMPLES
from helpers.hostile import TIMEOUT


@pytest.mark.parametrize("signum", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow),
                                    pytest.param(signal.SIGHUP, marks=pytest.mark.slow)])
@pytest.mark.slow
def test_a_signal_once_the_output_is_in_place(signum, plume_trio, tmp_path):
    out = tmp_path / "regions.npz"
    for _ in range(4):
        out.unlink(missing_ok=True)
        proc = subprocess.Popen([sys.executable, "-m", "exabricks.cli.main", "regions", plume_trio[0],
                                 "-o", out], stderr=subprocess.PIPE, text=True)
        # The event is the rename that puts the output in place; the signal follows it.
        while not out.exists() and proc.poll() is None:
            time.sleep(0.0002)
        assert out.exists(), proc.communicate()[1]
        proc.send_signal(signum)
        err = proc.communicate(timeout=TIMEOUT)[1]
        assert proc.returncode in (0, 128 + signum), (proc.returncode, err)
        lines = [line for line in err.splitlines() if line.strip()]
        if proc.returncode:
            assert lines == [f"error: interrupted ({signal.Signals(signum).name})"], err
        else:
            assert lines == [], err
        assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


@pytest.mark.fuzz
def test_a_signal_during_start_up(plume_trio, tmp_path):
    """A signal at a random moment of a render's start-up (the imports of
    pyopencl's nanobind modules and numba's C modules, numba's cache, the kernel
    build; issue 49, item 10) ends it with the interrupted line and 128 + N, or
    it finished first; or the signal came before Python ran any of the command
    (death by the signal; for SIGINT, Python's own KeyboardInterrupt). Never an
    abort, an internal error or a message from a swallowed exception."""
    rng = random.Random(49)
    args = [sys.executable, "-m", "exabricks.cli.main", "render", *plume_trio,
            "-o", str(tmp_path / "s.png"), "--size", "64", "64"]
    start = time.perf_counter()
    subprocess.run(args, check=True, capture_output=True, timeout=TIMEOUT)
    whole = time.perf_counter() - start
    for attempt in range(max(3, FUZZ_EXAMPLES // 3)):
        signum = (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)[attempt % 3]
        proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True)
        time.sleep(rng.uniform(0.0, whole))
        proc.send_signal(signum)
        err = proc.communicate(timeout=TIMEOUT)[1]
        lines = [line for line in err.splitlines() if line.strip()]
        name = signal.Signals(signum).name
        before = proc.returncode == -signum and (
            not lines or signum == signal.SIGINT and lines[-1] == "KeyboardInterrupt"
            and "exabricks/cli" not in err)
        assert (proc.returncode == 128 + signum and lines == [f"error: interrupted ({name})"]
                or proc.returncode == 0 and not lines or before), (name, proc.returncode, err)
        assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]
