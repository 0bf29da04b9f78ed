"""Native reader of AMReX (BoxLib) plotfiles: `Header`, `Level_N/Cell_H`, `Cell_D_*`.
Their text is parsed by exabricks.readers.amrex_headers; this module reads the
FABs' values into leaf cells.

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

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError
from . import _blocks, _checks
from .amrex_headers import FAB_LINE, decode_real_descriptor, read_header, read_level_header


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

    levels = [read_level_header(path, header["level_paths"][L], L, len(names))
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
    m = FAB_LINE.match(line.decode("ascii", errors="replace"))
    if not m or not line.endswith(b"\n"):
        raise ExabricksError(
            f"{name}: byte {offset}: no FAB header line for box {b} of {lev['where']} "
            f"(corrupt file or wrong offset)"
        )
    groups = m.groups()
    if groups[:4] not in rd_cache:
        rd_cache[groups[:4]] = decode_real_descriptor(groups[:4], f"{name}: byte {offset}")
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
