"""The one writer of every output file (stage outputs, images, probe values).

`write_output(path, write, inputs=...)` calls ``write(tmp)`` with the name of a
fresh temporary file and then puts the result at `path`:

* a regular file (or a name that does not exist yet) is replaced atomically:
  the temporary file lives in the target's directory under a short name
  (``.eb-XXXXXXXX.tmp``) and is renamed into place, so a failed or killed run
  never leaves a file that `make` would take as up to date;
* a symbolic link is followed: the file it names is replaced, the link stays; a
  dangling one is written through too (the file it names is made, where that
  file's directory exists; else refused with one line naming the directory);
* an open descriptor named by ``/dev/stdout``, ``/dev/stderr``, ``/dev/fd/N``
  or ``/proc/self/fd/N`` (or a link to one) is written through, whatever it
  is open on (a file opened for appending, a pipe, a terminal): the file
  behind it is never replaced (`descriptor`);
* a character device or a FIFO given by name (``/dev/null``, a named pipe) is
  written into directly, never replaced;
* a directory, a socket or a block device is refused;
* an output that is one of the command's inputs, any file an input is made of
  (exabricks.util.source_files: every file of a source folder, an ExaJet file's
  scalars, an Enzo output's companions), or a new file inside an input folder is
  refused before anything is computed, whatever the symbolic or hard links on
  either side: `check_output` runs when a command starts, `write_output` checks
  again.

What goes through a descriptor, a device or a FIFO is first written to an
anonymous in-memory file (memfd; a file in the system's temporary directory
where there is none), so no temporary directory is needed.

Temporary files are registered while they exist: `remove_temporaries` (called
by exabricks.util.interrupt's handlers of SIGTERM, SIGHUP and SIGINT) deletes them,
and a signal that arrived during a write aborts it before the rename
(`interrupt.pending`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import select
import stat
import tempfile
from pathlib import Path
from typing import Callable, Iterable

from . import interrupt, source_files
from .errors import ExabricksError
from .jsonfile import kind_of

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


# The magic links of a process's open descriptors, after /proc/self and /dev/fd
# are resolved: /proc/PID/fd/N or /proc/PID/task/TID/fd/N.
_FD_LINK = re.compile(r"/proc/(\d+)(?:/task/\d+)?/fd/(\d+)")


def descriptor(path) -> int | None:
    """The open descriptor of this process that `path` names (``/dev/stdout``,
    ``/dev/fd/3``, ``/proc/self/fd/1``, or a symbolic link to one), else None.

    The links are followed one at a time and the descriptor's own link
    (``/proc/PID/fd/N``, which points at the file, pipe or terminal behind it) is
    recognised before it would be followed; a descriptor of another process is
    refused."""
    p = os.path.abspath(os.fspath(path))
    for _ in range(40):  # the kernel's own limit on links in a path
        head, tail = os.path.split(p)
        p = os.path.join(os.path.realpath(head), tail)
        m = _FD_LINK.fullmatch(p)
        if m:
            if int(m.group(1)) != os.getpid():
                raise ExabricksError(f"{path}: names a descriptor of another process")
            return int(m.group(2))
        if not os.path.islink(p):
            return None
        p = os.path.join(head if os.path.isabs(head) else os.getcwd(), os.readlink(p))
    raise ExabricksError(f"{path}: cannot resolve the output path (too many symbolic links)")


# What check_output returns for a descriptor (a resolved path never starts so:
# realpath turns /proc/self into /proc/PID).
_FD_DIR = Path("/proc/self/fd")


def _target_descriptor(target: Path) -> int | None:
    """The descriptor a `check_output` result stands for, else None."""
    return int(target.name) if target.parent == _FD_DIR else None


def _check_descriptor(path, fd: int, inputs: Inputs) -> None:
    """Refuse descriptor `fd` (named by `path`) unless it is open for writing on
    something other than a directory or one of the `inputs`."""
    import fcntl

    try:
        st = os.fstat(fd)
        flags = fcntl.fcntl(fd, fcntl.F_GETFL)
    except OSError:
        raise ExabricksError(f"{path}: descriptor {fd} is not open") from None
    if flags & os.O_ACCMODE not in (os.O_WRONLY, os.O_RDWR):
        raise ExabricksError(f"{path}: descriptor {fd} is not open for writing")
    if stat.S_ISDIR(st.st_mode):
        raise ExabricksError(f"{path}: descriptor {fd} is open on a directory")
    if stat.S_ISREG(st.st_mode):
        _refuse_members(path, None, (st.st_dev, st.st_ino), inputs)


class Inputs:
    """A command's inputs, each with the (device, inode) of every file it is made of
    (exabricks.util.source_files), listed on first need and kept: a series checks
    every frame against every step's files with one listing of each step."""

    def __init__(self, inputs: Iterable = ()):
        self.paths = tuple(Path(p) for p in inputs if p is not None)
        self._files: dict = {}

    def __iter__(self):
        return iter(self.paths)

    def files(self, inp: Path) -> dict:
        """(device, inode) -> path of every file `inp` is made of that exists."""
        if inp not in self._files:
            found = {}
            try:
                members = source_files.members(inp) if inp.exists() else []
            except (OSError, ExabricksError):
                members = []
            for _, member in members:
                try:
                    other = os.stat(member)
                except OSError:
                    continue
                found.setdefault((other.st_dev, other.st_ino), member)
            self._files[inp] = found
        return self._files[inp]


