"""Native reader of RAMSES outputs (``output_NNNNN/``): the octree and the hydro fields.

An output folder holds ``info_NNNNN.txt`` (ncpu, levelmin, levelmax, boxlen, time,
units, the ordering), ``hydro_file_descriptor.txt`` (version 1: the hydro variables'
names and types) and, per cpu K = 1..ncpu, ``amr_NNNNN.outK`` and ``hydro_NNNNN.outK``:
Fortran unformatted sequential records (an int32 length before and after each).

amr file: a header (ncpu, ndim, nx ny nz, nlevelmax, ..., numbl(ncpu, nlevelmax): the
octs of each level listed under each cpu, ..., the ordering, its keys, the coarse
cells), then for each level 1..nlevelmax and each cpu (then each boundary) with octs
37 records of those octs: ind_grid, next, prev, xg(x, y, z) (centres, box units),
father, nbor(1..6), son(1..8), cpu_map(1..8), flag1(1..8); cell ind = 1 + x + 2y + 4z.
hydro file: ncpu, nvar, ndim, nlevelmax, nboundary, gamma; then for each level and cpu
(then boundary) the records ilevel, ncache and, where ncache > 0, for each cell ind and
each variable the ncache values.

File K owns the octs listed under cpu K; the octs listed under the other cpus are
virtual copies (ghosts, and the coarser ancestors).  As yt does, the leaves are the
cells (son index 0) of the owned octs of level >= levelmin; cells coarser than
levelmin are not shown.

Frame: the box [0, 1]^3 in code units (code_length = boxlen x unit_l), as yt reports
it: origin 0, spacing the width of the finest leaves present, 2**-L (L: their RAMSES
level); exabricks level = L - RAMSES level.  Field names are yt's ("density" ->
"Density", "velocity_x" -> "x-velocity", other names "hydro_<name>"), values in code
units cast to float32.

Everything is read with a loop per cpu file and per level at most: the byte offset of
each level's and cpu's records follows from numbl (every record's length is known), so
only the owned octs' records are read, checked by their length markers.

The ordering's keys (hilbert or bisection) are skipped: the octs are found from numbl,
not from the domains.  Boundary octs (nboundary > 0) are skipped, never owned.  Reals
of 4 or 8 bytes (the amr file's boxlen record) and hydro variables of descriptor types
d, f, i are read.  Not read: gravity, RT and particle files.  Refused with a message:
outputs split in group_NNNNN/ folders, coarse grids other than nx = ny = nz = 1, 2D/1D
runs, a missing or non-version-1 descriptor, a descriptor that lists other than nvar
variables, big-endian files and 8-byte record markers.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

import numba
import numpy as np

from .. import schema
from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError, quoted
from ..util.jsonfile import not_regular
from ..util import numba_compiles
from . import _checks

numba_compiles.announce()  # its first compile on a machine says so on a terminal

INFO_RE = re.compile(r"^info_(\d{5,})\.txt$")
OUTPUT_RE = re.compile(r"^output_(\d{5,})$")
DESCRIPTOR = "hydro_file_descriptor.txt"

# yt's names of RAMSES' descriptor names (yt.frontends.ramses.io._read_fluid_file_descriptor)
_YT_NAMES = {
    "density": "Density", "velocity_x": "x-velocity", "velocity_y": "y-velocity",
    "velocity_z": "z-velocity", "pressure": "Pressure", "metallicity": "Metallicity",
    "H_p1_fraction": "HII", "He_p1_fraction": "HeII", "He_p2_fraction": "HeIII",
    **{f"photon_density_{i:02d}": f"Photon_density_{i:d}" for i in range(100)},
    **{f"photon_flux_{i:02d}_{d}": f"Photon_flux_{d}_{i:d}" for i in range(100) for d in "xyz"},
    **{f"B_{d}_{s}": f"B_{d}_{s}" for s in ("left", "right") for d in "xyz"},
}
# yt's units of its on-disk RAMSES fields (code units)
_UNITS = {"Density": "code_density", "x-velocity": "code_velocity", "y-velocity": "code_velocity",
          "z-velocity": "code_velocity", "Pressure": "code_pressure"}
_TYPES = {"d": "f8", "f": "f4", "i": "i4"}

# cell ind - 1 -> its (x, y, z) offset in the oct: x fastest
_OFFSETS = np.array([[i & 1, (i >> 1) & 1, i >> 2] for i in range(8)], LATTICE_DTYPE)
# per oct group of the amr file: 37 records, 34 of int32 and 3 of reals (xg)
_INT_RECORDS, _REAL_RECORDS = 34, 3


def info_file(path: str | Path) -> Path:
    """The ``info_NNNNN.txt`` of the output `path` (that file, or the output folder
    holding exactly one); ExabricksError otherwise."""
    path = Path(path)
    if path.is_dir():
        infos = sorted(p for p in path.iterdir() if INFO_RE.match(p.name) and p.is_file())
        if len(infos) != 1:
            found = "no" if not infos else f"{len(infos)}"
            raise ExabricksError(f"{path}: {found} info_NNNNN.txt files in the folder; a RAMSES "
                                 f"output folder holds one")
        return infos[0]
    if not path.exists():
        raise ExabricksError(f"{path}: no such file or directory")
    if not INFO_RE.match(path.name):
        raise ExabricksError(f"{path}: not a RAMSES info_NNNNN.txt file: give the output "
                             f"folder or its info file")
    return path


def is_output(path: str | Path) -> bool:
    """Whether `path` looks like a RAMSES output (for format detection; reads no file):
    an ``output_NNNNN`` folder holding ``info_NNNNN.txt``, or an ``info_NNNNN.txt`` whose
    folder holds ``amr_NNNNN.out*`` files."""
    path = Path(path)
    try:
        if path.is_dir():
            m = OUTPUT_RE.match(path.name)
            return bool(m) and (path / f"info_{m.group(1)}.txt").is_file()
        m = INFO_RE.match(path.name)
        if not m or not path.is_file():
            return False
        return (path.parent / f"amr_{m.group(1)}.out00001").is_file() or any(
            e.name.startswith(f"amr_{m.group(1)}.out") for e in os.scandir(path.parent))
    except OSError:
        return False


def field_names(path: str | Path) -> list[str]:
    """The hydro fields' names (yt's) from hydro_file_descriptor.txt; no data is read."""
    info = info_file(path)
    return [name for name, _ in _descriptor(info.parent / DESCRIPTOR)]


def read(path: str | Path, *, fields: Sequence[str] | None = None) -> schema.Cells:
    """Leaf cells of the RAMSES output `path` (its folder or its info file), hydro
    variables as float32.

    Returns Cells with lower_lattice int32 (N, 3) in finest-cell units, level int8 (N,)
    (0 = the finest leaves), values float32 (F, N) in code units, origin_world 0 and
    spacing_world the finest leaf width, in code_length (the box is [0, 1]^3).
    Raises ExabricksError naming the file for bad input.
    """
    info_path = info_file(path)
    info = _info(info_path)
    folder, num = info_path.parent, INFO_RE.match(info_path.name).group(1)
    descriptor = _descriptor(folder / DESCRIPTOR)
    names = [n for n, _ in descriptor]
    if fields is None:
        fields = names
    fields = list(fields)
    for name in fields:
        if name not in names:
            raise ExabricksError(f"{info_path}: no field {quoted(name)} (fields: {', '.join(names)})")
    if len(set(fields)) != len(fields):
        raise ExabricksError(f"{info_path}: field listed twice in {fields}")
    ncpu, levelmin = info["ncpu"], info["levelmin"]

    groups = []  # (cpu, RAMSES level, oct indices (n, 3) int32, leaf mask (n, 8))
    layouts = {}
    for cpu in range(1, ncpu + 1):
        amr = folder / f"amr_{num}.out{cpu:05d}"
        _check_data_file(amr, ncpu, " (outputs split in group_NNNNN folders are not supported)"
                         if (folder / "group_00001").is_dir() else "")
        with open(amr, "rb") as f:
            header = _amr_header(f, amr, info)
            layouts[cpu] = header
            groups += _owned_octs(f, amr, header, cpu, levelmin)
    if not groups:
        raise ExabricksError(f"{info_path}: no octs of level >= levelmin = {levelmin} in any amr file")
    counts = [int(g[3].sum()) for g in groups]
    finest = max(g[1] for g, n in zip(groups, counts) if n)
    if finest > MAX_LEVEL:
        raise ExabricksError(f"{info_path}: leaves of level {finest}: more than {MAX_LEVEL} levels")
    covered = sum(n << 3 * (finest - g[1]) for g, n in zip(groups, counts))
    if covered != 1 << 3 * finest:
        raise ExabricksError(
            f"{info_path}: the leaves of the {ncpu} amr files cover {covered / (1 << 3 * finest):.6g} "
            f"of the box, not all of it once (files of another output, or damaged)")

    n = sum(counts)
    lattice = np.empty((n, 3), LATTICE_DTYPE)
    level = np.empty(n, LEVEL_DTYPE)
    at = 0
    for _, lv, q, mask in groups:
        at = _place_leaves(q, mask, finest - lv, _OFFSETS, lattice, level, at)

    wanted = [names.index(f) for f in fields]
    values = np.empty((len(fields), n), VALUE_DTYPE)
    at = 0
    by_cpu = {}
    for g, k in zip(groups, counts):
        by_cpu.setdefault(g[0], []).append((g, k))
    for cpu in range(1, ncpu + 1):
        hydro = folder / f"hydro_{num}.out{cpu:05d}"
        _check_data_file(hydro, ncpu)
        with open(hydro, "rb") as f:
            at = _read_hydro(f, hydro, layouts[cpu], descriptor, folder / DESCRIPTOR, cpu,
                             by_cpu.get(cpu, []), wanted, values, at)

    spacing = np.full(3, 2.0 ** -finest)
    _checks.check_frame(info_path, np.zeros(3), spacing, np.full(3, 1 << finest))
    return schema.Cells(
        fields=tuple(fields),
        origin_world=np.zeros(3, WORLD_DTYPE),
        spacing_world=spacing.astype(WORLD_DTYPE),
        meta={"source": {
            "format": "ramses", "code": "RAMSES", "time": info.get("time"),
            "time_unit": "code_time", "length_unit": "code_length",
            "aexp": info.get("aexp"), "levelmin": levelmin, "levelmax": info["levelmax"],
            "max_level": finest, "ncpu": ncpu,
            "units": {f: _UNITS[f] for f in fields if f in _UNITS},
            "code_units": {k: info.get(k) for k in ("boxlen", "unit_l", "unit_d", "unit_t")},
        }},
        lower_lattice=lattice,
        level=level,
        values=values,
    )


def _check_data_file(path: Path, ncpu: int, extra: str = "") -> None:
    """ExabricksError unless the amr or hydro file `path` is a regular file."""
    why = not_regular(path)
    if why == "no such file":
        raise ExabricksError(f"{path}: no such file: the output has ncpu = {ncpu}{extra}")
    if why is not None:
        raise ExabricksError(f"{path}: {why}, not a regular file")


@numba.njit(cache=True)
def _place_leaves(q, mask, shift, offsets, lattice, level, at):
    """The leaf cells (mask (n, 8)) of octs at lattice q (n, 3) of their level, into
    lattice[at:] and level[at:] (`shift` = the finest level minus theirs), by cell ind
    and then oct, as _read_hydro fills the values; returns the next free row."""
    for ind in range(8):
        for i in range(q.shape[0]):
            if mask[i, ind]:
                for a in range(3):
                    lattice[at, a] = (2 * q[i, a] + offsets[ind, a]) << shift
                level[at] = shift
                at += 1
    return at


# --- the info file and the descriptor -------------------------------------------------

# The info file and the descriptor are a few kB; a larger one is not RAMSES'.
_MAX_TEXT = 1 << 20


def _small_text(path: Path, what: str) -> str:
    """The text of the small regular file `path` (never a FIFO or a device: they would
    block or never end); FileNotFoundError where there is none."""
    why = not_regular(path)
    if why == "no such file":
        raise FileNotFoundError(path)
    if why is not None:
        raise ExabricksError(f"{path}: {why}, not a regular file")
    size = path.stat().st_size
    if size > _MAX_TEXT:
        raise ExabricksError(f"{path}: {size:,} bytes: not a RAMSES {what} (a few kB)")
    return path.read_text(errors="replace")



def _info(path: Path) -> dict:
    """The info file's ``key = value`` lines: ints, floats, strings (ordering type);
    checked: ncpu >= 1, ndim = 3, 1 <= levelmin <= levelmax."""
    try:
        text = _small_text(path, "info file")
    except OSError as e:
        raise ExabricksError(f"{path}: cannot read the info file ({e.strerror or e})") from e
    info = {}
    for line in text.splitlines():
        key, sep, value = line.partition("=")
        if not sep:
            continue
        key, value = key.strip(), value.strip()
        try:
            info[key] = int(value)
        except ValueError:
            try:
                info[key] = float(value.replace("D", "E").replace("d", "e"))
            except ValueError:
                info[key] = value
    for key in ("ncpu", "ndim", "levelmin", "levelmax"):
        if not isinstance(info.get(key), int):
            raise ExabricksError(f"{path}: no integer {key} = ... line: not a RAMSES info file")
    if info["ndim"] != 3:
        raise ExabricksError(f"{path}: ndim = {info['ndim']}: exabricks reads 3D RAMSES outputs only")
    if info["ncpu"] < 1 or info["ncpu"] > 99999:
        raise ExabricksError(f"{path}: ncpu = {info['ncpu']} is not in 1..99999")
    if not 1 <= info["levelmin"] <= info["levelmax"] <= 64:
        raise ExabricksError(f"{path}: levelmin = {info['levelmin']}, levelmax = {info['levelmax']}: "
                             f"need 1 <= levelmin <= levelmax")
    return info


def _descriptor(path: Path) -> list[tuple[str, str]]:
    """(yt's field name, numpy dtype) of each hydro variable of a version-1 descriptor."""
    try:
        lines = _small_text(path, "hydro file descriptor").splitlines()
    except FileNotFoundError:
        raise ExabricksError(f"{path}: no such file: the hydro variables' names are unknown "
                             f"(exabricks reads RAMSES outputs with a version-1 descriptor)") from None
    except OSError as e:
        raise ExabricksError(f"{path}: cannot read it ({e.strerror or e})") from e
    m = re.match(r"#\s*version:\s*(\d+)", lines[0]) if lines else None
    if not m or m.group(1) != "1":
        raise ExabricksError(f"{path}: not a version-1 hydro file descriptor "
                             f"(first line {quoted(lines[0] if lines else '')})")
    out = []
    for number, line in enumerate(lines[1:], 2):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) != 3 or parts[0] != str(len(out) + 1) or parts[2] not in _TYPES:
            raise ExabricksError(f"{path}: line {number} {quoted(line)} is not "
                                 f"'{len(out) + 1}, NAME, TYPE' (TYPE d, f or i)")
        out.append((_YT_NAMES.get(parts[1], f"hydro_{parts[1]}"), parts[2]))
    if not out:
        raise ExabricksError(f"{path}: lists no hydro variable")
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        raise ExabricksError(f"{path}: variable {next(n for n in names if names.count(n) > 1)!r} "
                             f"listed twice")
    return out


