"""The cache of built structures: the bricks, regions and BVH that a source-taking
`render`, `probe` or `eb.open` built from a source, and the BVHs of mesh files
(exabricks.mesh), kept by content.

An entry is a directory `<root>/<key>/` with its files (the three structure
files, or MESH_FILES) and `entry.json` (what it was built from). The key is the sha256 of the source's
content (`source_digest`), of the build options, and of this exabricks' own
code (`code_digest`), so an entry can only be found by the inputs and the
parameters that built it, and a changed file or a new exabricks misses.

Entries are built in a private directory under the root and renamed into place:
two builds of one source at once both finish, the first rename wins and the
second build's directory is dropped. An entry is loaded and checked like any
file, and its structures carry their key and the source's content hash in their
provenance (`record`), checked against both on load: one that fails the checks
(or that is not whole: a member missing, a directory or a FIFO) is removed and
built again. A build holds an exclusive lock (flock) on its private directory,
and a process that uses an entry a shared one (`Cache.lease`): `clear` never
removes what a live process holds. `clear` removes only what this module made
(entry directories that hold an entry.json or entry members, and what is left
of unfinished builds), never anything else a user keeps under the root.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import os
import re
import shutil
import stat
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from .util.version import __version__
from .util.errors import ExabricksError
from .util import source_files

log = logging.getLogger(__name__)

FILES = ("bricks.npz", "regions.npz", "bvh.npz")
MESH_FILES = ("meshes.npz",)
ENTRY = "entry.json"
_KEY = re.compile(r"[0-9a-f]{64}")
_BUILDING = ".eb-build-"


def default_root() -> Path:
    """$EXABRICKS_CACHE, else $XDG_CACHE_HOME/exabricks, else ~/.cache/exabricks."""
    if os.environ.get("EXABRICKS_CACHE"):
        return Path(os.environ["EXABRICKS_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "exabricks"


def source_digest(path: str | os.PathLike) -> str:
    """The sha256 of what a source holds: the relative name and content of every
    file it is made of (exabricks.util.source_files: a directory's every file, or
    a file with the siblings a reader may also read)."""
    from .formats.provenance import sha256_file

    h = hashlib.sha256()
    try:
        for name, member in source_files.members(path):
            h.update(json.dumps([name, sha256_file(member)]).encode())
    except OSError as e:
        raise ExabricksError(f"{path}: cannot read the source ({e.strerror or e})") from None
    return h.hexdigest()


_CODE: list[str] = []


def code_digest() -> str:
    """The sha256 of this exabricks' Python code: any change to a reader or a
    builder makes every entry miss."""
    if not _CODE:
        root = Path(__file__).resolve().parent
        h = hashlib.sha256(__version__.encode())
        for p in sorted(root.rglob("*.py")):
            h.update(p.relative_to(root).as_posix().encode())
            h.update(p.read_bytes())
        _CODE.append(h.hexdigest())
    return _CODE[0]


def key(source: str | os.PathLike, options: dict, source_sha256: str | None = None) -> str:
    """The entry key of `source` built with ingest `options` (a JSON-able dict whose
    file paths, such as --scalars files, are hashed in); `source_sha256`: the
    source's `source_digest`, where already known."""
    files = {name: source_digest(p) for name, p in sorted((options.get("scalars") or {}).items())}
    material = {"cache": 1, "code": code_digest(),
                "source": source_sha256 or source_digest(source),
                "options": options, "files": files}
    return hashlib.sha256(json.dumps(material, sort_keys=True, default=str).encode()).hexdigest()


def mesh_key(paths, digests=None) -> str:
    """The entry key of the BVH of the mesh files `paths` (in order), by content
    (`digests`: their sha256, where already known)."""
    from .formats.provenance import sha256_file

    material = {"cache": 1, "kind": "meshes", "code": code_digest(),
                "files": list(digests) if digests is not None else [sha256_file(p) for p in paths]}
    return hashlib.sha256(json.dumps(material, sort_keys=True).encode()).hexdigest()


class EntryNotWritten(ExabricksError):
    """An entry could not be written under a usable root (a full disk): what was
    built can still be used, uncached."""


