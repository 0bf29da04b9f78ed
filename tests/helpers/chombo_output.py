"""A small Chombo plotfile in Chombo's own HDF5 layout, as an AMR application of
Chombo 3 writes it (AMR::writePlotFile with AMRLevel::writePlotHeader/writePlotLevel,
through CH_HDF5's HDF5HeaderData and write(BoxLayout) / write(LevelData<FArrayBox>));
yt 4.4.3's Chombo front end reads it as a plain ChomboDataset (not Orion2, Pluto or
ChomboPIC: no orion2.ini or pluto.ini beside it, no "CeilVA_mass" attribute, no
"Charm_global" group).

The mesh is the block tree of helpers.flash_output (the same domain, refinement rule
and levels): one 8^3-cell box per block, level L of the tree = Chombo's level_L, ref
ratio 2, each level properly nested in the one below (the tree is 2:1 balanced across
faces, edges and corners).  Every box stores the float64 field values at its cells.

A Chombo plotfile holds no origin, only index boxes: yt puts cell i of a level at
[i, i + 1) * dx, i.e. index 0 at the origin.  A domain whose lower corner is elsewhere
is a prob_domain whose lower index is not 0 (so the corner must be a multiple of dx_0);
yt takes domain_left_edge = dx_0 * prob_domain's lower corner, so [-2, 2] x [0.5, 1.5]
x [2, 3] with dx_0 = 1/8 is prob_domain (-16, 4, 16)..(15, 11, 23).

Layout (HDF5 types as Chombo's: int attributes int32, reals float64, strings fixed
length without a terminator, boxes and IntVects compound):
  /  attributes  max_level, num_levels, iteration (int), time (real),
                 num_components (int), component_0 = "density", component_1 = "pressure"
  /Chombo_global  attributes SpaceDim = 3 (int), testReal = 0.0 (real)
  /level_L  attributes  ref_ratio = 2 (int), dx, dt, time (real),
                        prob_domain (box: lo_i, lo_j, lo_k, hi_i, hi_j, hi_k; hi inclusive)
            boxes             (nboxes,) box compound, in the tree's Morton order
            Processors        (nboxes,) int32 (all 0: one process)
            data:offsets=0    (nboxes + 1,) int64, the start of each box in data:datatype=0
            data:datatype=0   (ncells * ncomp,) float64: box after box, each box component
                              after component, each component Fortran order (i fastest)
            data_attributes   group, attributes comps (int), objectType = "FArrayBox",
                              ghost, outputGhost (IntVect: intvecti, intvectj, intvectk) = 0
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from helpers import analytic_amr, flash_output

NAMES = {"density": "density", "pressure": "pressure"}   # analytic field -> component name
NAME = "plt0001.3d.hdf5"
_AXES = "ijk"
BOX = np.dtype([(f"{end}_{a}", np.int32) for end in ("lo", "hi") for a in _AXES])
INTVECT = np.dtype([(f"intvect{a}", np.int32) for a in _AXES])


def _string(obj, name: str, value: str) -> None:
    """A Chombo string attribute of the group or file `obj`: a copy of H5T_C_S1 (null-terminated padding) sized to
    exactly the string's length and written raw, so it holds no terminator (h5py's
    high-level write would convert, and drop the last character for the terminator)."""
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(len(value))
    attr = h5py.h5a.create(obj.id, name.encode(), tid, h5py.h5s.create(h5py.h5s.SCALAR))
    attr.write(np.array(value.encode(), dtype=f"S{len(value)}"), mtype=tid)


def _box(lo, hi) -> np.ndarray:
    """A Chombo Box (inclusive hi) as a scalar of the box compound."""
    return np.array(tuple(int(v) for v in (*lo, *hi)), dtype=BOX)


def _level_boxes(blocks, level: int, dx: float, n: int):
    """The level's blocks and their index boxes (lower (nboxes, 3) int, inclusive)."""
    mine = [b for b in blocks if b.level == level]
    lower = np.rint(np.stack([b.lower for b in mine]) / dx).astype(np.int64)
    assert np.all(lower * dx == np.stack([b.lower for b in mine])), "box corners off the level's lattice"
    return mine, lower, lower + n - 1