# --- Fortran records ---------------------------------------------------------------------


class _Reader:
    """Sequential Fortran records of the file `f` (`path` in messages), little-endian
    with int32 markers."""

    def __init__(self, f, path: Path):
        self.f, self.path = f, path
        self.size = os.fstat(f.fileno()).st_size
        self.count = 0

    def record(self, what: str) -> bytes:
        at = self.f.tell()
        head = self.f.read(4)
        self.count += 1
        if len(head) < 4:
            raise ExabricksError(f"{self.path}: truncated: ends before record {self.count} ({what})")
        n = int(np.frombuffer(head, "<i4")[0])
        if n < 0 or at + 8 + n > self.size:
            if self.count == 1 and int(np.frombuffer(head, ">i4")[0]) in range(0, 1 << 16):
                raise ExabricksError(f"{self.path}: a big-endian file; exabricks reads "
                                     f"little-endian RAMSES files only")
            raise ExabricksError(f"{self.path}: truncated or not a Fortran record file: record "
                                 f"{self.count} ({what}) claims {n} bytes from byte {at + 4} "
                                 f"but the file holds {self.size}")
        data = self.f.read(n)
        tail = self.f.read(4)
        if tail != head:
            raise ExabricksError(f"{self.path}: record {self.count} ({what}): the length markers "
                                 f"disagree (a damaged file or 8-byte markers)")
        return data

    def ints(self, what: str, count: int | None = None) -> np.ndarray:
        data = self.record(what)
        if len(data) % 4 or (count is not None and len(data) != 4 * count):
            want = f"{count} int32" if count is not None else "int32 values"
            raise ExabricksError(f"{self.path}: record {self.count} ({what}) holds {len(data)} "
                                 f"bytes, not {want}")
        return np.frombuffer(data, "<i4").astype(np.int64)


