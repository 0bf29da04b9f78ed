"""Saving and loading the file kinds: `save` (validated, written through
exabricks.util.output), `load` (headers checked before any array is read, mapped or
read, validated) and `peek` (the header alone).
"""

from __future__ import annotations

import json
import os

import numpy as np

from ..util.version import __version__
from ..util.errors import ExabricksError
from ..util.jsonfile import json_default
from ..util.output import write_output
from .checks import check_declared, check_implied_sizes, validate
from .kinds import KINDS, Kind
from .memory import check_memory
from .npz import FORMAT, NpzArchive, read_header
from .provenance import content_sha256


def save(path: str | os.PathLike, obj: Kind, *, inputs=()) -> None:
    """Validate `obj` and write it to `path` through exabricks.util.output (atomic
    for files, direct for devices; refused if `path` names one of `inputs`)."""
    validate(obj, str(path))
    meta = dict(obj.meta)
    meta["fields"] = list(obj.fields)
    meta["content_sha256"] = content_sha256(obj)
    header = {
        "format": np.array(FORMAT),
        "kind": np.array(obj.KIND),
        "version": np.array(obj.VERSION, dtype=np.int32),
        "meta": np.array(json.dumps(meta, sort_keys=True, default=json_default)),
    }

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, **header, **obj.arrays())
            f.flush()
            os.fsync(f.fileno())

    write_output(path, write, inputs=inputs)


def peek(path: str | os.PathLike) -> tuple[str, int, dict]:
    """(kind, version, meta) of an exabricks file, without reading the arrays."""
    with NpzArchive(path) as z:
        return read_header(z, str(path))


def load(path: str | os.PathLike, kind: str | None = None, *, mapped: bool = False,
         checked: bool | None = None, digest: bool = False) -> Kind:
    """Read and validate an exabricks file; with `kind`, refuse any other kind.

    The arrays' dtypes and shapes are read from their .npy headers and checked
    against the schema (and against the sizes the zip directory records)
    before any array is decompressed, so a crafted file cannot make the
    loader allocate more than the file claims consistently.

    `mapped`: the large stored arrays are mapped read-only from the file instead
    of read (pages come in as they are used).  `checked` (default: not `mapped`)
    validates the whole file; a mapped file is then checked in steps, its CRCs
    too, handing its pages back as it goes, so that a builder holds only what it
    uses.  Mapped and unchecked, only dtypes and shapes are checked: for a caller
    that uses a part of the data and validates that part itself
    (exabricks.engine.domains.domain_data, whose output goes through `validate`
    like any file).

    `digest`: hash the file on a background thread, from the descriptor its
    arrays are read and mapped through, for the `inputs` of the `make_meta` of
    what is built from it (`sha256_file`)."""
    where = str(path)
    with NpzArchive(path, digest=digest) as z:
        found, version, meta = read_header(z, where)
        if kind is not None and found != kind:
            raise ExabricksError(f"{where}: expected a {kind} file, found a {found} file")
        cls = KINDS[found]
        if version != cls.VERSION:
            newer = "newer" if version > cls.VERSION else "older"
            raise ExabricksError(
                f"{where}: {found} file version {version} is {newer} than this exabricks "
                f"reads (version {cls.VERSION}); rebuild it with exabricks {__version__}"
            )
        fields = meta.pop("fields", None)
        if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
            raise ExabricksError(f"{where}: meta has no list of field names")
        headers = {}
        for name in cls.SPECS:
            if name not in z.files:
                raise ExabricksError(f"{where}: array {name!r} is missing")
            headers[name] = z.header(name)
        check_declared(cls, headers, len(fields), where)
        sizes = {name: int(np.prod(shape)) * dtype.itemsize for name, (shape, dtype) in headers.items()}
        check_memory(sum(sizes.values()), where)
        # Smallest first: the sizes the small arrays imply are checked against the
        # large ones' headers before those are decompressed.
        arrays = {}
        for name in sorted(cls.SPECS, key=sizes.get):
            check_implied_sizes(cls, arrays, headers, where)
            arrays[name] = z.array(name, mapped=mapped)
            if mapped and checked:
                z.check_crc(name, arrays[name])
    obj = cls(fields=tuple(fields), meta=meta, **arrays)
    if checked or (checked is None and not mapped):
        validate(obj, where)
    return obj
