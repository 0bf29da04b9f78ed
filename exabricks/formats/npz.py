"""The .npz reader: `NpzArchive`, a zip archive read member by member through one
descriptor, and the reading of an exabricks file's header entries
(`read_header`).
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from ..util.errors import ExabricksError
from .kinds import KINDS
from .memory import mapping, rows
from .provenance import hash_in_background


FORMAT = "exabricks"
HEADER_KEYS = ("format", "kind", "version", "meta")
# The header entries are short strings; meta (provenance, statistics) stays far below this.
MAX_HEADER_BYTES = 64 << 20


class NpzArchive:
    """A .npz file read member by member, with every failure an ExabricksError.

    `files` lists the member names (without ".npy"); `header(name)` is the
    (shape, dtype) of a member's .npy header, checked against the size the zip
    directory records; `array(name)` reads it (never with pickles)."""

    # Stored (uncompressed, as exabricks writes them) members this large are read
    # straight into their array: one copy from the file, no chunked copies.
    DIRECT_BYTES = 1 << 20
    # With `mapped`, stored members this large are mapped: a per-brick or
    # per-region array of a large dataset is then paged in where it is used and
    # handed back, however many such arrays the files hold (docs/design-scale.md,
    # "Rendering under a memory budget").
    MAP_BYTES = 1 << 16

    def __init__(self, path, *, digest: bool = False):
        self.path = Path(path)
        self.digest = digest
        self.file = None
        self.zip = None
        self._headers = {}  # name -> (shape, dtype, bytes of the .npy header)

    def __enter__(self):
        from ..util.jsonfile import open_regular

        self.file = open_regular(self.path, "an exabricks file")
        try:
            return self._open_zip()
        except BaseException:
            self.file.close()
            raise

    def _open_zip(self):
        p = self.path
        try:
            head = os.pread(self.file.fileno(), 4, 0)
        except OSError as e:
            raise ExabricksError(f"{p}: cannot read ({e.strerror or e})") from None
        if not head:
            raise ExabricksError(f"{p}: empty file, not an exabricks .npz file")
        if head.startswith(b"\x93NUM"):
            raise ExabricksError(f"{p}: a plain .npy array, not an exabricks .npz file")
        if head != b"PK\x03\x04":
            raise ExabricksError(f"{p}: not an exabricks .npz file (not a zip archive; "
                                 "an image, a raw data file or text?)")
        if self.digest:
            hash_in_background(p, self.file.fileno())
        try:
            self.zip = zipfile.ZipFile(self.file)
            self.members = {i.filename[:-4]: i for i in self.zip.infolist()
                            if i.filename.endswith(".npy")}
        except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError,
                NotImplementedError, RuntimeError) as e:
            raise ExabricksError(f"{p}: not a readable exabricks .npz file "
                                 f"(truncated or another format: {e})") from None
        return self

    def __exit__(self, *exc):
        if self.zip is not None:
            self.zip.close()
        if self.file is not None:
            self.file.close()
        return False

    def _pread(self, n: int, offset: int) -> bytes:
        """`n` bytes of the archive at `offset` (fewer at its end), through the one
        descriptor every read of this archive goes through."""
        return os.pread(self.file.fileno(), n, offset)

    @property
    def files(self) -> list[str]:
        return list(self.members)

    def _fail(self, name, problem):
        return ExabricksError(f"{self.path}: array {name!r} {problem}")

    def _open_member(self, name):
        try:
            return self.zip.open(self.members[name])
        except (zipfile.BadZipFile, NotImplementedError, RuntimeError, ValueError, OSError) as e:
            raise self._fail(name, f"cannot be read ({e})") from None

    def header(self, name) -> tuple[tuple[int, ...], np.dtype]:
        if name not in self._headers:
            self._headers[name] = self._read_header(name)
        return self._headers[name][:2]

    def _read_header(self, name) -> tuple[tuple[int, ...], np.dtype, int]:
        fmt = np.lib.format
        info = self.members[name]
        try:
            with self._open_member(name) as f:
                version = fmt.read_magic(f)
                if version == (1, 0):
                    shape, fortran, dtype = fmt.read_array_header_1_0(f)
                elif version == (2, 0):
                    shape, fortran, dtype = fmt.read_array_header_2_0(f)
                else:
                    raise ValueError(f"unsupported .npy version {version}")
                header_bytes = f.tell()
        except ExabricksError:
            raise
        except Exception as e:  # zlib, zipfile and numpy raise many types for bad bytes
            raise self._fail(name, f"has no readable .npy header ({e})") from None
        if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
            raise self._fail(name, f"has dtype {dtype}, not a plain numeric array")
        if fortran and len(shape) > 1:
            raise self._fail(name, "is stored in Fortran order (exabricks writes C order)")
        size = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if header_bytes + size != info.file_size:
            raise self._fail(name, f"claims shape {shape} of {dtype} ({size} bytes) but the "
                                   f"archive holds {info.file_size - header_bytes} bytes for it")
        return tuple(int(x) for x in shape), dtype, header_bytes

    def array(self, name, mapped: bool = False) -> np.ndarray:
        """The member's array: read (stored members checked against the CRC), or
        with `mapped` a large stored member mapped read-only from the file."""
        info = self.members[name]
        if info.compress_type == zipfile.ZIP_STORED and mapped and info.file_size >= self.MAP_BYTES:
            return self._map_stored(name, info)
        if info.compress_type == zipfile.ZIP_STORED and info.file_size >= self.DIRECT_BYTES:
            return self._read_stored(name, info)
        try:
            with self._open_member(name) as f:
                return np.lib.format.read_array(f, allow_pickle=False)
        except ExabricksError:
            raise
        except MemoryError:
            raise
        except Exception as e:  # truncated member, CRC error, ...
            raise self._fail(name, f"cannot be read ({e})") from None

    def _data_offset(self, info) -> int:
        """Where a stored member's bytes (its .npy header first) start in the file."""
        local = self._pread(30, info.header_offset)
        if len(local) != 30 or local[:4] != b"PK\x03\x04":
            raise ValueError("bad local file header")
        name_len = int.from_bytes(local[26:28], "little")
        extra_len = int.from_bytes(local[28:30], "little")
        return info.header_offset + 30 + name_len + extra_len

    def _map_stored(self, name, info) -> np.ndarray:
        """A stored member's array mapped read-only (no CRC: its pages are not read)."""
        shape, dtype = self.header(name)
        skip = self._headers[name][2]
        try:
            offset = self._data_offset(info) + skip
            if offset + info.file_size - skip > os.fstat(self.file.fileno()).st_size:
                raise ValueError("truncated")
            return np.memmap(self.file, dtype=dtype, mode="r", offset=offset, shape=shape)
        except OSError as e:
            raise self._fail(name, f"cannot be read ({e.strerror or e})") from None
        except ValueError as e:
            raise self._fail(name, f"cannot be read ({e})") from None

    def check_crc(self, name, array: np.ndarray) -> None:
        """Check a mapped member against the archive's CRC, in `rows` steps (a
        member read whole is checked as it is read)."""
        import zlib

        info = self.members[name]
        if mapping(array) is None:
            return
        try:
            crc = zlib.crc32(self._pread(self._headers[name][2], self._data_offset(info)))
        except (OSError, ValueError) as e:
            raise self._fail(name, f"cannot be read ({e})") from None
        for _, (part,) in rows(array.reshape(-1)):
            crc = zlib.crc32(part, crc)
        if crc != info.CRC:
            raise self._fail(name, "cannot be read (bad CRC: the file is damaged)")

    def _read_stored(self, name, info) -> np.ndarray:
        """A stored member's array, read with one readinto and checked against the
        archive's CRC (zlib.crc32 runs at several GB/s)."""
        import zlib

        shape, dtype = self.header(name)
        skip = self._headers[name][2]
        out = np.empty(shape, dtype)
        view = memoryview(out.reshape(-1).view(np.uint8))
        try:
            start = self._data_offset(info)
            head = self._pread(skip, start)
            done = 0
            while done < len(view):
                n = os.preadv(self.file.fileno(), [view[done:]], start + skip + done)
                if n <= 0:
                    break
                done += n
            if done != len(view) or len(head) != skip:
                raise ValueError("truncated")
        except OSError as e:
            raise self._fail(name, f"cannot be read ({e.strerror or e})") from None
        except ValueError as e:
            raise self._fail(name, f"cannot be read ({e})") from None
        if zlib.crc32(view, zlib.crc32(head)) != info.CRC:
            raise self._fail(name, "cannot be read (bad CRC: the file is damaged)")
        return out

    def __getitem__(self, name) -> np.ndarray:
        return self.array(name)


