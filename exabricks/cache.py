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
file; one that fails the checks is removed and built again. `clear` removes
only what this module made (entry directories that hold an entry.json, and
unfinished builds), never anything else a user keeps under the root.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from . import __version__
from .errors import ExabricksError

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
    """The sha256 of what a source holds: a directory's every file (relative name
    and content), or a file with its siblings that share its name up to the last
    suffix (an Enzo output's .hierarchy and .cpu files, a Gerris .cells file's
    .scalars), which a reader may also read."""
    from .formats.provenance import sha256_file

    path = Path(path)
    h = hashlib.sha256()
    try:
        if path.is_dir():
            members = sorted(p for p in path.rglob("*") if p.is_file())
            names = [p.relative_to(path).as_posix() for p in members]
        else:
            stem = path.name.rsplit(".", 1)[0] if "." in path.name[1:] else path.name
            members = sorted(p for p in path.parent.iterdir()
                             if p.name.startswith(stem) and p.is_file())
            if path not in members:
                members.append(path)
            names = [p.name for p in members]
        for name, member in zip(names, members):
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


def key(source: str | os.PathLike, options: dict) -> str:
    """The entry key of `source` built with ingest `options` (a JSON-able dict whose
    file paths, such as --scalars files, are hashed in)."""
    files = {name: source_digest(p) for name, p in sorted((options.get("scalars") or {}).items())}
    material = {"cache": 1, "code": code_digest(), "source": source_digest(source),
                "options": options, "files": files}
    return hashlib.sha256(json.dumps(material, sort_keys=True, default=str).encode()).hexdigest()


def mesh_key(paths) -> str:
    """The entry key of the BVH of the mesh files `paths` (in order), by content."""
    from .formats.provenance import sha256_file

    material = {"cache": 1, "kind": "meshes", "code": code_digest(),
                "files": [sha256_file(p) for p in paths]}
    return hashlib.sha256(json.dumps(material, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class Cache:
    """The entries under `root`."""

    root: Path

    def paths(self, k: str, files=FILES) -> tuple[Path, ...] | None:
        """The `files` of entry `k`, or None where there is none."""
        entry = self.root / k
        if not (entry / ENTRY).is_file() or not all((entry / f).is_file() for f in files):
            return None
        return tuple(entry / f for f in files)

    def put(self, k: str, write, about: dict, files=FILES) -> tuple[Path, ...]:
        """Entry `k` made by `write(directory)` (which writes `files` into a private
        directory), renamed into place; an entry that another process put there
        first is kept and ours dropped."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            building = Path(tempfile.mkdtemp(prefix=_BUILDING, dir=self.root))
        except OSError as e:
            raise ExabricksError(f"{self.root}: cannot write the cache ({e.strerror or e}); "
                                 "give --cache DIR or --no-cache") from None
        try:
            write(building)
            (building / ENTRY).write_text(json.dumps(
                {**about, "software": f"exabricks {__version__}", "created": time.time()},
                sort_keys=True, default=str))
            try:
                os.rename(building, self.root / k)
            except OSError:
                if self.paths(k, files) is None:
                    raise
                log.debug("%s: another process built this entry first", self.root / k)
        finally:
            shutil.rmtree(building, ignore_errors=True)
        return self.paths(k, files)

    def drop(self, k: str) -> None:
        """Remove entry `k` (a damaged one)."""
        _remove(self.root / k)

    def entries(self) -> list[tuple[str, int, dict]]:
        """(key, bytes, entry.json) of every entry."""
        out = []
        if not self.root.is_dir():
            return out
        for p in sorted(self.root.iterdir()):
            if _KEY.fullmatch(p.name) and not p.is_symlink() and (p / ENTRY).is_file():
                try:
                    about = json.loads((p / ENTRY).read_text())
                except (OSError, ValueError):
                    about = {}
                out.append((p.name, _size(p), about))
        return out

    def clear(self) -> tuple[int, int]:
        """Remove every entry and unfinished build: (entries removed, bytes freed)."""
        n = freed = 0
        for k, size, _ in self.entries():
            _remove(self.root / k)
            n, freed = n + 1, freed + size
        if self.root.is_dir():
            for p in self.root.iterdir():
                if p.name.startswith(_BUILDING) and p.is_dir() and not p.is_symlink():
                    freed += _size(p)
                    shutil.rmtree(p, ignore_errors=True)
        return n, freed


def _remove(entry: Path) -> None:
    """Remove an entry: renamed aside first, so that no reader finds half of one."""
    aside = entry.with_name(f"{_BUILDING}{entry.name[:16]}-{os.getpid()}")
    try:
        os.rename(entry, aside)
    except OSError:
        return
    shutil.rmtree(aside, ignore_errors=True)


def _size(directory: Path) -> int:
    return sum(p.stat().st_size for p in directory.rglob("*") if p.is_file() and not p.is_symlink())