def _write_level(f, blocks, level: int, dx: float, dt: float, time: float,
                 domain: tuple, lo: np.ndarray, hi: np.ndarray, n: int) -> None:
    """Group level_`level`: its header, boxes, Processors, data and data_attributes."""
    group = f.create_group(f"level_{level}")
    group.attrs.create("ref_ratio", 2, dtype=np.int32)
    group.attrs.create("dx", dx, dtype=np.float64)
    group.attrs.create("dt", dt, dtype=np.float64)
    group.attrs.create("time", time, dtype=np.float64)
    group.attrs.create("prob_domain", _box(*domain))
    mine, box_lo, box_hi = _level_boxes(blocks, level, dx, n)
    boxes = np.zeros(len(mine), BOX)
    for k, a in enumerate(_AXES):
        boxes[f"lo_{a}"], boxes[f"hi_{a}"] = box_lo[:, k], box_hi[:, k]
    group["boxes"] = boxes
    group["Processors"] = np.zeros(len(mine), np.int32)
    centres = flash_output.cell_centres(mine, n)                          # (nboxes, n^3, 3)
    values = np.stack([analytic_amr.value(name, centres.reshape(-1, 3), lo, hi)
                       .reshape(len(mine), n ** 3) for name in analytic_amr.FIELDS], axis=1)
    per_box = len(analytic_amr.FIELDS) * n ** 3
    group["data:offsets=0"] = np.arange(len(mine) + 1, dtype=np.int64) * per_box
    group["data:datatype=0"] = values.reshape(-1).astype(np.float64)       # box, comp, cell
    data_attributes = group.create_group("data_attributes")
    data_attributes.attrs.create("comps", len(analytic_amr.FIELDS), dtype=np.int32)
    _string(data_attributes, "objectType", "FArrayBox")
    data_attributes.attrs.create("ghost", np.zeros((), INTVECT))
    data_attributes.attrs.create("outputGhost", np.zeros((), INTVECT))


def write(folder: Path, *, lo=flash_output.LO, hi=flash_output.HI, roots=flash_output.ROOTS,
          max_level=flash_output.MAX_LEVEL, name: str = NAME) -> tuple[Path, analytic_amr.Leaves]:
    """Write `folder/name`, a Chombo plotfile of the analytic fields on the block tree
    of helpers.flash_output, and return its path and its leaf cells (world units)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    n = flash_output.NB
    blocks = flash_output.block_tree(lo, hi, roots, max_level)
    levels = 1 + max(b.level for b in blocks)
    dx0 = float((hi[0] - lo[0]) / (roots[0] * n))
    time, dt0 = 0.0125, 6.25e-4
    path = Path(folder) / name
    with h5py.File(path, "w") as f:
        f.attrs.create("max_level", max_level, dtype=np.int32)
        f.attrs.create("num_levels", levels, dtype=np.int32)
        f.attrs.create("iteration", 20, dtype=np.int32)
        f.attrs.create("time", time, dtype=np.float64)
        f.attrs.create("num_components", len(analytic_amr.FIELDS), dtype=np.int32)
        for c, field_name in enumerate(analytic_amr.FIELDS):
            _string(f, f"component_{c}", NAMES[field_name])
        chombo = f.create_group("Chombo_global").attrs
        chombo.create("SpaceDim", 3, dtype=np.int32)
        chombo.create("testReal", 0.0, dtype=np.float64)
        for level in range(levels):
            dx = dx0 / 2 ** level
            first = np.rint(lo / dx).astype(np.int64)
            assert np.all(first * dx == lo), "the domain's corner is off the level's lattice"
            last = first + np.rint((hi - lo) / dx).astype(np.int64) - 1
            _write_level(f, blocks, level, dx, dt0 / 2 ** level, time, (first, last), lo, hi, n)
    return path, flash_output.leaves_of(blocks, lo, hi)
