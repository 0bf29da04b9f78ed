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

A signal that lands while the main thread imports a module is held until the
outermost import returns (`install` routes the `import` statement through
`_deferring_import`): an exception raised inside the initialisation of a
native extension (pyopencl's nanobind types, numba's C modules) aborts the
process or leaves a half-made module behind, where it should end the run with
the interrupted line.
"""

from __future__ import annotations

import builtins
import signal
import sys
import threading


SIGNALS = tuple(s for s in (signal.SIGTERM, getattr(signal, "SIGHUP", None), signal.SIGINT) if s)

_received: list[int] = []
# What a signal must undo before the run ends (exabricks.util.output registers the
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


# Imports the main thread is inside (`_deferring_import`), whether signals wait for
# `install` (install(hold=True)), and a signal held meanwhile.
_importing = 0
_holding = False
_held: list[int] = []
_import = builtins.__import__


def _handler(signum, frame):
    _received.append(signum)
    if _importing or _holding:
        _held.append(signum)
    else:
        _stop(signum)


def _stop(signum: int):
    for cleanup in _cleanups:
        cleanup()
    for s in SIGNALS:  # a second signal must not interrupt the clean exit
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


def at_signal(cleanup) -> None:
    """Have the signal handlers call `cleanup()` (no arguments) before the run ends."""
    if cleanup not in _cleanups:
        _cleanups.append(cleanup)


def _deferring_import(*args, **kwargs):
    """builtins.__import__, with a signal to the main thread held until the
    outermost import returns (module docstring)."""
    global _importing
    if threading.current_thread() is not threading.main_thread():
        return _import(*args, **kwargs)
    _importing += 1
    try:
        return _import(*args, **kwargs)
    finally:
        _importing -= 1
        if not (_importing or _holding) and _held:
            _stop(_held.pop(0))


def _unraisable(unraisable) -> None:
    """sys.unraisablehook: an `Interrupted` that a callback from native code
    swallowed (llvmlite's object cache while numba loads a function) is not
    reported; it is recorded, and `raise_pending` raises it again."""
    if not isinstance(unraisable.exc_value, Interrupted):
        sys.__unraisablehook__(unraisable)


def install(hold: bool = False) -> None:
    """Route SIGTERM, SIGHUP and SIGINT to `Interrupted` (main thread only),
    held during imports. `hold`: held until `install()` is called again (where
    the caller can catch `Interrupted`), which raises one that came meanwhile."""
    global _holding
    _holding = hold
    builtins.__import__ = _deferring_import
    sys.unraisablehook = _unraisable
    for s in SIGNALS:
        try:
            signal.signal(s, _handler)
        except (ValueError, OSError):  # not the main thread, or an embedded interpreter
            pass
    if not hold and _held:
        _stop(_held.pop(0))


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