def _amr_header(f, path: Path, info: dict) -> dict:
    """The amr file's header, checked against the info file; its oct groups' counts and
    byte offsets, and the size of its reals."""
    r = _Reader(f, path)
    ncpu = int(r.ints("ncpu", 1)[0])
    ndim = int(r.ints("ndim", 1)[0])
    nx = r.ints("nx ny nz", 3)
    nlevelmax = int(r.ints("nlevelmax", 1)[0])
    r.ints("ngridmax", 1)
    nboundary = int(r.ints("nboundary", 1)[0])
    r.ints("ngrid_current", 1)
    if ncpu != info["ncpu"] or ndim != 3 or nlevelmax < info["levelmax"] or nboundary < 0:
        raise ExabricksError(
            f"{path}: ncpu {ncpu}, ndim {ndim}, nlevelmax {nlevelmax}, nboundary {nboundary} "
            f"disagree with the info file (ncpu {info['ncpu']}, ndim 3, levelmax {info['levelmax']})")
    if np.any(nx != 1):
        raise ExabricksError(f"{path}: a coarse grid of {nx.tolist()} cells; exabricks reads RAMSES "
                             f"outputs with nx = ny = nz = 1 only")
    boxlen = r.record("boxlen")
    if len(boxlen) not in (4, 8):
        raise ExabricksError(f"{path}: record {r.count} (boxlen) holds {len(boxlen)} bytes, not one real")
    real = np.dtype(f"<f{len(boxlen)}")
    r.ints("noutput iout ifout", 3)
    for what in ("tout", "aout", "t", "dtold", "dtnew", "nstep nstep_coarse", "einit mass_tot_0 "
                 "rho_tot", "cosmology", "aexp hexp aexp_old epot_tot_int epot_tot_old"):
        r.record(what)
    # mass_sph (one real) in RAMSES since 2013; older files go on with headl
    if len(r.record("mass_sph or headl")) == real.itemsize and 4 * ncpu * nlevelmax != real.itemsize:
        r.record("headl")
    r.record("taill")
    numbl = r.ints("numbl", ncpu * nlevelmax).reshape(nlevelmax, ncpu)
    r.record("numbtot")
    counts = numbl
    if nboundary > 0:
        r.record("headb"), r.record("tailb")
        numbb = r.ints("numbb", nboundary * nlevelmax).reshape(nlevelmax, nboundary)
        counts = np.concatenate([numbl, numbb], axis=1)
    r.ints("free memory", 5)
    ordering = r.record("ordering").decode("ascii", "replace").strip()
    if ordering == "hilbert":
        r.record("bound_key")
    elif ordering == "bisection":
        for what in ("bisec_wall", "bisec_next", "bisec_indx", "bisec_cpubox_min", "bisec_cpubox_max"):
            r.record(what)
    else:
        raise ExabricksError(f"{path}: ordering {quoted(ordering)}: exabricks reads the hilbert and "
                             f"bisection orderings only")
    for what in ("son", "flag1", "cpu_map"):
        r.ints(f"{what} of the coarse cell", 1)
    if np.any(counts < 0):
        raise ExabricksError(f"{path}: negative oct counts in numbl")
    sizes = np.where(counts > 0, _INT_RECORDS * (4 * counts + 8) + _REAL_RECORDS * (real.itemsize * counts + 8), 0)
    offsets = f.tell() + np.concatenate([[0], np.cumsum(sizes.ravel())])
    _checks.claim(path, f"numbl, listing {int(counts.sum())} octs,", int(offsets[-1]) - f.tell(),
                  "the file", r.size, at=f.tell())
    return {"counts": counts, "offsets": offsets[:-1].reshape(counts.shape), "real": real,
            "nlevelmax": nlevelmax, "ncpu": ncpu, "nboundary": nboundary}