def _refuse_members(path, target: Path | None, ident, inputs: Inputs) -> None:
    """Refuse an output that is, or lies inside, any of `inputs` or any file one of
    them is made of (exabricks.util.source_files: a folder's every file, the
    siblings a reader reads), whatever the symbolic links on either side.
    `target`: the output's resolved path (None for a descriptor); `ident`: the
    (device, inode) of the file it names, where one exists."""
    for inp in inputs:
        if target is not None and _same_file(path, inp):
            raise ExabricksError(f"{path}: the output would overwrite the input {inp}")
        if target is not None and inp.is_dir() and target.is_relative_to(_resolved(inp)):
            raise ExabricksError(f"{path}: the output would land inside the input folder {inp}")
        member = None if ident is None else inputs.files(inp).get(ident)
        if member is not None:
            what = f"the input {inp}" if member == inp else f"{member}, a file of the input {inp}"
            raise ExabricksError(f"{path}: the output would overwrite {what}")


def check_output(path, inputs: Iterable = ()) -> Path:
    """Refuse an output `path` that cannot be written or that names an input (of
    `inputs`: paths, or an Inputs to check many outputs against); returns the
    resolved path that will receive the output (for a descriptor,
    ``/proc/self/fd/N``)."""
    inputs = inputs if isinstance(inputs, Inputs) else Inputs(inputs)
    text = os.fspath(path)
    if not text:
        raise ExabricksError("the output path is empty")
    path = Path(text)
    if "\0" in text:
        raise ExabricksError(f"{text!r}: the output path contains a NUL byte")
    fd = descriptor(path)
    if fd is not None:
        _check_descriptor(path, fd, inputs)
        return _FD_DIR / str(fd)
    target = _resolved(path)
    if len(os.fsencode(target.name)) > 255:
        raise ExabricksError(f"{path}: file name too long ({len(os.fsencode(target.name))} bytes, "
                             "at most 255)")
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise ExabricksError(f"{path}: cannot write the output: {_describe(e)}") from None
    _refuse_members(path, target, None if st is None else (st.st_dev, st.st_ino), inputs)
    if st is not None and not (stat.S_ISREG(st.st_mode) or stat.S_ISCHR(st.st_mode)
                               or stat.S_ISFIFO(st.st_mode)):
        raise ExabricksError(f"{path}: cannot write the output there ({kind_of(st.st_mode)}; "
                             "the output is a regular file, a character device or a FIFO)")
    directory = target.parent
    if st is None and not directory.is_dir():
        raise ExabricksError(f"{path}: directory {directory} does not exist")
    return target


def write_output(path, write: Callable[[str], None], *, inputs: Iterable = ()) -> None:
    """Have `write(tmp)` write a file, then put it at `path` (module docstring)."""
    target = check_output(path, inputs)
    fd = _target_descriptor(target)
    if fd is None:
        try:
            mode = os.stat(target).st_mode
        except FileNotFoundError:
            mode = None
        direct = mode is not None and not stat.S_ISREG(mode)
    else:
        direct = True
    tmp = _memory_file(path) if direct else _temporary(path, target.parent)
    try:
        write(tmp)
        interrupt.raise_pending()
        if fd is not None:
            _copy_into(tmp, fd)
        elif direct:
            out = os.open(target, os.O_WRONLY | getattr(os, "O_CLOEXEC", 0))
            try:
                _copy_into(tmp, out)
            finally:
                os.close(out)
        else:
            os.chmod(tmp, 0o644)
            os.replace(tmp, target)
            _TEMPORARIES.discard(tmp)
    except OSError as e:
        raise ExabricksError(f"{path}: cannot write the output: {_describe(e)}") from None
    finally:
        _remove(tmp)


def _copy_into(tmp: str, out: int) -> None:
    """Write the bytes of file `tmp` to descriptor `out` at its own position (or
    its end, when it was opened for appending), waiting while a non-blocking pipe
    is full."""
    with open(tmp, "rb") as src:
        while block := src.read(1 << 20):
            view = memoryview(block)
            while view:
                try:
                    view = view[os.write(out, view):]
                except BlockingIOError:
                    select.select([], [out], [])


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


# Anonymous in-memory files in use (their /proc/self/fd names -> descriptors).
_MEMORY_FILES: dict[str, int] = {}


def _memory_file(path) -> str:
    """A registered anonymous in-memory file for an output that goes through a
    descriptor, device or FIFO, by a name that `open` takes; a file in the
    system's temporary directory where memfd_create is missing."""
    try:
        fd = os.memfd_create("exabricks-output", getattr(os, "MFD_CLOEXEC", 0))
    except (AttributeError, OSError):
        return _temporary(path, None)
    name = f"/proc/self/fd/{fd}"
    _MEMORY_FILES[name] = fd
    _TEMPORARIES.add(name)
    return name


@contextlib.contextmanager
def scratch(path):
    """A temporary file to build the output `path` in pieces (a frame larger than
    memory), beside it (in the system's temporary directory for a device or
    FIFO); deleted on leaving, and by the signal handlers like every temporary."""
    target = check_output(path)
    try:
        regular = _target_descriptor(target) is None and stat.S_ISREG(os.stat(target).st_mode)
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
    if tmp in _MEMORY_FILES:
        os.close(_MEMORY_FILES.pop(tmp))
        _TEMPORARIES.discard(tmp)
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


interrupt.at_signal(remove_temporaries)


def write_json(path, doc, *, inputs: Iterable = ()) -> None:
    """`doc` as an indented JSON file at `path`, atomically (`write_output`)."""
    import json

    text = json.dumps(doc, indent=1) + "\n"

    def write(tmp):
        with open(tmp, "w") as f:
            f.write(text)

    write_output(path, write, inputs=inputs)
