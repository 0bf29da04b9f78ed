"""The text of an AMReX plotfile (exabricks.readers.amrex reads its values): the
`Header` (field names, dimension, time, levels, prob_lo/prob_hi, refinement
ratios, domain boxes, cell sizes, one multifab path per level), each level's
VisMF header `Cell_H` (BoxArray, one `FabOnDisk: FILE OFFSET` per box), and the
real descriptor of the FABs (`decode_real_descriptor`), each checked with one
error naming the file and line."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..util.constants import MAX_LEVEL
from ..util.errors import ExabricksError
from ..util.jsonfile import not_regular
from . import _checks

_INT = r"-?\d+"


_IV = rf"\(\s*({_INT}(?:\s*,\s*{_INT})*)\s*\)"


_BOX_RE = re.compile(rf"\(\s*{_IV}\s*{_IV}\s*{_IV}\s*\)")


_RD = r"\(\s*\(\s*(\d+)\s*,\s*\(([\d\s]+)\)\s*\)\s*,\s*\(\s*(\d+)\s*,\s*\(([\d\s]+)\)\s*\)\s*\)"


_RD_RE = re.compile(_RD)


FAB_LINE = re.compile(rf"FAB\s*{_RD}\s*{_BOX_RE.pattern}\s*(\d+)\s*$")


# The IEEE formats AMReX writes (FPC::Ieee{64,32}NormalRealDescriptor / native ones).
_IEEE = {
    (64, 11, 52, 0, 1, 12, 0, 1023): 8,
    (32, 8, 23, 0, 1, 9, 0, 127): 4,
}


_VISMF_VERSIONS = (1, 2, 3, 4)  # Version_v1 … NoFabHeaderFAMinMax_v1


class _Lines:
    """Line cursor over a text file that names the file and line in its errors."""

    def __init__(self, where: Path, text: str):
        self.where = where
        self.lines = text.splitlines()
        self.i = 0

    def next(self, what: str) -> str:
        if self.i >= len(self.lines):
            raise ExabricksError(f"{self.where}: ends early (truncated?) before the {what}")
        self.i += 1
        return self.lines[self.i - 1].strip()

    def fail(self, what: str) -> ExabricksError:
        return ExabricksError(f"{self.where}: line {self.i}: cannot read the {what}")

    def ints(self, what: str, count: int | None = None) -> list[int]:
        try:
            out = [int(t) for t in self.next(what).split()]
        except ValueError:
            raise self.fail(what) from None
        if count is not None and len(out) != count:
            raise self.fail(f"{what} (expected {count} numbers, found {len(out)})")
        return out

    def floats(self, what: str, count: int) -> np.ndarray:
        try:
            out = np.array([float(t) for t in self.next(what).split()], dtype=np.float64)
        except ValueError:
            raise self.fail(what) from None
        if out.shape[0] != count:
            raise self.fail(f"{what} (expected {count} numbers, found {out.shape[0]})")
        return out


def _read_text(where: Path, what: str) -> str:
    why = not_regular(where)
    if why == "no such file":
        raise ExabricksError(f"{where}: missing ({what}; the plotfile is incomplete)")
    if why is not None:
        raise ExabricksError(f"{where}: cannot read the {what}: {why}, not a regular file")
    try:
        return where.read_text(encoding="ascii", errors="strict")
    except FileNotFoundError:
        raise ExabricksError(f"{where}: missing ({what}; the plotfile is incomplete)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ExabricksError(f"{where}: cannot read the {what} ({e})") from e


def _parse_boxes(text: str, where: Path, count: int) -> tuple[np.ndarray, np.ndarray]:
    """lo, hi int64 (count, 3) of `count` cell-centred 3D boxes written as ((lo) (hi) (type))."""
    found = _BOX_RE.findall(text)
    if len(found) != count:
        raise ExabricksError(f"{where}: expected {count} boxes, found {len(found)}")
    if not found:
        return np.empty((0, 3), np.int64), np.empty((0, 3), np.int64)
    try:
        nums = np.array([[int(t) for t in ",".join(b).split(",")] for b in found], dtype=np.int64)
    except OverflowError:
        raise ExabricksError(f"{where}: a box index does not fit in 64 bits") from None
    except ValueError:
        raise ExabricksError(f"{where}: a box is not three-dimensional") from None
    if nums.ndim != 2 or nums.shape[1] != 9:
        raise ExabricksError(f"{where}: a box is not three-dimensional")
    if np.any(nums[:, 6:] != 0):
        raise ExabricksError(f"{where}: node- or face-centred boxes; only cell data is supported")
    lo, hi = nums[:, 0:3], nums[:, 3:6]
    if np.any(hi < lo):
        raise ExabricksError(f"{where}: a box has hi < lo")
    return lo, hi


def _parse_ratios(c: _Lines, finest: int) -> list[int]:
    """The refinement ratios of levels 0..finest-1 from the Header's ratio line.

    AMReX writes one ratio per coarse level (`finest` numbers); embedded-boundary and
    PeleLMeX-family writers add one for the finest level too (`finest + 1`), which is
    ignored, as yt does (it only ever uses ref_factors[L] for L < finest).  Older
    writers give per-axis IntVects "(2,2,2) (2,2,2)" (isotropic ones are accepted).
    """
    ratio_line = c.next("refinement ratios")
    r = [int(t) for t in re.findall(_INT, ratio_line)]
    if "(" in ratio_line:  # per-axis IntVects (older writers)
        if len(r) % 3 or len(r) // 3 not in (finest, finest + 1):
            raise c.fail(f"refinement ratios (expected {finest} or {finest + 1} IntVects, "
                         f"found {len(r)} numbers)")
        r3 = np.array(r, dtype=np.int64).reshape(-1, 3)[:finest]
        if np.any(r3 != r3[:, :1]):
            raise ExabricksError(
                f"{c.where}: anisotropic refinement ratios {r3.tolist()} are not supported"
            )
        r = r3[:, 0].tolist()
    if len(r) not in (finest, finest + 1):
        raise c.fail(f"refinement ratios (expected {finest}, or {finest + 1} with the finest "
                     f"level's, found {len(r)})")
    r = r[:finest]
    for x in r:
        if x < 2 or x & (x - 1):
            raise ExabricksError(
                f"{c.where}: refinement ratio {x} is not a power of two (exabricks needs 2, 4, 8, ...)"
            )
    return r


def read_header(path: Path) -> dict:
    """The plotfile's Header, checked: fields, finest_level, ratios, domains, prob_lo,
    spacing, level_paths [(multifab path, box count)] and more (no level data read)."""
    if not path.is_dir():
        kind = "no such file or directory" if not path.exists() else "a file, not a directory"
        raise ExabricksError(f"{path}: not an AMReX plotfile directory ({kind})")
    where = path / "Header"
    if not where.is_file():
        raise ExabricksError(f"{path}: not an AMReX plotfile (no Header file)")
    c = _Lines(where, _read_text(where, "plotfile Header"))
    version = c.next("version line")
    ncomp = c.ints("number of fields", 1)[0]
    if ncomp < 1:
        raise c.fail("number of fields (must be positive)")
    names = [c.next("field names") for _ in range(ncomp)]
    if len(set(names)) != len(names):
        raise ExabricksError(f"{where}: duplicate field names {names}")
    dim = c.ints("dimension", 1)[0]
    if dim != 3:
        raise ExabricksError(f"{where}: a {dim}D plotfile; exabricks reads 3D data only")
    try:
        time = float(c.next("time"))
    except ValueError:
        raise c.fail("time") from None
    finest = c.ints("finest level", 1)[0]
    if not 0 <= finest <= MAX_LEVEL:
        raise c.fail(f"finest level (must lie in 0..{MAX_LEVEL})")
    prob_lo = c.floats("prob_lo", 3)
    prob_hi = c.floats("prob_hi", 3)
    if not (np.all(np.isfinite(prob_lo)) and np.all(np.isfinite(prob_hi))):
        raise ExabricksError(
            f"{where}: prob_lo and prob_hi must be finite (found {prob_lo.tolist()} and "
            f"{prob_hi.tolist()})"
        )
    if not np.all(prob_hi > prob_lo):
        raise ExabricksError(
            f"{where}: prob_hi must exceed prob_lo (found {prob_lo.tolist()} and "
            f"{prob_hi.tolist()})"
        )
    r = _parse_ratios(c, finest)
    dom_lo, dom_hi = _parse_boxes(c.next("domain boxes"), where, finest + 1)
    for L in range(finest):
        want = (dom_hi[L] - dom_lo[L] + 1) * r[L]
        if np.any(dom_hi[L + 1] - dom_lo[L + 1] + 1 != want) or \
                np.any(dom_lo[L + 1] != dom_lo[L] * r[L]):
            raise ExabricksError(
                f"{where}: the level-{L + 1} domain is not the level-{L} domain refined by {r[L]}"
            )
    c.next("level steps")
    for L in range(finest + 1):
        _checks.check_cell_size(f"{where}: line {c.i + 1}", c.floats("cell sizes", 3),
                                f"level-{L} cell size")
    coord = c.ints("coordinate system", 1)[0]
    if coord != 0:
        raise ExabricksError(
            f"{where}: coordinate system {coord} (1 = RZ, 2 = spherical); only Cartesian (0) "
            f"is supported"
        )
    c.next("boundary width")
    level_paths = []
    for L in range(finest + 1):
        head = c.next(f"level-{L} line (level, boxes, time)").split()
        try:
            lvl, nbox = int(head[0]), int(head[1])
        except (ValueError, IndexError):
            raise c.fail(f"level-{L} line (level, boxes, time)") from None
        if nbox < 0:
            raise c.fail(f"level-{L} line (negative box count)")
        if lvl != L:
            raise c.fail(f"level-{L} line (found level {lvl})")
        c.next(f"level-{L} steps")
        for _ in range(3 * nbox):
            c.next(f"level-{L} box extents")
        level_paths.append((c.next(f"level-{L} multifab path"), nbox))
    ratios = np.array(r, dtype=np.int64)
    if math.prod(r) * int((dom_hi[0] - dom_lo[0] + 1).max()) >= 2**31:  # exact ints
        raise ExabricksError(f"{where}: the finest domain exceeds the int32 lattice")
    cells = (dom_hi[finest] - dom_lo[finest] + 1).astype(np.float64)
    with np.errstate(all="ignore"):
        spacing = (prob_hi - prob_lo) / cells
    _checks.check_frame(where, prob_lo, spacing, cells)
    return {
        "version": version, "fields": names, "ncomp": ncomp, "time": time,
        "finest_level": finest, "prob_lo": prob_lo, "prob_hi": prob_hi, "ratios": ratios,
        "spacing": spacing,
        "domains": [(dom_lo[L], dom_hi[L]) for L in range(finest + 1)],
        "level_paths": level_paths,
    }


def decode_real_descriptor(groups: Sequence[str], where: str) -> np.dtype:
    """dtype of a real descriptor ((n, (format)), (nbytes, (order))); only IEEE 32/64 bits."""
    fmt = tuple(int(t) for t in groups[1].split())
    order = [int(t) for t in groups[3].split()]
    nbytes = _IEEE.get(fmt)
    if nbytes is None or int(groups[0]) != len(fmt):
        raise ExabricksError(f"{where}: unsupported real format {fmt} (only IEEE 32- and 64-bit)")
    if int(groups[2]) != len(order) or len(order) != nbytes:
        raise ExabricksError(f"{where}: byte order {order} does not fit a {nbytes}-byte real")
    if order == list(range(1, nbytes + 1)):
        return np.dtype(f">f{nbytes}")
    if order == list(range(nbytes, 0, -1)):
        return np.dtype(f"<f{nbytes}")
    raise ExabricksError(f"{where}: byte order {order} is neither big- nor little-endian")


def read_level_header(path: Path, level_path: tuple[str, int], L: int, ncomp: int) -> dict:
    prefix, nbox = level_path
    where = path / (prefix + "_H")
    c = _Lines(where, _read_text(where, f"level-{L} multifab header"))
    vers = c.ints("VisMF version", 1)[0]
    if vers not in _VISMF_VERSIONS:
        raise ExabricksError(f"{where}: unknown VisMF header version {vers}")
    c.ints("write mode", 1)
    nc = c.ints("number of components", 1)[0]
    if nc != ncomp:
        raise ExabricksError(f"{where}: {nc} components, but the Header lists {ncomp} fields")
    ngrow = c.next("number of ghost cells")
    try:  # one number, or an IntVect "(1,1,1)" from writers with per-axis ghost cells
        ngrow = np.broadcast_to(np.array(re.findall(_INT, ngrow), dtype=np.int64), (3,)).copy()
    except (ValueError, OverflowError):
        raise c.fail("number of ghost cells") from None
    if np.any(ngrow < 0):
        raise c.fail("number of ghost cells")
    first = c.next("BoxArray")
    m = re.match(r"\(\s*(\d+)\s+\d+", first)
    if not m:
        raise c.fail("BoxArray")
    count = int(m.group(1))
    if count != nbox:
        raise ExabricksError(f"{where}: {count} boxes, but the Header lists {nbox} for level {L}")
    lo, hi = _parse_boxes("\n".join(c.next("BoxArray boxes") for _ in range(count)), where, count)
    if c.next("end of the BoxArray") != ")":
        raise c.fail("end of the BoxArray")
    nfod = c.ints("number of FABs", 1)[0]
    if nfod != count:
        raise ExabricksError(f"{where}: {nfod} FabOnDisk entries for {count} boxes")
    files, offsets = [], np.empty(count, dtype=np.int64)
    directory = where.parent
    for b in range(count):
        parts = c.next("FabOnDisk entries").split()
        if len(parts) != 3 or parts[0] != "FabOnDisk:":
            raise c.fail("FabOnDisk entry")
        try:
            offsets[b] = int(parts[2])
        except (ValueError, OverflowError):
            raise c.fail("FabOnDisk offset") from None
        files.append(directory / parts[1])
    dtype = None
    if vers != 1:  # the FABs carry no header line; the real descriptor ends Cell_H
        m = None
        for line in c.lines[c.i:][::-1]:
            m = _RD_RE.search(line)
            if m:
                break
        if m is None:
            raise ExabricksError(f"{where}: no real descriptor (VisMF version {vers}); truncated?")
        dtype = decode_real_descriptor(m.groups(), str(where))
    return {"where": where, "lo": lo, "hi": hi, "files": files, "offsets": offsets,
            "ngrow": ngrow, "version": vers, "dtype": dtype}
