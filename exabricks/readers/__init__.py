"""Readers that turn AMR files of many codes into leaf `Cells`, one module per format.

Every reader module exposes ``read(path, *, fields=None, **options) -> schema.Cells``
and raises ExabricksError naming the file for bad input.  This package picks the
reader (`detect_format` for ``--format auto``) and imports it only when used, so
formats whose dependencies are missing (yt) cost nothing until asked for.
"""

from __future__ import annotations

import importlib
import os
import re
import stat
from pathlib import Path

from ..util.errors import ExabricksError, quoted
from ..util.jsonfile import kind_of, not_regular
from ..schema import Cells

FORMATS = ("exajet", "amrex", "athena", "ramses", "raw", "yt")

# File names that yt's front ends own, checked before asking yt itself (importing yt
# takes seconds).  FLASH: base_hdf5_plt_cnt_0100 / _chk_; Chombo: x.3d.hdf5.
_YT_NAME_PATTERNS = (
    re.compile(r"_hdf5_(plt_cnt|chk)_\d+$"),
    re.compile(r"\.[23]d\.hdf5$"),
)


def detect_format(path: str | Path, *, dims=None) -> str:
    """The format of `path` for ``--format auto``: one of FORMATS.

    A directory with ``Header`` and ``Level_0/`` is an AMReX plotfile; ``*.athdf``
    is Athena++; an ``output_NNNNN`` folder with ``info_NNNNN.txt`` (or that file,
    beside ``amr_NNNNN.out*`` files) is RAMSES; ``*.cells`` is ExaJet;
    ``*.raw``/``*.bin`` is a raw volume (which needs `dims`); an Enzo output (``NAME``
    with a ``NAME.hierarchy`` sibling), a FLASH or Chombo file, or anything else one
    of yt's front ends claims, is yt.
    """
    fmt = guess_format(path, dims=dims)
    if fmt is None:
        raise unknown_format(path)
    return fmt


def unknown_format(path: str | Path) -> ExabricksError:
    """The error for a source no format claims: use --format, and for a folder that
    holds AMReX plotfiles (a run's folder, given where one of its plotfiles belongs)
    a hint naming them."""
    message = f"cannot tell the format of {path}; use --format"
    plotfiles = plotfiles_in(path)
    if plotfiles:
        names = [p.name for p in plotfiles]
        shown = ", ".join(names) if len(names) <= 3 else f"{names[0]}, {names[1]}, ..., {names[-1]}"
        stem = os.path.commonprefix(names).rstrip("0123456789")
        glob = Path(path) / f"{stem}*" if stem else None
        # a command to copy: the whole path, however long (the message names it anyway)
        series = f", or every step with exabricks series '{glob}'" if glob else ""
        message = (f"{path} is a folder of {len(names)} AMReX plotfile{'s' if len(names) > 1 else ''} "
                   f"({shown}), not a plotfile: give one, e.g. {Path(path) / names[-1]}{series}")
    return ExabricksError(message)


def plotfiles_in(path: str | Path, limit: int = 10000) -> list[Path]:
    """The AMReX plotfiles (folders with a Header and Level_0/) directly inside the
    folder `path`, in natural order of their names (plt10 after plt9); [] for anything
    else. Looks at `limit` entries at most."""
    folder = Path(path)
    try:
        if not folder.is_dir():
            return []
        found = []
        for k, entry in enumerate(os.scandir(folder)):
            if k >= limit:
                break
            candidate = Path(entry.path)
            if entry.is_dir() and (candidate / "Header").is_file() and (candidate / "Level_0").is_dir():
                found.append(candidate)
    except OSError:
        return []
    return sorted(found, key=lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)])


def guess_format(path: str | Path, *, dims=None, ask_yt: bool = True) -> str | None:
    """`detect_format`'s answer, or None where no format claims `path` (`ask_yt`:
    whether to ask yt's front ends, which takes seconds, about a name no rule knows).
    Raises ExabricksError for a missing path and a raw volume without `dims`."""
    path = given_path(path)
    if not path.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    _refuse_special(path)
    name = path.name
    if path.is_dir():
        header = path / "Header"
        if (path / "Level_0").is_dir() and header.exists():
            why = not_regular(header)
            if why is not None:
                raise ExabricksError(f"{header}: the plotfile Header is {why}, not a regular file")
            return "amrex"
        if _is_ramses(path):
            return "ramses"
    elif name.endswith(".athdf"):
        return "athena"
    elif name.endswith(".cells"):
        return "exajet"
    elif name.endswith((".raw", ".bin")):
        if dims is None:
            raise ExabricksError(f"{path}: a raw volume needs its size: give --dims X Y Z")
        return "raw"
    elif _is_ramses(path):  # after the suffixes: the reader's import is not free
        return "ramses"
    enzo = bool(name) and path.with_name(name + ".hierarchy").is_file()  # "." has no name
    if enzo or any(p.search(name) for p in _YT_NAME_PATTERNS):
        return "yt"
    if ask_yt and _safe_for_yt(path) and _yt_claims(path):
        return "yt"
    return None


