"""The files an input is made of: what a source's content hash covers
(exabricks.cache) and what no output may replace (exabricks.util.output).

* A directory (an AMReX plotfile, a RAMSES output) is made of every regular file
  under it, symbolic links inside it followed (a loop of links is refused).
* A file is made of itself and the siblings that a reader may also read:
  - those named after it and a suffix (``NAME.*``: an Enzo output's
    ``.hierarchy``, ``.boundary`` and ``.cpuNNNN`` files, an Athena++ file's
    ``.xdmf``);
  - for an ExaJet ``STEM.cells`` file, its ``STEM.FIELD.scalars``.
  Siblings with the suffix of a file that exabricks itself writes (an image, a
  movie, a mesh, an intermediate ``.npz``, a ``.npy`` or a scene ``.json``) are
  never part of a source: ``render DD0046 -o DD0046.png`` may run again, and its
  picture does not change the source's hash.
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import ExabricksError

# What exabricks writes: images, movies, meshes, stage outputs, probe values, scenes.
WRITTEN_SUFFIXES = frozenset((".png", ".exr", ".gif", ".mp4", ".ply", ".obj", ".stl",
                              ".npz", ".npy", ".json"))

_MAX_DEPTH = 256


def members(path: str | os.PathLike) -> list[tuple[str, Path]]:
    """(name, path) of every file that `path` is made of, sorted by name: a
    directory's files by their names relative to it, a file and its siblings by
    their own names (module docstring). OSError where the source cannot be read."""
    path = Path(path)
    if path.is_dir():
        return walk(path)
    name = path.name
    stem = name.rsplit(".", 1)[0] if "." in name[1:] else name
    found = {name: path}
    try:
        siblings = list(path.parent.iterdir())
    except OSError:
        siblings = []
    for p in siblings:
        n = p.name
        ours = os.path.splitext(n)[1].lower() in WRITTEN_SUFFIXES
        named = n.startswith(name + ".")
        scalars = name.endswith(".cells") and n.startswith(stem + ".") and n.endswith(".scalars")
        if (named or scalars) and not ours and p.is_file():
            found[n] = p
    return sorted(found.items())


def walk(top: Path) -> list[tuple[str, Path]]:
    """(relative name, path) of every regular file under directory `top`, sorted
    by name, following symbolic links; ExabricksError on a loop of links (a
    directory that leads back to one that holds it)."""
    out: list[tuple[str, Path]] = []

    def visit(directory: Path, rel: str, held: frozenset) -> None:
        st = os.stat(directory)
        ident = (st.st_dev, st.st_ino)
        if ident in held:
            raise ExabricksError(f"{top}: a loop of symbolic links: {rel} leads back to a "
                                 "directory that holds it")
        if len(held) > _MAX_DEPTH:
            raise ExabricksError(f"{top}: directories nested more than {_MAX_DEPTH} deep "
                                 f"at {rel}")
        held = held | {ident}
        with os.scandir(directory) as it:
            found = sorted(it, key=lambda e: e.name)
        for e in found:
            name = f"{rel}/{e.name}" if rel else e.name
            try:
                is_dir = e.is_dir(follow_symlinks=True)
                is_file = not is_dir and e.is_file(follow_symlinks=True)
            except OSError:
                continue
            if is_dir:
                visit(Path(e.path), name, held)
            elif is_file:
                out.append((name, Path(e.path)))

    visit(top, "", frozenset())
    return out