def read_header(z: NpzArchive, where: str) -> tuple[str, int, dict]:
    for key in HEADER_KEYS:
        if key not in z.files:
            raise ExabricksError(f"{where}: not an exabricks file (no {key!r} entry)")
        shape, dtype = z.header(key)
        if shape != () or dtype.itemsize > MAX_HEADER_BYTES or dtype.kind not in "Uiu":
            raise ExabricksError(f"{where}: not an exabricks file (its {key!r} entry is a "
                                 f"{dtype} array of shape {shape})")
    try:
        fmt = str(z["format"])
        kind = str(z["kind"])
        version = int(z["version"])
        meta = json.loads(str(z["meta"]))
    except ExabricksError:
        raise
    except RecursionError:
        raise ExabricksError(f"{where}: unreadable header (meta is nested too deeply)") from None
    except Exception as e:
        raise ExabricksError(f"{where}: unreadable header ({e})") from e
    if fmt != FORMAT:
        raise ExabricksError(f"{where}: format is {fmt!r}, expected {FORMAT!r}")
    if kind not in KINDS:
        raise ExabricksError(
            f"{where}: unknown kind {kind!r} (known: {', '.join(KINDS)})"
        )
    if not isinstance(meta, dict):
        raise ExabricksError(f"{where}: meta is not a JSON object")
    return kind, version, meta