def record(k: str, source_sha256: str) -> dict:
    """What the structures of entry `k` carry in their provenance (meta key
    `cache`): the key and the source's content hash, checked on load (`check`)."""
    return {"key": k, "source_sha256": source_sha256}


def check(objs, paths, k: str, source_sha256: str) -> None:
    """ExabricksError (naming the file) unless every one of `objs` (loaded from
    `paths`) records entry `k` and the source's content hash `source_sha256`: an
    entry swapped with another's, or a member copied in from another entry, is
    refused."""
    for obj, where in zip(objs, paths):
        recorded = obj.meta.get("cache") if isinstance(obj.meta, dict) else None
        if not isinstance(recorded, dict):
            raise ExabricksError(f"{where}: records no cache key (not built by this cache)")
        if recorded.get("key") != k:
            raise ExabricksError(f"{where}: belongs to another cache entry "
                                 f"({str(recorded.get('key'))[:12]}..., not {k[:12]}...)")
        if recorded.get("source_sha256") != source_sha256:
            raise ExabricksError(f"{where}: was built from another source's content "
                                 f"({str(recorded.get('source_sha256'))[:12]}..., not "
                                 f"{source_sha256[:12]}...)")


class Lease:
    """A lock held on a directory of the cache while it is in use (shared: an entry
    being read; exclusive: a build), released by `release` or when dropped."""

    def __init__(self, fd: int):
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the lock
            self._fd = None

    def __del__(self):
        self.release()


def _lock(directory: Path, how: int) -> Lease | None:
    """A Lease of `directory` (not followed if a symbolic link), or None where it is
    gone, not a directory or (with LOCK_NB) held by another process."""
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW
                     | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        fcntl.flock(fd, how)
        # Still the directory at that path (not removed, nor replaced, meanwhile)?
        st, own = os.stat(directory, follow_symlinks=False), os.fstat(fd)
        if (st.st_dev, st.st_ino) != (own.st_dev, own.st_ino):
            raise FileNotFoundError(directory)
    except OSError:
        os.close(fd)
        return None
    return Lease(fd)


