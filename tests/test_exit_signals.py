"""A signal that arrives once the output is in place (exabricks/cli/main.py,
exabricks/interrupt.py; issue 32) ends the run with exit 0, or with the
interrupted line and 128 + N: never with death by the signal, which would lie to
a scheduler about a complete output."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from test_hostile import TIMEOUT


@pytest.mark.parametrize("signum", [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow),
                                    pytest.param(signal.SIGHUP, marks=pytest.mark.slow)])
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
