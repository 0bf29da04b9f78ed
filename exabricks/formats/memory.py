"""Memory: handing back the pages of mapped arrays (`release`, `release_arrays`),
of arrays whose contents are done with (`discard`) and the C heap
(`trim_heap`), work in steps of about CHUNK elements (`rows`, `reduce_chunks`),
and the memory this process can hold (`memory_limit`, `check_memory` before
allocating).
"""

from __future__ import annotations

import functools
import os

import numpy as np

from ..util.errors import ExabricksError


# Elements per step of `rows` and `reduce_chunks` (1 MiB of float32): a step's
# pages and its temporaries (a few times the step) stay small beside a memory
# budget of a few MiB (docs/design-scale.md, "Rendering under a memory budget").
CHUNK = 1 << 18


def mapping(array: np.ndarray):
    """The mmap behind a mapped array (load(mapped=True)), else None."""
    return getattr(array, "_mmap", None) if isinstance(array, np.memmap) else None


def _hand_back(base, start: int = 0, length: int = 0) -> None:
    """Drop the resident pages of mmap `base` from byte `start` for `length` bytes
    (0: to the end): clean copies of the file, read again if used again."""
    import mmap

    if not hasattr(mmap, "MADV_DONTNEED"):
        return
    if not length:
        base.madvise(mmap.MADV_DONTNEED)
        return
    lo = start // mmap.PAGESIZE * mmap.PAGESIZE
    base.madvise(mmap.MADV_DONTNEED, lo, start + length - lo)


def release(obj) -> None:
    """Hand back the resident pages of `obj`'s mapped arrays (`obj` a file kind)."""
    release_arrays(*obj.arrays().values())


def release_arrays(*arrays: np.ndarray) -> None:
    """Hand back the resident pages of those `arrays` that are mapped."""
    for array in arrays:
        base = mapping(array)
        if base is not None:
            _hand_back(base)


def discard(part: np.ndarray) -> None:
    """Hand back the pages of `part`, a contiguous view of an array this process
    allocated, whose contents are no longer needed: a mapped array's pages are
    handed back (`release_arrays`), an in-memory one's whole pages inside `part`
    read as zeros afterwards and take memory again only when written
    (madvise MADV_DONTNEED on private anonymous memory; a no-op elsewhere).
    For passes that turn one large array into another in steps."""
    import mmap

    if not part.nbytes:
        return
    base = mapping(part)
    if base is not None:
        _hand_back(base, part.ctypes.data - np.frombuffer(base, np.uint8).ctypes.data, part.nbytes)
        return
    if not hasattr(mmap, "MADV_DONTNEED") or not part.flags.c_contiguous:
        return
    page = mmap.PAGESIZE
    lo = -(-part.ctypes.data // page) * page
    hi = (part.ctypes.data + part.nbytes) // page * page
    libc = _libc()
    if hi > lo and libc is not None and hasattr(libc, "madvise"):
        import ctypes

        libc.madvise(ctypes.c_void_p(lo), ctypes.c_size_t(hi - lo), mmap.MADV_DONTNEED)


def trim_heap() -> None:
    """Give the C heap's free memory back to the system (glibc keeps what the
    piece's temporaries used, a few hundred MB on large data); a no-op elsewhere."""
    libc = _libc()
    if libc is not None and hasattr(libc, "malloc_trim"):
        libc.malloc_trim(0)


@functools.cache
def _libc():
    """The C library (ctypes), or None where there is none to load."""
    import ctypes
    import ctypes.util

    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


def rows(*arrays: np.ndarray):
    """Steps of about CHUNK elements (whole rows) along the first axis, which
    `arrays` share: yields (start, [views of rows start.. of each array]).  The pages
    of mapped arrays are handed back after each step, so that a pass over large
    mapped arrays does not keep them resident."""
    n = arrays[0].shape[0]
    width = max(max(1, int(np.prod(a.shape[1:]))) for a in arrays)
    step = max(1, CHUNK // width)
    for start in range(0, n, step):
        parts = [a[start:start + step] for a in arrays]
        yield start, parts
        for a, part in zip(arrays, parts):
            if mapping(a) is not None:
                discard(part)


def reduce_chunks(array: np.ndarray, fn, combine):
    """combine() over fn(chunk) of the `rows` steps of `array` (fn(array[:0]) if it
    has no rows)."""
    result = None
    for _, (part,) in rows(array):
        value = fn(part)
        result = value if result is None else combine(result, value)
    return fn(array[:0]) if result is None else result


def check_memory(nbytes: int, where: str) -> None:
    """Refuse arrays that cannot fit this machine's memory (or the process's limit)."""
    limit = memory_limit()
    if limit is not None and nbytes > limit:
        raise ExabricksError(f"{where}: its arrays need {nbytes / 2**30:.1f} GiB, more than the "
                             f"{limit / 2**30:.1f} GiB of memory available")


def memory_limit() -> int | None:
    """Bytes this process can hold: physical memory, or a lower RLIMIT_AS; None if unknown."""
    limits = []
    try:
        limits.append(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        pass
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            limits.append(soft)
    except (ImportError, ValueError, OSError):
        pass
    return min(limits) if limits else None
