"""SIGTERM, SIGHUP and SIGINT end a command cleanly (docs/design.md, "Errors, hostile input, outputs and signals").

`install()` (called once by the CLI) makes each of these signals raise
`Interrupted` in the main thread, after deleting the temporary file of any
write in progress; the CLI prints ``error: interrupted (SIGTERM)`` and exits
with 128 + the signal number. SLURM and `timeout` send SIGTERM first, a closed
terminal SIGHUP, Ctrl-C SIGINT.

Python runs signal handlers between bytecodes, so a long native call (a numba
builder, an OpenCL kernel) delays the exit until it returns: the renderer and
probe therefore enqueue their work in chunks of well under a second. A signal
whose exception was swallowed by library code (a finaliser, a thread) is still
recorded: `raise_pending` re-raises it, and `write_output` calls it before
putting an output in place.
"""

from __future__ import annotations

import signal


SIGNALS = tuple(s for s in (signal.SIGTERM, getattr(signal, "SIGHUP", None), signal.SIGINT) if s)

_received: list[int] = []
# What a signal must undo before the run ends (exabricks.output registers the
# removal of its temporary files).
_cleanups: list = []


class Interrupted(BaseException):
    """A signal asked the command to stop (BaseException: `except Exception` must not catch it)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


def _handler(signum, frame):
    _received.append(signum)
    for cleanup in _cleanups:
        cleanup()
    for s in SIGNALS:  # a second signal must not interrupt the clean exit
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


def at_signal(cleanup) -> None:
    """Have the signal handlers call `cleanup()` (no arguments) before the run ends."""
    if cleanup not in _cleanups:
        _cleanups.append(cleanup)


def install() -> None:
    """Route SIGTERM, SIGHUP and SIGINT to `Interrupted` (main thread only)."""
    for s in SIGNALS:
        try:
            signal.signal(s, _handler)
        except (ValueError, OSError):  # not the main thread, or an embedded interpreter
            pass


def ignore() -> None:
    """Ignore SIGTERM, SIGHUP and SIGINT from now on: the CLI calls this once the
    run's outcome is decided (its output in place, or its error known), so that a
    signal during the exit can change neither the output nor the exit status.
    (Python restores the default action of its own handlers while it shuts
    down, which would end the process by the signal; an ignored signal stays
    ignored.)"""
    for s in SIGNALS:
        try:
            signal.signal(s, signal.SIG_IGN)
        except (ValueError, OSError):
            pass


def pending() -> int | None:
    """The first signal received so far, or None."""
    return _received[0] if _received else None


def raise_pending() -> None:
    """Raise `Interrupted` if a signal arrived (even one whose exception was swallowed)."""
    if _received:
        raise Interrupted(_received[0])
