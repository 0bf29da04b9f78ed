"""A small FLASH4 plotfile (PARAMESH block octree) in FLASH's own HDF5 layout, as
FLASH 4 with PARAMESH 4 and the serial HDF5 I/O unit writes it (file format version 9,
the name `BASE_hdf5_plt_cnt_NNNN`); yt 4.4.3's FLASH front end (FLASHDataset) reads it.

The mesh: blocks of NB^3 = 8^3 cells, ROOTS = 4x1x1 root blocks over [LO, HI] =
[-2, 2] x [0.5, 1.5] x [2, 3] (cubic cells of width 1/8, 1/16, 1/32; the lower corner
off the origin); a block of refinement level L (0-based; FLASH's "refine level" is
L + 1) is refined into its 8 children iff `analytic_amr.refined` says so and
L < MAX_LEVEL = 2: 4 + 24 + 96 blocks, 1 + 12 + 96 of them leaves, 55,808 leaf cells,
every level partly refined.  The rule's tree is 2:1 balanced across faces, edges and
corners, as PARAMESH requires (2x1x1 roots give only two leaf widths with MAX_LEVEL 2,
and leaves two levels apart side by side with 3).  Every block, leaf or not, stores the
field values at its cell centres.

Datasets (nblocks = N, all at the file's root):
  "unknown names"       (nvar, 1) S4: "dens", "pres"
  "dens", "pres"        (N, nzb, nyb, nxb) float32 (plotfiles are single precision),
                        attributes "minimum", "maximum" (1,) float64
  "refine level"        (N,) int32, 1 = the root blocks
  "node type"           (N,) int32, PARAMESH's: 1 leaf, 2 parent of a leaf, 3 a parent
                        whose children are all parents
  "which child"         (N,) int32, the block's child index 1..8 in its parent, -1 for roots
  "gid"                 (N, 15) int32, 1-based block ids: 6 face neighbours (-x, +x, -y,
                        +y, -z, +z) at the same level (-1: none there, the neighbour is
                        coarser; -32: FLASH's OUTFLOW code at the domain's faces), the
                        parent (-1 for roots), 8 children (-1 for leaves), children in
                        PARAMESH's order (x fastest, then y, then z)
  "processor number"    (N,) int32 (all 0: one process)
  "coordinates", "block size" (N, 3) and "bounding box" (N, 3, 2) float32 (FLASH writes
                        the tree's reals in single precision in plotfiles unless
                        plotfileMetadataDP; every value here is dyadic, so exact)
  "sim info"            (1,) compound, "file format version" = 9, setup and build strings
  "{integer,real,string,logical} {runtime parameters,scalars}" (n,) compounds of
                        ("name" S80, "value" int32 / float64 / S80 / int32), names
                        lower case and space-padded as Fortran writes them.
Blocks are in PARAMESH's Morton order: each root, then its children's subtrees in
child order (parents before their children).  Left out (yt reads neither): "bflags"
and "gsurr_blks", which PARAMESH 4 builds of FLASH also write.

yt needs these parameters: the integer scalars nxb, nyb, nzb, dimensionality and
globalnumblocks; the real scalar time; the integer runtime parameters lrefine_min (its
presence means PARAMESH) and nblockx, nblocky, nblockz; the real runtime parameters
xmin ... zmax; the string runtime parameter geometry.  It takes its children from
"gid", the blocks' extents from "bounding box" and their levels from "refine level".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from helpers import analytic_amr

NB = 8                                   # cells per block edge (nxb = nyb = nzb)
ROOTS = (4, 1, 1)                        # root blocks (nblockx, nblocky, nblockz)
LO = np.array([-2.0, 0.5, 2.0])
HI = np.array([2.0, 1.5, 3.0])
MAX_LEVEL = 2                            # 0-based: refine levels 1 .. 3 in the file
NAMES = {"density": "dens", "pressure": "pres"}   # analytic field -> FLASH variable
OUTFLOW = -32                            # FLASH's constants.h: a neighbour past the domain
NAME = "sedov_hdf5_plt_cnt_0001"


@dataclass
class Block:
    """One PARAMESH block: its lower corner (3,) and edge (world), level (0-based),
    and the indices of its parent (-1 none) and children, and which child it is (1..8)."""

    lower: np.ndarray
    size: float
    level: int
    parent: int = -1
    which: int = -1
    children: list[int] = field(default_factory=list)


def block_tree(lo=LO, hi=HI, roots=ROOTS, max_level=MAX_LEVEL) -> list[Block]:
    """The block octree over [lo, hi] of `roots` cubic root blocks, in Morton order
    (depth first, children x fastest), refined by `analytic_amr.refined`."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    size = (hi - lo) / np.asarray(roots)
    assert np.all(size == size[0]), "root blocks must be cubes"
    blocks: list[Block] = []

    def visit(lower, size, level, parent, which):
        i = len(blocks)
        blocks.append(Block(lower, size, level, parent, which))
        if level < max_level and analytic_amr.refined(lower[None], (lower + size)[None], lo, hi, level)[0]:
            for c in range(8):
                offset = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1]) * (size / 2)
                blocks[i].children.append(visit(lower + offset, size / 2, level + 1, i, c + 1))
        return i

    for k in range(roots[2]):
        for j in range(roots[1]):
            for i in range(roots[0]):
                visit(lo + np.array([i, j, k]) * size[0], float(size[0]), 0, -1, -1)
    return blocks