@dataclass(frozen=True)
class Cache:
    """The entries under `root`."""

    root: Path

    def paths(self, k: str, files=FILES) -> tuple[Path, ...] | None:
        """The `files` of entry `k`, or None where there is no whole one (a member
        missing, or not a regular file; a symbolic link in the entry's place)."""
        entry = self.root / k
        if entry.is_symlink() or not (entry / ENTRY).is_file() or not all((entry / f).is_file() for f in files):
            return None
        return tuple(entry / f for f in files)

    def lease(self, k: str) -> Lease | None:
        """A shared lock on entry `k` while this process uses it (`clear` leaves it),
        or None where there is no entry `k` now."""
        return _lock(self.root / k, fcntl.LOCK_SH)

    def put(self, k: str, write, about: dict, files=FILES) -> tuple[Path, ...]:
        """Entry `k` made by `write(directory)` (which writes `files` into a private
        directory, locked while it is built), renamed into place; an entry that
        another process put there first is kept and ours dropped, and a broken one
        (not whole) is replaced. ExabricksError where the root cannot be written,
        EntryNotWritten where the entry cannot (naming the entry, never the
        private directory)."""
        entry = self.root / k
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            building, held = self._building()
        except OSError as e:
            raise ExabricksError(f"{self.root}: cannot write the cache ({e.strerror or e}); "
                                 "give --cache DIR or --no-cache") from None
        try:
            try:
                write(building)
                (building / ENTRY).write_text(json.dumps(
                    {**about, "key": k, "software": f"exabricks {__version__}",
                     "created": time.time()}, sort_keys=True, default=str))
                for attempt in range(2):
                    try:
                        os.rename(building, entry)
                        break
                    except OSError:
                        if self.paths(k, files) is not None:
                            log.debug("%s: another process built this entry first", entry)
                            break
                        if attempt or not os.path.lexists(entry):
                            raise
                        log.debug("%s: a broken entry: replaced", entry)
                        self.drop(k)
            except OSError as e:
                raise EntryNotWritten(f"{entry}: cannot write the cache entry "
                                      f"({e.strerror or e})") from None
            except ExabricksError as e:
                raise EntryNotWritten(str(e).replace(str(building), str(entry))) from None
        finally:
            held.release()
            _discard(building)
        found = self.paths(k, files)
        if found is None:
            raise EntryNotWritten(f"{entry}: cannot write the cache entry (it was removed "
                                 "while it was written)")
        return found

    def _building(self) -> tuple[Path, Lease]:
        """A private directory under the root, locked (exclusive) for a build."""
        while True:
            building = Path(tempfile.mkdtemp(prefix=_BUILDING, dir=self.root))
            held = _lock(building, fcntl.LOCK_EX)
            if held is not None:
                return building, held
            # `clear` removed it before we locked it: make another

    def drop(self, k: str) -> None:
        """Remove entry `k` (a damaged or a broken one; a symbolic link in its place
        is removed, never what it points to)."""
        _remove(self.root / k)

    def entries(self) -> list[tuple[str, int, dict]]:
        """(key, bytes, entry.json as a dict, {} where it is not one) of every entry."""
        from .util.jsonfile import read_small

        out = []
        for p in _listing(self.root):
            if _KEY.fullmatch(p.name) and not p.is_symlink() and (p / ENTRY).is_file():
                try:
                    about = json.loads(read_small(p / ENTRY, "a cache entry's entry.json"))
                except (OSError, ValueError, ExabricksError):
                    about = {}
                out.append((p.name, _size(p), about if isinstance(about, dict) else {}))
        return out

    def clear(self) -> tuple[int, int]:
        """Remove every entry, whole or broken, and what is left of unfinished builds,
        except what a live process holds: (entries removed, bytes freed)."""
        n = freed = 0
        for p in _listing(self.root):
            if p.name.startswith(_BUILDING):
                if p.is_symlink() or not p.is_dir():
                    _unlink(p)  # left by an older exabricks: never followed
                    continue
            elif not (_KEY.fullmatch(p.name) and not p.is_symlink() and p.is_dir()
                      and any(os.path.lexists(p / f) for f in (ENTRY, *FILES, *MESH_FILES))):
                continue  # not ours
            held = _lock(p, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if held is None:
                continue  # in use by a live process (or gone)
            try:
                size = _size(p)
                if _remove(p):
                    freed += size
                    n += not p.name.startswith(_BUILDING)
            finally:
                held.release()
        return n, freed


def _remove(entry: Path) -> bool:
    """Remove an entry: renamed aside first, so that no reader finds half of one;
    whether it was there."""
    aside = entry.with_name(f"{_BUILDING}{entry.name[:16]}-{os.getpid()}-{time.monotonic_ns()}")
    try:
        os.rename(entry, aside)
    except OSError:
        return False
    _discard(aside)
    return True


def _discard(p: Path) -> None:
    """Remove `p`: a directory with what it holds, a symbolic link (not followed) or
    anything else."""
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        _unlink(p)


def _unlink(p: Path) -> None:
    try:
        p.unlink()
    except OSError:
        pass


def _listing(root: Path) -> list[Path]:
    """What `root` holds, sorted; nothing where it is missing (or removed meanwhile)."""
    try:
        return sorted(root.iterdir())
    except OSError:
        return []


def _size(directory: Path) -> int:
    """Bytes of the regular files under `directory`, links not followed. Other
    processes build and clear entries meanwhile: a file or folder that vanishes
    between its listing and its stat counts nothing (Path.rglob raised
    FileNotFoundError for a folder removed while it walked)."""
    total = 0
    folders = [directory]
    while folders:  # a stack, not recursion: a folder nested thousands deep is summed too
        try:
            with os.scandir(folders.pop()) as it:
                found = list(it)
        except OSError:
            continue
        for e in found:
            try:
                st = e.stat(follow_symlinks=False)
            except OSError:
                continue
            if stat.S_ISDIR(st.st_mode):
                folders.append(Path(e.path))
            elif stat.S_ISREG(st.st_mode):
                total += st.st_size
    return total
