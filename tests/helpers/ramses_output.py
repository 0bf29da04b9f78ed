"""A small RAMSES output written in RAMSES' own on-disk layout, the octree refined by
`analytic_amr.refined` and every cell's hydro values `analytic_amr.value` (float64).

`write(folder)` makes ``folder/output_00001/`` with

- ``info_00001.txt``: ncpu, ndim, levelmin, levelmax, ngridmax, nstep_coarse, then
  boxlen = unit_l = unit_d = unit_t = 1, time 0, aexp = H0 = 1 (not cosmological), then
  ``ordering type=hilbert`` and each domain's Hilbert key range (``DOMAIN ind_min
  ind_max``), as RAMSES' output_info writes them;
- ``amr_00001.out0000N`` (N = 1, 2), Fortran unformatted sequential records (int32
  markers, little-endian int32 integers and float64 reals): ncpu; ndim; nx ny nz;
  nlevelmax; ngridmax; nboundary; ngrid_current; boxlen; noutput iout ifout; tout;
  aout; t; dtold; dtnew; nstep nstep_coarse; einit mass_tot_0 rho_tot; the 7
  cosmological constants; aexp hexp aexp_old epot_tot_int epot_tot_old; mass_sph;
  headl; taill; numbl; numbtot; headf tailf numbf used_mem used_mem_tot; ordering
  (128 characters, "hilbert"); bound_key(0:ncpu); son, flag1, cpu_map of the one
  coarse cell; then for each level 1..levelmax and each cpu with numbl > 0 the records
  ind_grid, next, prev, xg(x), xg(y), xg(z), father, nbor(1..6), son(1..8),
  cpu_map(1..8), flag1(1..8) of its octs (cell ind = 1 + x + 2y + 4z);
- ``hydro_00001.out0000N``: ncpu; nvar; ndim; nlevelmax; nboundary; gamma; then for
  each level and cpu the records ilevel, ncache and, where ncache > 0, for each cell
  ind 1..8 and each variable the ncache float64 values;
- ``hydro_file_descriptor.txt`` (version 1): ``density, d`` and ``pressure, d``.

Levels: RAMSES level l holds octs of cell width 2**-l (boxlen 1, one coarse cell);
levels 1..levelmin are fully refined; a cell of level l >= levelmin is refined iff
`analytic_amr.refined(..., level=l - levelmin, radius=radius)` and l < levelmax, i.e.
analytic level 0 is RAMSES level levelmin, the coarsest cells yt shows.  Domain [0,
1]^3 code_length.  `write`'s levelmin, levelmax and radius set the size (defaults
LEVELMIN = 3, LEVELMAX = 6 and 0.3: what the figures below describe); with levelmin 7
and up each further level adds about as many leaves as the one before (for a radius
r, about 7 x 4/3 pi (r 2**levelmin)**3 where the ball lies inside the box).

Domains: a cell's cpu is the one whose [bound_key(cpu-1), bound_key(cpu)) holds the
Hilbert key (RAMSES' hilbert3d, bit length levelmax + 1) of its centre; an oct
belongs to its father cell's cpu.  The one bound key between the two domains falls
on a level levelmin - 1 cell, so every oct of level >= levelmin lies in one domain
with its whole subtree (domain 1: the fewest such cells, in key order, that hold half
the octs of levels >= levelmin; by default 289 of 436, the ball's root cells being
heavy).
File N holds domain N's octs and, as virtual octs under their owners' numbl, their
coarser ancestors: no ghost layer of neighbouring domains (nbor and son pointing to
octs not in the file are 0).  yt 4.4.3 reads it, given the info file or the folder:
fields ("ramses", "Density"), ("ramses", "Pressure"); by default 3116 leaves of widths
1/8 to 1/64 (RAMSES levels 3..6).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from helpers import analytic_amr

LEVELMIN = 3
LEVELMAX = 6
NCPU = 2
IOUT = 1
NCOARSE = 1  # nx = ny = nz = 1
GAMMA = 1.4
DESCRIPTOR_NAMES = ("density", "pressure")  # analytic_amr.FIELDS, in that order

# cell ind - 1 -> its (x, y, z) offset in the oct: x fastest
_OFFSETS = np.array([[i & 1, (i >> 1) & 1, i >> 2] for i in range(8)], np.int64)
# RAMSES' hilbert3d state diagram: per state, the next states then the key digits,
# both indexed by the digit 4 x_bit + 2 y_bit + z_bit
_STATES = np.array([
    [[1, 2, 3, 2, 4, 5, 3, 5], [0, 1, 3, 2, 7, 6, 4, 5]],
    [[2, 6, 0, 7, 8, 8, 0, 7], [0, 7, 1, 6, 3, 4, 2, 5]],
    [[0, 9, 10, 9, 1, 1, 11, 11], [0, 3, 7, 4, 1, 2, 6, 5]],
    [[6, 0, 6, 11, 9, 0, 9, 8], [2, 3, 1, 0, 5, 4, 6, 7]],
    [[11, 11, 0, 7, 5, 9, 0, 7], [4, 3, 5, 2, 7, 0, 6, 1]],
    [[4, 4, 8, 8, 0, 6, 10, 6], [6, 5, 1, 2, 7, 4, 0, 3]],
    [[5, 7, 5, 3, 1, 1, 11, 11], [4, 7, 3, 0, 5, 6, 2, 1]],
    [[6, 1, 6, 10, 9, 4, 9, 10], [6, 7, 5, 4, 1, 0, 2, 3]],
    [[10, 3, 1, 1, 10, 3, 5, 9], [2, 5, 3, 4, 1, 6, 0, 7]],
    [[4, 4, 8, 8, 2, 7, 2, 3], [2, 1, 5, 6, 3, 0, 4, 7]],
    [[7, 2, 11, 2, 7, 5, 8, 5], [4, 5, 7, 6, 3, 2, 0, 1]],
    [[10, 3, 2, 6, 10, 3, 4, 4], [6, 1, 7, 0, 5, 2, 4, 3]],
], np.int64)


def hilbert_keys(ijk, bits: int) -> np.ndarray:
    """RAMSES' hilbert3d: the int64 Hilbert keys of the integer points `ijk` (N, 3) of
    the 2**bits lattice, in [0, 8**bits)."""
    ijk = np.asarray(ijk, np.int64).reshape(-1, 3)
    state = np.zeros(len(ijk), np.int64)
    key = np.zeros(len(ijk), np.int64)
    for i in range(bits - 1, -1, -1):
        digit = 4 * ((ijk[:, 0] >> i) & 1) + 2 * ((ijk[:, 1] >> i) & 1) + ((ijk[:, 2] >> i) & 1)
        key = 8 * key + _STATES[state, 1, digit]
        state = _STATES[state, 0, digit]
    return key


def write(folder: Path, *, levelmin: int = LEVELMIN, levelmax: int = LEVELMAX,
          radius: float = 0.3) -> tuple[Path, analytic_amr.Leaves]:
    """Write ``folder/output_00001`` (see the module) of levels `levelmin`..`levelmax`
    (2 <= levelmin <= levelmax <= 19), refined by the ball of `radius` (at analytic level
    0, in units of the box); return its info file (what yt.load takes) and the leaves
    written, in code_length (domain [0, 1]^3)."""
    if not 2 <= levelmin <= levelmax <= 19:  # 3 (levelmax + 1) key bits fit an int64
        raise ValueError(f"need 2 <= levelmin <= levelmax <= 19, got {levelmin}, {levelmax}")
    out = Path(folder) / f"output_{IOUT:05d}"
    out.mkdir(parents=True, exist_ok=True)
    lo, hi = np.zeros(3), np.ones(3)
    tree = tree_of(levelmin, levelmax, radius)
    bounds = _bound_keys(tree, levelmin, levelmax)
    cpus = _owners(tree, bounds, levelmax)
    ngridmax = sum(len(octs) for octs, _ in tree.values())
    for cpu in range(1, NCPU + 1):
        igrid = _numbering(tree, cpus, cpu, levelmax)
        with open(out / f"amr_{IOUT:05d}.out{cpu:05d}", "wb") as f:
            _write_amr(f, tree, cpus, igrid, bounds, ngridmax, levelmax)
        with open(out / f"hydro_{IOUT:05d}.out{cpu:05d}", "wb") as f:
            _write_hydro(f, tree, cpus, igrid, lo, hi, levelmax)
    (out / "hydro_file_descriptor.txt").write_text(
        "# version:  1\n# ivar, variable_name, variable_type\n"
        + "".join(f"{i:3d}, {n}, d\n" for i, n in enumerate(DESCRIPTOR_NAMES, 1)))
    info = out / f"info_{IOUT:05d}.txt"
    info.write_text(_info_text(bounds, ngridmax, levelmin, levelmax))
    return info, _leaves(tree, lo, hi, levelmin, levelmax)


def leaf_counts(tree) -> dict[int, int]:
    """level -> number of leaves (unrefined cells) of `tree` (`tree_of`), for the levels
    that have any: what `write` would write, counted without writing."""
    counts = {level: int((~refined).sum()) for level, (_, refined) in tree.items()}
    return {level: n for level, n in counts.items() if n}


def tree_of(levelmin: int = LEVELMIN, levelmax: int = LEVELMAX, radius: float = 0.3,
            ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """level 1..levelmax -> (octs (n, 3) int64: oct indices on the 2**(level-1) lattice,
    in Hilbert order; refined (n, 8) bool per cell ind), in the box [0, 1]^3."""
    lo, hi = np.zeros(3), np.ones(3)
    tree = {}
    octs = np.zeros((1, 3), np.int64)
    for level in range(1, levelmax + 1):
        cells = _cells(octs)
        if level < levelmin:
            refined = np.ones(cells.shape[:2], bool)
        elif level == levelmax:
            refined = np.zeros(cells.shape[:2], bool)
        else:
            width = 2.0 ** -level
            flat = cells.reshape(-1, 3) * width
            refined = analytic_amr.refined(lo + flat * (hi - lo), lo + (flat + width) * (hi - lo),
                                           lo, hi, level - levelmin, radius=radius).reshape(-1, 8)
        tree[level] = (octs, refined)
        octs = cells[refined]
        octs = octs[np.argsort(hilbert_keys(octs, level), kind="stable")]
    return tree


def _cells(octs: np.ndarray) -> np.ndarray:
    """(n, 8, 3) indices of the cells of `octs`, on their level's lattice, by ind."""
    return 2 * octs[:, None, :] + _OFFSETS