def _owned_octs(f, path: Path, header: dict, cpu: int, levelmin: int) -> list:
    """(cpu, level, oct indices (n, 3) int32 on the level's 2**(level-1) lattice, leaf
    mask (n, 8)) of each level >= levelmin with octs of `cpu`: its owned octs.  Only
    their xg and son records are read."""
    real = header["real"]
    out = []
    for lv in range(levelmin, header["nlevelmax"] + 1):
        ng = int(header["counts"][lv - 1, cpu - 1])
        if ng == 0:
            continue
        if lv - 1 > MAX_LEVEL:
            raise ExabricksError(f"{path}: octs of level {lv}: more than {MAX_LEVEL} levels")
        base = int(header["offsets"][lv - 1, cpu - 1])
        ints, reals = 4 * ng + 8, real.itemsize * ng + 8
        xg = _columns(f, path, base + 3 * ints, 3, real, ng, lv, cpu)
        son = _columns(f, path, base + 3 * ints + 3 * reals + 7 * ints, 8, np.dtype("<i4"), ng, lv, cpu)
        scaled = xg.astype(np.float64) * float(2 ** (lv - 1)) - 0.5
        q = np.rint(scaled)
        bad = ~(np.abs(scaled - q) <= 1e-3) | (q < 0) | (q >= 2 ** (lv - 1))
        if np.any(bad):
            i = int(np.flatnonzero(bad.any(axis=1))[0])
            raise ExabricksError(f"{path}: oct {i} of level {lv}, cpu {cpu} has centre "
                                 f"{xg[i].tolist()}, not one of that level's oct centres in [0, 1]")
        out.append((cpu, lv, q.astype(LATTICE_DTYPE), son == 0))
    return out