def _is_ramses(path: Path) -> bool:
    from . import ramses
    return ramses.is_output(path)


def given_path(path) -> Path:
    """`path` as a Path; ExabricksError for an empty one, which pathlib would take for
    the current directory (an unset variable in a script, not a wish to read ".")."""
    if isinstance(path, (str, bytes, os.PathLike)) and not os.fspath(path):
        raise ExabricksError(f"{path!r}: an empty path: give a file or a directory")
    return Path(path)


def _refuse_special(path: Path) -> None:
    """ExabricksError unless `path` is a regular file or a directory: detection never
    opens a FIFO or a device (an open would block, or read a device)."""
    mode = path.stat().st_mode
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise ExabricksError(f"{path}: {kind_of(mode)}, not a dataset file or directory")


# Entries of a directory looked at before yt's front ends may open them.
_MAX_PROBED_ENTRIES = 10_000


def _safe_for_yt(path: Path) -> bool:
    """Whether yt's front ends may probe `path`: they open files in a directory (and a
    file's siblings) by name, so one FIFO or device among them would block or be read.
    Raises ExabricksError naming the first such entry."""
    folder = path if path.is_dir() else path.parent
    try:
        with os.scandir(folder) as entries:
            for i, entry in enumerate(entries):
                if i >= _MAX_PROBED_ENTRIES:
                    return False
                try:
                    mode = os.stat(entry.path).st_mode
                except OSError:
                    continue  # a dangling link: nothing to open
                if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                    raise ExabricksError(f"{path}: cannot tell its format: {entry.path} is "
                                         f"{kind_of(mode)}, not a regular file; use --format")
    except OSError:
        return False
    return True


def _yt_claims(path: Path) -> bool:
    """Whether any yt front end says it can load `path` (False when yt is missing)."""
    try:
        from yt.data_objects.static_output import Dataset  # noqa: F401  (registers the registry)
        from yt.frontends import _all  # noqa: F401  (imports every front end)
        from yt.utilities.object_registries import output_type_registry
    except ImportError:
        return False
    for cls in output_type_registry.values():
        try:
            if cls._is_valid(str(path)):
                return True
        except Exception:  # a front end's probe failing on a foreign file means "not mine"
            continue
    return False


def read(path: str | Path, *, format: str = "auto", fields=None, **options) -> Cells:
    """Leaf cells of `path` read by the reader of `format` (``auto``: `detect_format`).

    fields: names to keep, in that order (None: all); an unknown name is an error
    that lists the available ones.  options go to the reader (``scalars`` for
    exajet; ``dims``, ``dtype``, ``name``, ``max_level``, ``threshold``,
    ``byte_order`` for raw).
    """
    path = Path(path)
    if format == "auto":
        format = detect_format(path, dims=options.get("dims"))
    elif format not in FORMATS:
        raise ExabricksError(f"unknown format {format!r} (known: auto, {', '.join(FORMATS)})")
    elif not path.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    module = importlib.import_module(f"{__name__}.{'yt_bridge' if format == 'yt' else format}")
    cells = module.read(path, fields=list(fields) if fields else None, **options)
    return select_fields(cells, fields, source=str(path))


def field_names(path: str | Path, *, format: str, **options) -> list[str] | None:
    """The names of the fields `path` holds, from its headers only (no data is read).

    format: one of FORMATS (not auto).  None where that is not cheap (yt loads the
    whole dataset index to know).  Raises ExabricksError for a bad header.
    """
    path = Path(path)
    if not path.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    if format == "amrex":
        from . import amrex
        return list(amrex.field_names(path))
    if format == "athena":
        from . import athena
        return list(athena.field_names(path))
    if format == "exajet":
        if options.get("scalars") is not None:
            return list(options["scalars"])
        from . import exajet
        return list(exajet.scalar_files(path))
    if format == "raw":
        return [options.get("name", "value")]
    if format == "ramses":
        from . import ramses
        return ramses.field_names(path)
    return None


def select_fields(cells: Cells, fields, *, source: str) -> Cells:
    """`cells` with only `fields`, in that order (None or empty: unchanged)."""
    if not fields:
        return cells
    fields = list(fields)
    missing = [f for f in fields if f not in cells.fields]
    if missing:
        raise ExabricksError(
            f"{source}: no field {quoted(missing[0])} (fields: {', '.join(cells.fields) or 'none'})"
        )
    if len(set(fields)) != len(fields):
        raise ExabricksError(f"{source}: field listed twice in {fields}")
    if tuple(fields) == cells.fields:
        return cells
    rows = [cells.fields.index(f) for f in fields]
    return cells.replace(fields=tuple(fields), values=cells.values[rows])
