"""Provenance: the sha256 of input files (hashed on background threads from the
descriptor their data came from), the meta every output carries (`make_meta`),
the digest of what a file holds (`content_sha256`) and the build chain
(`built_from`, `check_built_from`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..util.version import __version__
from ..util.errors import ExabricksError
from .kinds import Kind


def sha256_file(path: str | os.PathLike) -> str | None:
    """The sha256 (hex) of input `path`: of the bytes read through the descriptor
    its data came from, when it was opened by `load(digest=True)` or
    `prefetch_sha256`, else of the file now; None for what is not a regular file
    (an AMReX plotfile directory)."""
    pending = _DIGESTS.get(os.fspath(path))
    if pending is not None:
        return pending.result()
    from ..util.jsonfile import open_regular

    try:
        with open_regular(path, "an input") as f:
            return _sha256_fd(f.fileno())
    except ExabricksError:
        return None


def prefetch_sha256(paths) -> None:
    """Start hashing the regular files among `paths` on background threads, each
    from the file as opened now, so that `make_meta` at the end of a command finds
    their digests ready instead of reading the inputs once more (hashlib and
    file reads release the GIL; a daemon thread never holds up an interrupted
    command's exit)."""
    from ..util.jsonfile import open_regular

    for p in paths:
        try:
            with open_regular(p, "an input") as f:
                hash_in_background(p, f.fileno())
        except ExabricksError:
            continue


# The inputs being hashed: path as given -> Future of the sha256 of the file
# that was opened under that path (the bytes read, even if a rename has since
# put another file there).
_DIGESTS: dict = {}


def hash_in_background(path, fd: int) -> None:
    """Hash the file open on `fd` (through a duplicate of it) on a daemon thread,
    as `path`'s digest."""
    import threading
    from concurrent.futures import Future

    own = os.dup(fd)
    future = Future()

    def run():
        try:
            future.set_result(_sha256_fd(own))
        except BaseException as e:  # re-raised by sha256_file in the main thread
            future.set_exception(e)
        finally:
            os.close(own)

    _DIGESTS[os.fspath(path)] = future
    threading.Thread(target=run, name="sha256", daemon=True).start()


def _sha256_fd(fd: int, chunk: int = 1 << 22) -> str:
    h = hashlib.sha256()
    offset = 0
    while block := os.pread(fd, chunk, offset):
        h.update(block)
        offset += len(block)
    return h.hexdigest()


def make_meta(
    inputs: list[str | os.PathLike] = (),
    parameters: dict[str, Any] | None = None,
    statistics: dict[str, Any] | None = None,
    upstream: Kind | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The provenance every output carries: software, command line, input hashes,
    and what it was built from (`upstream`, the loaded input: `built_from`)."""
    if upstream is not None:
        extra["built_from"] = built_from(upstream)
    return {
        "software": f"exabricks {__version__}",
        "command": shlex.join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "inputs": [
            {"path": str(p), "sha256": sha256_file(p)}
            for p in inputs
        ],
        "parameters": parameters or {},
        "statistics": statistics or {},
        **extra,
    }


def content_sha256(obj: Kind) -> str:
    """The sha256 (hex) of what `obj` holds: its kind, field names and every array
    (name, dtype, shape, bytes). `save` stores it in the file's meta; the files
    built from it record it as `meta.built_from` (`built_from`, `check_built_from`),
    so that a consumer checks a chain of files by comparing stored digests."""
    h = hashlib.sha256(json.dumps([obj.KIND, list(obj.fields)]).encode())
    for name in sorted(obj.SPECS):
        a = np.ascontiguousarray(getattr(obj, name))
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        flat = a.reshape(-1).view(np.uint8)
        for start in range(0, flat.size, 1 << 26):
            h.update(flat[start:start + (1 << 26)])
    return h.hexdigest()


def built_from(source: Kind) -> dict:
    """What a file built from `source` records of it (meta key `built_from`)."""
    return {"kind": source.KIND, "content_sha256": source.meta.get("content_sha256")}


def check_built_from(obj: Kind, where, source: Kind, source_where) -> None:
    """ExabricksError (one line naming both files) unless `obj` (read from `where`)
    records that it was built from `source` (read from `source_where`): the
    regions from the bricks, the BVH from the regions. Files that predate the
    record, or objects built in memory, carry none and are checked by their
    counts and frames only (exabricks.engine.device_data.check_inputs)."""
    recorded = obj.meta.get("built_from")
    recorded = recorded.get("content_sha256") if isinstance(recorded, dict) else None
    actual = source.meta.get("content_sha256")
    if recorded is None or actual is None or recorded == actual:
        return
    raise ExabricksError(
        f"{where}: was built from another {source.KIND} file than {source_where} (it records "
        f"{source.KIND} content sha256 {str(recorded)[:12]}..., {source_where} holds "
        f"{str(actual)[:12]}...): rebuild it from {source_where}")