def _bound_keys(tree, levelmin: int, levelmax: int) -> np.ndarray:
    """bound_key(0:NCPU) float64 on the bit length levelmax + 1: the split between the
    two domains after the first level levelmin - 1 cell (in key order) by which domain 1
    holds half the octs of level >= levelmin."""
    weight = np.zeros(8 ** (levelmin - 1), np.int64)
    for level in range(levelmin, levelmax + 1):
        roots = tree[level][0] >> (level - levelmin)
        weight += np.bincount(hilbert_keys(roots, levelmin - 1), minlength=len(weight))
    cut = int(np.searchsorted(np.cumsum(weight), weight.sum() / 2)) + 1
    cut = min(max(cut, 1), len(weight) - 1)
    scale = 8 ** (levelmax + 2 - levelmin)
    return np.array([0, cut * scale, len(weight) * scale], np.float64)


def _owners(tree, bounds, levelmax: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """level -> (cpu of each oct (n,), cpu of each cell (n, 8)), 1-based."""
    def cpu_of(centres_fine):
        keys = hilbert_keys(centres_fine, levelmax + 1).astype(np.float64)
        return np.searchsorted(bounds, keys, side="right").astype(np.int64)

    owners = {}
    father = cpu_of(np.full((1, 3), 2 ** levelmax))  # the coarse cell's centre
    for level in range(1, levelmax + 1):
        octs, refined = tree[level]
        shift = levelmax + 1 - level
        cells = cpu_of((_cells(octs) << shift) + (1 << (shift - 1))).reshape(-1, 8)
        owners[level] = (father, cells)
        if level < levelmax:  # children in the order _tree made them
            child = _cells(octs)[refined]
            father = cells[refined][np.argsort(hilbert_keys(child, level), kind="stable")]
    return owners


def _find(table: np.ndarray, query: np.ndarray, level: int) -> np.ndarray:
    """Row of each point of `query` (m, 3) in `table` (n, 3), both on the 2**level
    lattice (periodic), or -1."""
    side = 1 << max(level, 0)

    def code(p):
        p = p % side
        return (p[:, 0] * side + p[:, 1]) * side + p[:, 2]

    keys = code(table)
    order = np.argsort(keys)
    want = code(query)
    at = np.minimum(np.searchsorted(keys[order], want), len(keys) - 1)
    return np.where(keys[order][at] == want, order[at], -1)


def _numbering(tree, cpus, cpu: int, levelmax: int) -> dict[int, np.ndarray]:
    """level -> grid number (1-based) of each oct in file `cpu`, 0 for octs it lacks:
    its domain's octs and their ancestors, numbered by level, then owner, then key."""
    held = {levelmax: cpus[levelmax][0] == cpu}
    for level in range(levelmax - 1, 0, -1):
        octs, child = tree[level][0], tree[level + 1][0]
        parents = _find(octs, child[held[level + 1]] >> 1, level - 1)
        held[level] = cpus[level][0] == cpu
        held[level][parents] = True
    numbers, next_number = {}, 1
    for level in range(1, levelmax + 1):
        numbers[level] = np.zeros(len(held[level]), np.int64)
        for owner in range(1, NCPU + 1):
            rows = np.flatnonzero(held[level] & (cpus[level][0] == owner))
            numbers[level][rows] = np.arange(next_number, next_number + len(rows))
            next_number += len(rows)
    return numbers


class _Records:
    """Fortran unformatted sequential records: int32 length, data, int32 length."""

    def __init__(self, f):
        self.f = f

    def ints(self, *values):
        self.raw(np.asarray(values if len(values) > 1 else values[0], "<i4"))

    def reals(self, *values):
        self.raw(np.asarray(values if len(values) > 1 else values[0], "<f8"))

    def raw(self, data: np.ndarray):
        data = np.ascontiguousarray(data).tobytes()
        marker = np.int32(len(data)).astype("<i4").tobytes()
        self.f.write(marker + data + marker)


def _groups(cpus, igrid, levelmax: int):
    """(level, owner, rows of the file's octs of that level and owner, by grid number)."""
    for level in range(1, levelmax + 1):
        for owner in range(1, NCPU + 1):
            rows = np.flatnonzero((igrid[level] > 0) & (cpus[level][0] == owner))
            yield level, owner, rows[np.argsort(igrid[level][rows])]


def _write_amr(f, tree, cpus, igrid, bounds, ngridmax: int, levelmax: int) -> None:
    rec = _Records(f)
    numbl = np.zeros((levelmax, NCPU), np.int64)
    head, tail = numbl.copy(), numbl.copy()
    for level, owner, rows in _groups(cpus, igrid, levelmax):
        numbl[level - 1, owner - 1] = len(rows)
        if len(rows):
            head[level - 1, owner - 1], tail[level - 1, owner - 1] = igrid[level][rows[[0, -1]]]
    ngrid = int(numbl.sum())
    rec.ints(NCPU), rec.ints(3), rec.ints(1, 1, 1), rec.ints(levelmax), rec.ints(ngridmax)
    rec.ints(0), rec.ints(ngrid), rec.reals(1.0), rec.ints(1, IOUT, IOUT + 1)
    rec.reals([0.0]), rec.reals([1.0]), rec.reals(0.0)  # tout, aout, t
    rec.reals(np.zeros(levelmax)), rec.reals(np.zeros(levelmax))  # dtold, dtnew
    rec.ints(0, 0), rec.reals(0.0, 0.0, 0.0)  # nstep nstep_coarse; einit mass_tot_0 rho_tot
    rec.reals(1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0)  # omega_m omega_l omega_k omega_b h0 aexp_ini boxlen_ini
    rec.reals(1.0, 0.0, 1.0, 0.0, 0.0), rec.reals(0.0)  # aexp hexp aexp_old epot_tot_*; mass_sph
    owned = np.array([[np.sum(cpus[lv][0] == c) for c in range(1, NCPU + 1)]
                      for lv in range(1, levelmax + 1)])
    numbtot = np.zeros((levelmax, 10), np.int64)  # numbtot(1:10, level): total, min, max, mean
    numbtot[:, :4] = np.stack([owned.sum(1), owned.min(1), owned.max(1), owned.sum(1) // NCPU], 1)
    rec.ints(head), rec.ints(tail), rec.ints(numbl), rec.ints(numbtot)
    rec.ints(ngrid + 1, ngridmax, ngridmax - ngrid, ngrid, ngridmax)  # free memory
    rec.raw(np.frombuffer(b"hilbert".ljust(128), "S1"))
    rec.reals(bounds)
    rec.ints([1]), rec.ints([1]), rec.ints(cpus[1][0])  # son, flag1, cpu_map of the coarse cell
    for level, _, rows in _groups(cpus, igrid, levelmax):
        if len(rows):
            _write_octs(rec, tree, cpus, igrid, level, rows, ngridmax, levelmax)


def _write_octs(rec: _Records, tree, cpus, igrid, level: int, rows, ngridmax: int,
                levelmax: int) -> None:
    """The records of the octs `rows` of `level`: index, next, prev, centre, father,
    neighbours, sons, cpu map, refinement map."""
    octs, refined = tree[level][0][rows], tree[level][1][rows]
    numbers = igrid[level][rows]
    rec.ints(numbers)
    rec.ints(np.append(numbers[1:], 0)), rec.ints(np.insert(numbers[:-1], 0, 0))
    for axis in range(3):
        rec.reals((octs[:, axis] + 0.5) * 2.0 ** (1 - level))
    for step in [None] + [s * e for e in np.eye(3, dtype=np.int64) for s in (-1, 1)]:
        if level == 1:  # the coarse cell is its own (periodic) neighbour
            rec.ints(np.full(len(rows), 1))
            continue
        cell = (octs if step is None else octs + step) % (1 << (level - 1))  # father or its neighbour
        found = _find(tree[level - 1][0], cell >> 1, level - 2)
        number = np.where(found >= 0, igrid[level - 1][found], 0)
        ind = (cell & 1) @ np.array([1, 2, 4])
        rec.ints(np.where(number > 0, NCOARSE + ind * ngridmax + number, 0))
    if level < levelmax:
        found = _find(tree[level + 1][0], _cells(octs).reshape(-1, 3), level)
        sons = np.where(found >= 0, igrid[level + 1][found], 0).reshape(-1, 8)
    else:
        sons = np.zeros((len(rows), 8), np.int64)
    for ind in range(8):
        rec.ints(sons[:, ind])
    for ind in range(8):
        rec.ints(cpus[level][1][rows, ind])
    for ind in range(8):
        rec.ints(refined[:, ind].astype(np.int64))


def _write_hydro(f, tree, cpus, igrid, lo, hi, levelmax: int) -> None:
    rec = _Records(f)
    rec.ints(NCPU), rec.ints(len(DESCRIPTOR_NAMES)), rec.ints(3), rec.ints(levelmax)
    rec.ints(0), rec.reals(GAMMA)
    for level, _, rows in _groups(cpus, igrid, levelmax):
        rec.ints(level), rec.ints(len(rows))
        if not len(rows):
            continue
        centres = (_cells(tree[level][0][rows]) + 0.5) * 2.0 ** -level
        for ind in range(8):
            world = lo + centres[:, ind] * (hi - lo)
            for name in analytic_amr.FIELDS:
                rec.reals(analytic_amr.value(name, world, lo, hi))


def _info_text(bounds, ngridmax: int, levelmin: int, levelmax: int) -> str:
    ints = dict(ncpu=NCPU, ndim=3, levelmin=levelmin, levelmax=levelmax, ngridmax=ngridmax,
                nstep_coarse=0)
    reals = dict(boxlen=1.0, time=0.0, aexp=1.0, H0=1.0, omega_m=1.0, omega_l=0.0, omega_k=0.0,
                 omega_b=0.0, unit_l=1.0, unit_d=1.0, unit_t=1.0)
    lines = [f"{k:<12}={v:11d}" for k, v in ints.items()] + [""]
    lines += [f"{k:<12}={v:23.15E}" for k, v in reals.items()] + [""]
    lines += ["ordering type=hilbert", "   DOMAIN   ind_min                 ind_max"]
    lines += [f"{c:8d} {bounds[c - 1]:23.15E} {bounds[c]:23.15E}" for c in range(1, NCPU + 1)]
    return "\n".join(lines) + "\n"


def _leaves(tree, lo, hi, levelmin: int, levelmax: int) -> analytic_amr.Leaves:
    lower, width = [], []
    for level in range(levelmin, levelmax + 1):
        octs, refined = tree[level]
        cells = _cells(octs)[~refined]
        lower.append(lo + cells * 2.0 ** -level * (hi - lo))
        width.append(np.full(len(cells), 2.0 ** -level * (hi[0] - lo[0])))
    return analytic_amr.Leaves(lower=np.concatenate(lower), width=np.concatenate(width),
                               lo=lo, hi=hi)
