"""The command line run with a time limit, for hostile inputs: a hang fails the test instead of blocking it."""

from __future__ import annotations

import subprocess
import sys


TIMEOUT = 120


def run(*args, timeout=TIMEOUT, **kw):
    """`exabricks ARGS` with a time limit: a hang fails the test instead of blocking it."""
    return subprocess.run([sys.executable, "-m", "exabricks.cli.main", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, **kw)
