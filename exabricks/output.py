"""The one writer of every output file (stage outputs, images, probe values).

`write_output(path, write, inputs=...)` calls ``write(tmp)`` with the name of a
fresh temporary file and then puts the result at `path`:

* a regular file (or a name that does not exist yet) is replaced atomically:
  the temporary file lives in the target's directory under a short name
  (``.eb-XXXXXXXX.tmp``) and is renamed into place, so a failed or killed run
  never leaves a file that `make` would take as up to date;
* a symbolic link is followed: the file it names is replaced, the link stays;
* a character device or a FIFO (``/dev/null``, ``/dev/stdout``, a pipe) is
  written into directly, never replaced;
* a directory, a socket or a block device is refused;
* an output that is one of the command's inputs (after resolving symbolic
  links, or a hard link to one) is refused before anything is computed:
  `check_output` runs when a command starts, `write_output` checks again.

Temporary files are registered while they exist: `remove_temporaries` (called
by the CLI on SIGTERM, SIGHUP and SIGINT) deletes them, and a signal that
arrived during a write aborts it before the rename (`interrupt.pending`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Callable, Iterable

from .errors import ExabricksError

# Short, fixed-length temporary names: the target's own name may already be
# close to the file-system limit of 255 bytes.
TMP_PREFIX = ".eb-"
TMP_SUFFIX = ".tmp"

_TEMPORARIES: set[str] = set()


def _describe(error: OSError) -> str:
    return error.strerror or str(error)


def _resolved(path: Path) -> Path:
    """`path` with every symbolic link resolved (the path itself may not exist)."""
    try:
        return Path(os.path.realpath(path, strict=False))
    except (OSError, RuntimeError) as e:  # a symlink loop
        raise ExabricksError(f"{path}: cannot resolve the output path ({e})") from None


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return _resolved(a) == _resolved(b)


def check_output(path, inputs: Iterable = ()) -> Path:
    """Refuse an output `path` that cannot be written or that names an input;
    returns the resolved path that will receive the output."""
    text = os.fspath(path)
    if not text:
        raise ExabricksError("the output path is empty")
    path = Path(text)
    if "\0" in text:
        raise ExabricksError(f"{text!r}: the output path contains a NUL byte")
    target = _resolved(path)
    for inp in inputs:
        if inp is not None and _same_file(path, Path(inp)):
            raise ExabricksError(f"{path}: the output would overwrite the input {inp}")
    if len(os.fsencode(target.name)) > 255:
        raise ExabricksError(f"{path}: file name too long ({len(os.fsencode(target.name))} bytes, "
                             "at most 255)")
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise ExabricksError(f"{path}: cannot write the output: {_describe(e)}") from None
    if st is not None and not (stat.S_ISREG(st.st_mode) or stat.S_ISCHR(st.st_mode)
                               or stat.S_ISFIFO(st.st_mode)):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file, device or FIFO"
        raise ExabricksError(f"{path}: cannot write the output there ({kind})")
    directory = target.parent
    if st is None and not directory.is_dir():
        raise ExabricksError(f"{path}: directory {directory} does not exist")
    return target


def write_output(path, write: Callable[[str], None], *, inputs: Iterable = ()) -> None:
    """Have `write(tmp)` write a file, then put it at `path` (module docstring)."""
    from . import interrupt

    target = check_output(path, inputs)
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        mode = None
    direct = mode is not None and not stat.S_ISREG(mode)
    tmp = _temporary(path, None if direct else target.parent)
    try:
        write(tmp)
        interrupt.raise_pending()
        if direct:
            with open(tmp, "rb") as src, open(target, "wb", buffering=0) as dst:
                shutil.copyfileobj(src, dst, 1 << 20)
        else:
            os.chmod(tmp, 0o644)
            os.replace(tmp, target)
            _TEMPORARIES.discard(tmp)
    except OSError as e:
        raise ExabricksError(f"{path}: cannot write the output: {_describe(e)}") from None
    finally:
        _remove(tmp)


def _temporary(path, directory) -> str:
    """A fresh registered temporary file in `directory` (None: the system's)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=TMP_PREFIX, suffix=TMP_SUFFIX, dir=directory)
    except OSError as e:
        where = directory or tempfile.gettempdir()
        raise ExabricksError(f"{path}: cannot create a temporary file in {where}: "
                             f"{_describe(e)}") from None
    os.close(fd)
    _TEMPORARIES.add(tmp)
    return tmp


@contextlib.contextmanager
def scratch(path):
    """A temporary file to build the output `path` in pieces (a frame larger than
    memory), beside it (in the system's temporary directory for a device or
    FIFO); deleted on leaving, and by the signal handlers like every temporary."""
    target = check_output(path)
    try:
        regular = stat.S_ISREG(os.stat(target).st_mode)
    except FileNotFoundError:
        regular = True
    tmp = _temporary(path, target.parent if regular else None)
    try:
        yield tmp
    finally:
        _remove(tmp)


def _remove(tmp: str) -> None:
    """Delete `tmp` if it is still ours (not yet renamed into place)."""
    if tmp not in _TEMPORARIES:
        return
    try:
        os.unlink(tmp)
    except OSError as e:
        if e.errno != errno.ENOENT:
            return
    _TEMPORARIES.discard(tmp)


def remove_temporaries() -> None:
    """Delete every temporary file of a write in progress (signal handlers call this)."""
    for tmp in list(_TEMPORARIES):
        _remove(tmp)
