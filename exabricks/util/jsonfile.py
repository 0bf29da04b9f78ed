"""The one reader of the small files users hand over: cameras, scene files,
transfer-function presets, keyframes, camera paths and point files.

`open_regular` opens a file without blocking (a FIFO with no writer does not
hang) and refuses anything but a regular file, or a symbolic link to one, with
one ExabricksError naming the file; `read_small` reads at most its cap (a
device such as /dev/zero reports a size of 0 and would never end); `read_json`
parses what it read and bounds the nesting, the length of every list and the
number of values, so that the work after parsing is linear in the file and
small (docs/design.md, "Errors, hostile input, outputs and signals").
"""

from __future__ import annotations

import json
import os
import stat

from .constants import MAX_KNOTS
from .errors import ExabricksError

# A camera, a scene or a colour-map preset is a few kilobytes; anything far larger is not one.
MAX_JSON_BYTES = 16 << 20
# Nesting of any JSON input (a scene is 5 levels deep, a preset 3).
MAX_DEPTH = 32
# The longest list a small JSON input may hold: a preset's flat RGBPoints or Points
# list of MAX_KNOTS knots of 4 numbers.
MAX_LIST = 4 * MAX_KNOTS
# Values (numbers, strings, lists, objects) in one small JSON input.
MAX_VALUES = 1 << 20


def kind_of(mode: int) -> str:
    """What a file of `mode` is, in words, for messages."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def not_regular(path) -> str | None:
    """Why `path` is not a regular file ("no such file", "a directory", ...), or
    None when it is one (a symbolic link to one is followed)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "no such file"
    except (OSError, ValueError) as e:
        return getattr(e, "strerror", None) or str(e)
    return None if stat.S_ISREG(mode) else kind_of(mode)


def open_regular(path, what: str):
    """`path` opened for binary reading, or one ExabricksError naming the file when it
    is missing, unreadable or not a regular file (a symbolic link to one is followed).
    The open does not block: a FIFO is refused, not waited on."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise ExabricksError(f"{path}: cannot read {what}: no such file") from None
    except (OSError, ValueError) as e:
        raise ExabricksError(f"{path}: cannot read {what}: {getattr(e, 'strerror', None) or e}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise ExabricksError(f"{path}: cannot read {what}: {kind_of(mode)}, not a regular file")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_small(path, what: str, max_bytes: int = MAX_JSON_BYTES) -> bytes:
    """The bytes of regular file `path`, refused (naming the file and `what` it
    should be) beyond `max_bytes` without reading further."""
    with open_regular(path, what) as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as e:
            raise ExabricksError(f"{path}: cannot read {what}: {e.strerror or e}") from None
    if len(data) > max_bytes:
        raise ExabricksError(f"{path}: {what} is too large (more than {max_bytes:,} bytes)")
    return data


def read_json(path, what: str, max_bytes: int = MAX_JSON_BYTES, *, max_list: int = MAX_LIST,
              max_values: int = MAX_VALUES, **loads_options):
    """The parsed JSON of file `path`, or one ExabricksError naming the file and
    `what` it should be ("camera file", "transfer function") for a missing,
    oversized, undecodable, malformed or absurdly nested or long file."""
    data = read_small(path, what, max_bytes)
    try:
        doc = json.loads(data.decode("utf-8"), **loads_options)
    except UnicodeDecodeError as e:
        raise ExabricksError(f"{path}: cannot read {what}: not UTF-8 text ({e.reason} at byte "
                             f"{e.start})") from None
    except json.JSONDecodeError as e:
        raise ExabricksError(f"{path}: {what} is not valid JSON: {e.msg} (line {e.lineno})") from None
    except RecursionError:
        raise ExabricksError(f"{path}: {what} is nested too deeply to be one") from None
    except ValueError as e:  # a parse_constant hook refusing NaN/Infinity
        raise ExabricksError(f"{path}: {what} is not valid JSON: {e}") from None
    check_bounds(doc, f"{path}: {what}", max_list=max_list, max_values=max_values)
    return doc


def check_bounds(doc, where: str, *, max_list: int = MAX_LIST, max_depth: int = MAX_DEPTH,
                 max_values: int = MAX_VALUES) -> None:
    """ExabricksError unless parsed JSON `doc` nests at most `max_depth` deep, holds no
    list longer than `max_list` and at most `max_values` values in all. A list's
    length is checked before its items are visited, so the cost is bounded by the caps."""
    stack = [(doc, 1)]
    values = 0
    while stack:
        node, depth = stack.pop()
        if depth > max_depth:
            raise ExabricksError(f"{where}: is nested more than {max_depth} levels deep")
        if isinstance(node, dict):
            items = node.values()
        elif isinstance(node, list):
            if len(node) > max_list:
                raise ExabricksError(f"{where}: holds a list of {len(node):,} entries "
                                     f"(at most {max_list:,})")
            items = node
        else:
            continue
        values += len(node)
        if values > max_values:
            raise ExabricksError(f"{where}: holds more than {max_values:,} values")
        stack.extend((item, depth + 1) for item in items if isinstance(item, (dict, list)))


def json_default(x):
    """`json.dumps(..., default=json_default)`: numpy numbers and arrays as JSON
    numbers and lists, paths as strings, sets as sorted lists; TypeError for anything
    else (what every JSON this package writes holds)."""
    if hasattr(x, "dtype") and hasattr(x, "tolist"):  # a numpy number or array
        return x.tolist() if getattr(x, "ndim", 0) else x.item()
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    if isinstance(x, (set, frozenset)):
        return sorted(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")