def _columns(f, path: Path, at: int, count: int, dtype: np.dtype, ng: int, lv: int, cpu: int) -> np.ndarray:
    """`count` consecutive records of `ng` values of `dtype` from byte `at`, as the
    columns of an (ng, count) array; their length markers checked."""
    size = dtype.itemsize * ng
    f.seek(at)
    block = f.read(count * (size + 8))
    out = np.empty((ng, count), dtype.newbyteorder("="))
    for k in range(count):
        start = k * (size + 8)
        marks = np.frombuffer(block, "<i4", 1, start), np.frombuffer(block, "<i4", 1, start + 4 + size)
        if marks[0][0] != size or marks[1][0] != size:
            raise ExabricksError(
                f"{path}: the octs of level {lv}, cpu {cpu} are not where numbl puts them "
                f"(a record of {int(marks[0][0])} bytes, not {size}, at byte {at + start}): "
                f"a damaged file")
        out[:, k] = np.frombuffer(block, dtype, ng, start + 4)
    return out


def _read_hydro(f, path: Path, layout: dict, descriptor, descriptor_path: Path, cpu: int,
                groups, wanted: list[int], values: np.ndarray, at: int) -> int:
    """Fill values[:, at:...] with the leaves of `groups` (this cpu's, in order) from the
    hydro file; return the next free column."""
    r = _Reader(f, path)
    ncpu = int(r.ints("ncpu", 1)[0])
    nvar = int(r.ints("nvar", 1)[0])
    ndim = int(r.ints("ndim", 1)[0])
    nlevelmax = int(r.ints("nlevelmax", 1)[0])
    nboundary = int(r.ints("nboundary", 1)[0])
    r.record("gamma")
    if nvar != len(descriptor):
        raise ExabricksError(f"{path}: nvar = {nvar} but {descriptor_path} lists "
                             f"{len(descriptor)} variables")
    if (ncpu, ndim, nlevelmax, nboundary) != (layout["ncpu"], 3, layout["nlevelmax"], layout["nboundary"]):
        raise ExabricksError(f"{path}: ncpu {ncpu}, ndim {ndim}, nlevelmax {nlevelmax}, nboundary "
                             f"{nboundary} disagree with the amr file's")
    itemsize = np.array([np.dtype(_TYPES[t]).itemsize for _, t in descriptor], np.int64)
    counts = layout["counts"]
    sizes = 24 + np.where(counts > 0, 8 * (counts * int(itemsize.sum()) + 8 * nvar), 0)
    offsets = f.tell() + np.concatenate([[0], np.cumsum(sizes.ravel())])
    _checks.claim(path, f"the hydro data of the amr file's {int(counts.sum())} octs",
                  int(offsets[-1]) - f.tell(), "the file", r.size, at=f.tell())
    offsets = offsets[:-1].reshape(counts.shape)
    for (_, lv, _, mask), k in groups:
        ng = len(mask)
        base = int(offsets[lv - 1, cpu - 1])
        f.seek(base)
        head = np.frombuffer(f.read(24), "<i4")
        if head[0] != 4 or head[2] != 4 or head[3] != 4 or head[5] != 4 or head[1] != lv or head[4] != ng:
            types = ", ".join(t for _, t in descriptor)
            raise ExabricksError(f"{path}: the records of level {lv}, cpu {cpu} are not where the "
                                 f"amr file's oct counts and {descriptor_path.name}'s {nvar} "
                                 f"variables of types {types} put them: the files disagree or "
                                 f"are damaged")
        per_ind = int(8 * nvar + ng * int(itemsize.sum()))
        var_at = np.concatenate([[0], np.cumsum(ng * itemsize + 8)])
        starts = np.concatenate([[0], np.cumsum(mask.sum(axis=0))])
        for ind in range(8):
            if starts[ind + 1] == starts[ind]:
                continue
            for row, v in enumerate(wanted):
                dtype = np.dtype("<" + _TYPES[descriptor[v][1]])
                f.seek(base + 24 + ind * per_ind + int(var_at[v]))
                data = f.read(ng * dtype.itemsize + 8)
                marks = np.frombuffer(data, "<i4", 1, 0), np.frombuffer(data, "<i4", 1, 4 + ng * dtype.itemsize)
                if marks[0][0] != ng * dtype.itemsize or marks[1][0] != ng * dtype.itemsize:
                    raise ExabricksError(
                        f"{path}: level {lv}, cpu {cpu}: variable {v + 1} of cell {ind + 1} is a "
                        f"record of {int(marks[0][0])} bytes, not {ng} values of "
                        f"{dtype.itemsize} bytes ({descriptor_path} says type "
                        f"{descriptor[v][1]!r}): the files disagree or are damaged")
                column = np.frombuffer(data, dtype, ng, 4)[mask[:, ind]]
                with np.errstate(over="ignore", invalid="ignore"):
                    values[row, at + starts[ind]:at + starts[ind + 1]] = column
        at += k
    return at
