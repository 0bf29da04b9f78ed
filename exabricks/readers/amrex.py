"""Native reader of AMReX (BoxLib) plotfiles: `Header`, `Level_N/Cell_H`, `Cell_D_*`.

The plotfile directory holds a text `Header` (field names, dimension, time, levels,
prob_lo/prob_hi, refinement ratios, domain boxes, cell sizes, one multifab path per
level), and per level a VisMF header `Cell_H` (BoxArray, one `FabOnDisk: FILE OFFSET`
per box, min/max) whose FABs lie in binary `Cell_D_*` files.  A FAB is a text line
``FAB ((8, (64 11 52 0 1 12 0 1023)),(8, (8 7 6 5 4 3 2 1)))((lo) (hi) (type)) ncomp``
followed by its data, component after component, each in Fortran order (x fastest).
Headers of VisMF versions 2-4 drop that line and give the real descriptor once, at
the end of `Cell_H`.

The real descriptor is ``((n, (bits exp_bits mant_bits sign_bit exp_start mant_start
? bias)), (nbytes, (byte order)))``; the byte order lists, for each byte in memory,
its significance (1 = most significant), so ``1 2 … n`` is big-endian and
``n … 2 1`` little-endian.

Lattice: exabricks level 0 is AMReX's finest level; a cell of AMReX level L is as
wide as the product of the refinement ratios from L to the finest (all powers of
two), and lattice 0 is the corner of the domain, world `prob_lo`.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError
from ..util.jsonfile import not_regular
from . import _blocks, _checks

_INT = r"-?\d+"
_IV = rf"\(\s*({_INT}(?:\s*,\s*{_INT})*)\s*\)"
_BOX_RE = re.compile(rf"\(\s*{_IV}\s*{_IV}\s*{_IV}\s*\)")
_RD = r"\(\s*\(\s*(\d+)\s*,\s*\(([\d\s]+)\)\s*\)\s*,\s*\(\s*(\d+)\s*,\s*\(([\d\s]+)\)\s*\)\s*\)"
_RD_RE = re.compile(_RD)
_FAB_RE = re.compile(rf"FAB\s*{_RD}\s*{_BOX_RE.pattern}\s*(\d+)\s*$")

# The IEEE formats AMReX writes (FPC::Ieee{64,32}NormalRealDescriptor / native ones).
_IEEE = {
    (64, 11, 52, 0, 1, 12, 0, 1023): 8,
    (32, 8, 23, 0, 1, 9, 0, 127): 4,
}
_VISMF_VERSIONS = (1, 2, 3, 4)  # Version_v1 … NoFabHeaderFAMinMax_v1


def read(path: Path, *, fields: Sequence[str] | None = None,
         level_cap: int | None = None) -> schema.Cells:
    """Leaf cells of an AMReX plotfile directory, fields as float32.

    level_cap: read AMReX levels 0..level_cap only (None: all).  Every cell of level
        `level_cap` is then a leaf, covered or not: where finer levels cover it, its
        value is the covered data the plotfile stores (averaged down from the finer
        levels by the simulation).  The lattice and the levels stay those of the whole
        hierarchy, so the cells line up with a full read.

    Returns Cells with lower_lattice int32 (N, 3) in finest-cell units, level int8
    (N,) (0 = AMReX's finest level), values float32 (F, N) in the file's units,
    origin_world = prob_lo, spacing_world = the finest cell size per axis.
    """
    path = Path(path)
    header = read_header(path)
    names = header["fields"]
    if fields is None:
        selected = list(range(len(names)))
    else:
        missing = [f for f in fields if f not in names]
        if missing:
            raise ExabricksError(
                f"{path}: no field {missing[0]!r} in the plotfile (fields: {', '.join(names)})"
            )
        if len(set(fields)) != len(fields):
            raise ExabricksError(f"{path}: field listed twice in {list(fields)}")
        selected = [names.index(f) for f in fields]
    widths, lattice_level = lattice_widths(header), lattice_levels(header)
    finest = header["finest_level"]
    if level_cap is not None:
        if level_cap < 0:
            raise ExabricksError(f"{path}: the level cap must be >= 0, got {level_cap}")
        finest = min(finest, level_cap)
    domains = header["domains"]

    levels = [_read_level_header(path, header["level_paths"][L], L, len(names))
              for L in range(finest + 1)]
    for L, lev in enumerate(levels):
        lo, hi = lev["lo"], lev["hi"]
        dlo, dhi = domains[L]
        if lo.shape[0] and (np.any(lo < dlo) or np.any(hi > dhi)):
            b = int(np.flatnonzero(np.any((lo < dlo) | (hi > dhi), axis=1))[0])
            raise ExabricksError(
                f"{lev['where']}: box {b} {lo[b].tolist()}..{hi[b].tolist()} lies outside "
                f"the level-{L} domain {dlo.tolist()}..{dhi.tolist()}"
            )
    # Every FAB's claimed size against its Cell_D file, before anything of the size the
    # headers claim is allocated: the cells read below are then bounded by the bytes on disk.
    for lev in levels:
        lev["layout"] = _fab_layouts(lev, header["ncomp"])
    masks = []
    for L, lev in enumerate(levels):
        lo, hi = lev["lo"], lev["hi"]
        # A cell is a leaf unless any finer level covers it (with proper nesting the next
        # level alone would do; all finer levels guarantee that leaves never overlap).
        cover = [_blocks.coarsen(levels[F]["lo"], levels[F]["hi"], widths[L] // widths[F])
                 for F in range(L + 1, finest + 1)]
        cover_lo = np.concatenate([c[0] for c in cover]) if cover else np.empty((0, 3), np.int64)
        cover_hi = np.concatenate([c[1] for c in cover]) if cover else np.empty((0, 3), np.int64)
        masks.append(_blocks.leaf_mask(lo, hi, cover_lo, cover_hi))
    # The outputs are allocated once and every level writes its leaves into its slice
    # (no per-level arrays to concatenate: at 2e7 cells each copy costs ~0.1 s).
    counts = [int(np.count_nonzero(m)) for m in masks]
    first = np.concatenate([[0], np.cumsum(counts)]).tolist()
    lattice = np.empty((first[-1], 3), dtype=LATTICE_DTYPE)
    level = np.empty(first[-1], dtype=LEVEL_DTYPE)
    values = np.empty((len(selected), first[-1]), dtype=VALUE_DTYPE)
    for L, lev in enumerate(levels):
        part = slice(first[L], first[L + 1])
        _read_level_values(lev, selected, header["ncomp"], masks[L], values[:, part])
        _blocks.leaf_lattice(lev["lo"], lev["hi"], masks[L], domains[L][0], widths[L],
                             out=lattice[part])
        level[part] = lattice_level[L]

    spacing = header["spacing"]
    return schema.Cells(
        fields=tuple(names[i] for i in selected),
        origin_world=header["prob_lo"].astype(WORLD_DTYPE),
        spacing_world=spacing.astype(WORLD_DTYPE),
        meta={"source": {"format": "amrex", "code": header["version"], "time": header["time"],
                         "levels": header["finest_level"] + 1,
                         **({} if finest == header["finest_level"]
                            else {"levels_read": finest + 1})},
              # The files read (a capped read leaves the finer levels' files alone).
              "inputs": [str(path / "Header"), *(
                  str(f) for L in range(finest + 1)
                  for f in sorted((path / header["level_paths"][L][0]).parent.glob("*"))
                  if f.is_file())]},
        lower_lattice=lattice,
        level=level,
        values=values,
    )


def lattice_widths(header: dict) -> list[int]:
    """Width of a cell of each AMReX level in finest-cell units (the product of the
    refinement ratios below it, a power of two)."""
    ratios = header["ratios"]
    return [int(np.prod(ratios[L:], dtype=np.int64)) for L in range(header["finest_level"] + 1)]


def lattice_levels(header: dict) -> list[int]:
    """The exabricks level of each AMReX level: log2 of its `lattice_widths`."""
    return [w.bit_length() - 1 for w in lattice_widths(header)]


def field_names(path: Path) -> list[str]:
    """The field names listed in the plotfile's Header (nothing else is read)."""
    return read_header(Path(path))["fields"]


# ---------------------------------------------------------------------------
# Header


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


# ---------------------------------------------------------------------------
# Level_N/Cell_H


def _decode_rd(groups: Sequence[str], where: str) -> np.dtype:
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


def _read_level_header(path: Path, level_path: tuple[str, int], L: int, ncomp: int) -> dict:
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
        dtype = _decode_rd(m.groups(), str(where))
    return {"where": where, "lo": lo, "hi": hi, "files": files, "offsets": offsets,
            "ngrow": ngrow, "version": vers, "dtype": dtype}


# ---------------------------------------------------------------------------
# Cell_D


def _read_level_values(lev: dict, selected: list[int], ncomp: int, mask: np.ndarray,
                       out: np.ndarray) -> None:
    """`_copy_level_values` where float64 values beyond float32's range become inf (a
    non-finite value that the --nan policy handles later) without a RuntimeWarning."""
    with np.errstate(over="ignore", invalid="ignore"):
        _copy_level_values(lev, selected, ncomp, mask, out)


def _copy_level_values(lev: dict, selected: list[int], ncomp: int, mask: np.ndarray,
                       out: np.ndarray) -> None:
    """Write the leaf values of a level into out, float32 (len(selected), leaves).

    mask: bool (cells of all boxes,), box after box, x fastest (`_blocks.leaf_mask`);
    the leaves go to `out` in that order.  FABs are read in file and offset order
    (sequential I/O); per FAB, only the span from the first to the last selected
    component is read, into one reused buffer, and converted to float32 while it is
    copied into place (whole when every cell is a leaf, else through the mask).
    """
    los, his = lev["lo"].tolist(), lev["hi"].tolist()
    start = np.zeros(len(los) + 1, dtype=np.int64)
    np.cumsum(_blocks.box_volumes(lev["lo"], lev["hi"]), out=start[1:])
    leaf_start = np.zeros(len(los) + 1, dtype=np.int64)
    if len(los):
        np.cumsum(np.add.reduceat(mask, start[:-1], dtype=np.int64), out=leaf_start[1:])
    start, leaf_start = start.tolist(), leaf_start.tolist()
    c0, c1 = min(selected, default=0), max(selected, default=0) + 1
    rows = [s - c0 for s in selected]
    files, offsets = lev["files"], lev["offsets"].tolist()
    layout = lev["layout"]
    order = sorted(range(len(files)), key=lambda b: (str(files[b]), offsets[b]))
    f, name, size = None, None, 0
    buf = np.empty(0, dtype=np.uint8)
    try:
        for b in order:
            if files[b] != name:
                if f is not None:
                    f.close()
                name = files[b]
                try:
                    f = open(name, "rb")
                except FileNotFoundError:
                    raise ExabricksError(f"{name}: missing (FAB data of {lev['where']})") from None
                except OSError as e:
                    raise ExabricksError(f"{name}: cannot open ({e})") from e
                size = os.fstat(f.fileno()).st_size
            fab_lo, fab_hi, dtype, data_at = layout[b]
            shape = tuple(fab_hi[a] - fab_lo[a] + 1 for a in (2, 1, 0))  # (nz, ny, nx)
            nbytes = shape[0] * shape[1] * shape[2] * dtype.itemsize
            end = data_at + ncomp * nbytes
            if end > size:  # checked by _fab_layouts: the file shrank since
                raise ExabricksError(
                    f"{name}: truncated: FAB {b} of {lev['where']} needs bytes up to {end}, "
                    f"the file has {size}"
                )
            want = (c1 - c0) * nbytes
            if buf.shape[0] < want:
                buf = np.empty(want, dtype=np.uint8)
            f.seek(data_at + c0 * nbytes)
            if f.readinto(memoryview(buf)[:want]) != want:
                raise ExabricksError(f"{name}: truncated while reading FAB {b}")
            data = buf[:want].view(dtype).reshape(c1 - c0, *shape)
            lo, hi = los[b], his[b]
            if fab_lo != lo or fab_hi != hi:  # ghost cells around the box: keep the box
                data = data[:, lo[2] - fab_lo[2]:hi[2] - fab_lo[2] + 1,
                            lo[1] - fab_lo[1]:hi[1] - fab_lo[1] + 1,
                            lo[0] - fab_lo[0]:hi[0] - fab_lo[0] + 1]
            dst = out[:, leaf_start[b]:leaf_start[b + 1]]
            if leaf_start[b + 1] - leaf_start[b] == start[b + 1] - start[b]:  # all leaves
                for i, r in enumerate(rows):  # converts to float32 while copying
                    dst[i].reshape(data.shape[1:])[...] = data[r]
            elif leaf_start[b + 1] > leaf_start[b]:
                keep = mask[start[b]:start[b + 1]].reshape(data.shape[1:])
                for i, r in enumerate(rows):
                    dst[i] = data[r][keep]
    finally:
        if f is not None:
            f.close()


def _fab_layouts(lev: dict, ncomp: int) -> list[tuple[list[int], list[int], np.dtype, int]]:
    """(FAB lo, FAB hi as int lists, dtype, byte offset of the data) of every box of a level.

    Checks, before anything is allocated: each FabOnDisk offset lies in its Cell_D file,
    each FAB (header line and all components, ghost cells included) fits in the file
    from there, and no two FABs of the level share bytes, so the level's cells are
    bounded by the bytes on disk.  Sizes are Python ints (a claimed 2**30-cell box
    does not overflow).
    """
    files, offsets = lev["files"], lev["offsets"].tolist()
    out: list = [None] * len(files)
    rd_cache: dict = {}
    by_file: dict = {}
    for b, name in enumerate(files):
        by_file.setdefault(name, []).append(b)
    for name, boxes in by_file.items():
        try:
            size = os.stat(name).st_size
        except FileNotFoundError:
            raise ExabricksError(f"{name}: missing (FAB data of {lev['where']})") from None
        except OSError as e:
            raise ExabricksError(f"{name}: cannot open ({e})") from e
        boxes.sort(key=lambda b: offsets[b])
        f = None
        try:
            prev_end, prev = 0, None
            for b in boxes:
                lo, hi = lev["lo"][b].tolist(), lev["hi"][b].tolist()
                what = f"box {b} {tuple(lo)}..{tuple(hi)}"
                offset = offsets[b]
                if not 0 <= offset < size:
                    raise ExabricksError(
                        f"{lev['where']}: {what} starts at byte {offset} but {name} holds "
                        f"only {size} (truncated?)"
                    )
                if lev["version"] == 1:
                    if f is None:
                        try:
                            f = open(name, "rb")
                        except OSError as e:
                            raise ExabricksError(f"{name}: cannot open ({e})") from e
                    layout = _fab_header(f, name, lev, b, offset, ncomp, rd_cache)
                else:
                    g = lev["ngrow"].tolist()
                    layout = ([lo[a] - g[a] for a in range(3)], [hi[a] + g[a] for a in range(3)],
                              lev["dtype"], offset)
                fab_lo, fab_hi, dtype, data_at = layout
                end = data_at + ncomp * dtype.itemsize * _volume(fab_lo, fab_hi)
                _checks.claim(lev["where"], what, end - offset, name, size, at=offset)
                if offset < prev_end:
                    raise ExabricksError(
                        f"{lev['where']}: box {b} starts at byte {offset} of {name}, inside the "
                        f"data of box {prev} (bytes up to {prev_end}): corrupt FabOnDisk offsets"
                    )
                prev_end, prev = end, b
                out[b] = layout
        finally:
            if f is not None:
                f.close()
    return out


def _volume(lo: Sequence[int], hi: Sequence[int]) -> int:
    return (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1)


def _fab_header(f, name: Path, lev: dict, b: int, offset: int, ncomp: int, rd_cache: dict):
    """(FAB lo, FAB hi, dtype, data offset) from the header line of FAB `b` (VisMF v1)."""
    lo, hi = lev["lo"][b].tolist(), lev["hi"][b].tolist()
    f.seek(offset)
    line = f.readline(1024)
    m = _FAB_RE.match(line.decode("ascii", errors="replace"))
    if not m or not line.endswith(b"\n"):
        raise ExabricksError(
            f"{name}: byte {offset}: no FAB header line for box {b} of {lev['where']} "
            f"(corrupt file or wrong offset)"
        )
    groups = m.groups()
    if groups[:4] not in rd_cache:
        rd_cache[groups[:4]] = _decode_rd(groups[:4], f"{name}: byte {offset}")
    try:
        fab_lo = [int(t) for t in groups[4].split(",")]
        fab_hi = [int(t) for t in groups[5].split(",")]
    except ValueError:
        raise ExabricksError(f"{name}: byte {offset}: bad FAB box") from None
    if len(fab_lo) != 3 or len(fab_hi) != 3 or any(
            fab_lo[a] > lo[a] or fab_hi[a] < hi[a] for a in range(3)):
        raise ExabricksError(
            f"{name}: byte {offset}: FAB box {fab_lo}..{fab_hi} does not contain "
            f"box {b} {lo}..{hi} of {lev['where']}"
        )
    if int(groups[7]) != ncomp:
        raise ExabricksError(
            f"{name}: byte {offset}: FAB has {groups[7]} components, expected {ncomp}"
        )
    return fab_lo, fab_hi, rd_cache[groups[:4]], offset + len(line)