def cell_centres(blocks: list[Block], n: int = NB) -> np.ndarray:
    """(nblocks, n^3, 3) world centres of every block's cells, x fastest (the flat order
    of both FLASH's (nzb, nyb, nxb) arrays and Chombo's Fortran-ordered boxes)."""
    k, j, i = np.meshgrid(*[np.arange(n)] * 3, indexing="ij")
    unit = (np.stack([i, j, k], axis=-1).reshape(-1, 3) + 0.5) / n          # (n^3, 3)
    lower = np.stack([b.lower for b in blocks])[:, None, :]
    size = np.array([b.size for b in blocks])[:, None, None]
    return lower + unit[None] * size


def leaves_of(blocks: list[Block], lo=LO, hi=HI, n: int = NB) -> analytic_amr.Leaves:
    """The leaf cells of the tree: every cell of every block without children."""
    leaf = [b for b in blocks if not b.children]
    width = np.repeat([b.size / n for b in leaf], n ** 3)
    lower = cell_centres(leaf, n).reshape(-1, 3) - 0.5 * width[:, None]
    return analytic_amr.Leaves(lower=lower, width=width, lo=np.asarray(lo, np.float64),
                               hi=np.asarray(hi, np.float64))


def gid(blocks: list[Block], lo=LO, roots=ROOTS) -> np.ndarray:
    """(N, 15) int32 PARAMESH ids (1-based): face neighbours, parent, children."""
    key = {}
    for i, b in enumerate(blocks):
        key[(b.level, *np.rint((b.lower - lo) / b.size).astype(int))] = i
    out = np.full((len(blocks), 15), -1, np.int32)
    for i, b in enumerate(blocks):
        here = np.rint((b.lower - lo) / b.size).astype(int)
        extent = np.asarray(roots) * 2 ** b.level
        for face in range(6):
            there = here.copy()
            there[face // 2] += 1 if face % 2 else -1
            if there[face // 2] < 0 or there[face // 2] >= extent[face // 2]:
                out[i, face] = OUTFLOW
            else:
                out[i, face] = key.get((b.level, *there), -2) + 1
        out[i, 6] = b.parent + 1 if b.parent >= 0 else -1
        out[i, 7:7 + len(b.children)] = np.asarray(b.children) + 1
    return out


def node_type(blocks: list[Block]) -> np.ndarray:
    """PARAMESH's node type: 1 leaf, 2 parent of at least one leaf, 3 otherwise."""
    def kind(b):
        if not b.children:
            return 1
        return 2 if any(not blocks[c].children for c in b.children) else 3
    return np.array([kind(b) for b in blocks], np.int32)


def _table(entries: dict, value_dtype) -> np.ndarray:
    """A FLASH name/value list: names and string values space-padded to 80 characters."""
    table = np.zeros(len(entries), dtype=[("name", "S80"), ("value", value_dtype)])
    for row, (name, value) in enumerate(entries.items()):
        table[row] = (name.ljust(80).encode(), value.ljust(80).encode() if isinstance(value, str) else value)
    return table


def _parameters(nblocks: int, lo, hi, roots, max_level) -> dict[str, np.ndarray]:
    """The runtime parameters and scalars FLASH writes (a subset: those yt reads and
    the usual ones of a Sedov run)."""
    sides = {f"{a}{s}_boundary_type": "outflow" for a in "xyz" for s in "lr"}
    return {
        "integer runtime parameters": _table(
            {"lrefine_min": 1, "lrefine_max": max_level + 1, "nblockx": roots[0],
             "nblocky": roots[1], "nblockz": roots[2], "nrefs": 2, "nend": 1000,
             "checkpointfilenumber": 0, "plotfilenumber": 0}, np.int32),
        "real runtime parameters": _table(
            {"xmin": lo[0], "xmax": hi[0], "ymin": lo[1], "ymax": hi[1], "zmin": lo[2],
             "zmax": hi[2], "gamma": 1.4, "cfl": 0.8, "tmax": 0.05, "dtinit": 1e-5,
             "refine_cutoff_1": 0.8, "derefine_cutoff_1": 0.2}, np.float64),
        "string runtime parameters": _table(
            {"geometry": "cartesian", **sides, "basenm": "sedov_", "log_file": "sedov.log",
             "run_comment": "exabricks test output", "plot_var_1": "dens",
             "plot_var_2": "pres", "refine_var_1": "dens", "unitsystem": "none"}, "S80"),
        "logical runtime parameters": _table(
            {"restart": 0, "plotfilemetadatadp": 0, "plotfilegridquantitydp": 0}, np.int32),
        "integer scalars": _table(
            {"nxb": NB, "nyb": NB, "nzb": NB, "dimensionality": 3,
             "globalnumblocks": nblocks, "splitnumblocks": nblocks, "nstep": 20,
             "nbegin": 1, "plotfilenumber": 1, "checkpointfilenumber": 0,
             "forcedplotfilenumber": 0}, np.int32),
        "real scalars": _table({"time": 0.0125, "dt": 6.25e-4, "dtold": 6.2e-4,
                                "redshift": 0.0}, np.float64),
        "string scalars": _table({"file creation time": "1-1-2024  12:00:00.000",
                                  "run comment": "exabricks test output",
                                  "setup call": "./setup Sedov -auto -3d"}, "S80"),
        "logical scalars": _table({"restart": 0, "file_per_proc": 0}, np.int32),
    }


def _sim_info() -> np.ndarray:
    """FLASH's "sim info" record (file format version 9: FLASH 3 and 4)."""
    wide, narrow = "S400", "S80"
    dtype = [("file format version", np.int32), ("setup call", wide),
             ("file creation time", narrow), ("flash version", narrow),
             ("build date", narrow), ("build dir", narrow), ("build machine", narrow),
             ("cflags", wide), ("fflags", wide), ("setup time stamp", narrow),
             ("build time stamp", narrow)]
    info = np.zeros(1, dtype)
    info[0] = (9, b"./setup Sedov -auto -3d", b"1-1-2024  12:00:00.000", b"FLASH 4.6.2",
               b"Mon Jan  1 10:00:00 2024", b"/home/user/FLASH4.6.2/object", b"localhost",
               b"-O2", b"-O2 -r8 -i4", b"Mon Jan  1 09:59:00 2024", b"Mon Jan  1 10:00:00 2024")
    return info


def write(folder: Path, *, lo=LO, hi=HI, roots=ROOTS, max_level=MAX_LEVEL,
          name: str = NAME) -> tuple[Path, analytic_amr.Leaves]:
    """Write `folder/name`, a FLASH4 plotfile of the analytic fields on the block tree
    (`block_tree`), and return its path and its leaf cells (world units)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    blocks = block_tree(lo, hi, roots, max_level)
    lower = np.stack([b.lower for b in blocks])
    size = np.array([[b.size] * 3 for b in blocks])
    centres = cell_centres(blocks)
    path = Path(folder) / name
    with h5py.File(path, "w") as f:
        f["sim info"] = _sim_info()
        for key, table in _parameters(len(blocks), lo, hi, roots, max_level).items():
            f[key] = table
        f["unknown names"] = np.array([[NAMES[n].encode()] for n in analytic_amr.FIELDS], "S4")
        f["refine level"] = np.array([b.level + 1 for b in blocks], np.int32)
        f["node type"] = node_type(blocks)
        f["which child"] = np.array([b.which for b in blocks], np.int32)
        f["gid"] = gid(blocks, lo, roots)
        f["processor number"] = np.zeros(len(blocks), np.int32)
        f["coordinates"] = (lower + size / 2).astype(np.float32)
        f["block size"] = size.astype(np.float32)
        f["bounding box"] = np.stack([lower, lower + size], axis=-1).astype(np.float32)
        for field_name in analytic_amr.FIELDS:
            values = analytic_amr.value(field_name, centres.reshape(-1, 3), lo, hi)
            data = f.create_dataset(NAMES[field_name], data=values.reshape(len(blocks), NB, NB, NB)
                                    .astype(np.float32))
            data.attrs["minimum"] = np.array([values.min()])
            data.attrs["maximum"] = np.array([values.max()])
    return path, leaves_of(blocks, lo, hi)
