"""The waits a command leaves silent on a terminal: every stretch of more than
--gap seconds in which it wrote nothing to a 120x40 pseudo-terminal.

    .venv/bin/python -m benchmarks.silent_waits [--gap 2] [--cold] -- exabricks render SOURCE -o x.png

README's promise (docs/install.md, "Waits"): no wait over 2 s passes without a
line on a terminal. `--cold` runs the command with empty caches of its own
(numba's, PoCL's, pyopencl's and exabricks' structures, in a temporary
directory), as on a fresh install. Prints the total time, then each silent
stretch: when it began, how long it lasted, and what came after it. Exit status
1 when there is one.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import pty
import select
import struct
import sys
import tempfile
import termios
import time

COLUMNS, ROWS = 120, 40


def silent_stretches(command: list[str], gap: float, env: dict) -> tuple[float, list]:
    """(total seconds, [(start s, seconds, the bytes after)]) of `command` on a pty."""
    start = last = time.perf_counter()
    pid, fd = pty.fork()
    if pid == 0:  # the child: a terminal of a real size (tqdm draws nothing at 0 columns)
        fcntl.ioctl(0, termios.TIOCSWINSZ, struct.pack("HHHH", ROWS, COLUMNS, 0, 0))
        os.execvpe(command[0], command, env)
    stretches = []
    while True:
        ready, _, _ = select.select([fd], [], [], 0.1)
        if not ready:
            continue
        try:
            data = os.read(fd, 4096)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        now = time.perf_counter()
        if now - last > gap:
            stretches.append((last - start, now - last, data[:100]))
        last = now
    os.waitpid(pid, 0)
    end = time.perf_counter()
    if end - last > gap:
        stretches.append((last - start, end - last, b"<exit>"))
    return end - start, stretches


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--gap", type=float, default=2.0, help="seconds of silence reported")
    p.add_argument("--cold", action="store_true", help="empty caches of its own")
    p.add_argument("command", nargs=argparse.REMAINDER)
    args = p.parse_args(argv)
    command = [c for c in args.command if c != "--"] or p.error("give a command")
    with tempfile.TemporaryDirectory(prefix="eb-silent-") as cold:
        env = dict(os.environ)
        if args.cold:
            env.update(NUMBA_CACHE_DIR=f"{cold}/numba", POCL_CACHE_DIR=f"{cold}/pocl",
                       XDG_CACHE_HOME=f"{cold}/xdg", EXABRICKS_CACHE=f"{cold}/exabricks")
        total, stretches = silent_stretches(command, args.gap, env)
    print(f"{' '.join(command)}: {total:.1f} s, {len(stretches)} silent stretch(es) over "
          f"{args.gap:g} s")
    for at, seconds, after in stretches:
        print(f"  at {at:.1f} s: {seconds:.1f} s, then {after.decode(errors='replace')!r}")
    return 1 if stretches else 0


if __name__ == "__main__":
    sys.exit(main())
