"""Native reader of Athena++ `.athdf` (HDF5) outputs on uniform Cartesian meshes.

An Athena++ mesh is an octree of equal-sized mesh blocks (MeshBlockSize cells each);
the file holds only the leaf blocks, each with its refinement level (`Levels`,
0 = root) and its position in blocks of that level (`LogicalLocations`).  Variables
live in datasets named by `DatasetNames`, each of shape (nvar, nblocks, nz, ny, nx)
(x fastest), their names in `VariableNames`, concatenated in dataset order.

Lattice: exabricks level 0 is the finest level present (max `Levels`); a block of
level L holds cells of exabricks level (max - L), its lower corner at
LogicalLocations * MeshBlockSize * 2**(max - L).  The origin is the domain's lower
corner, the spacing the root cell size / 2**max.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import schema
from ..util.constants import LATTICE_DTYPE, LEVEL_DTYPE, MAX_LEVEL, VALUE_DTYPE, WORLD_DTYPE
from ..util.errors import ExabricksError
from . import _checks

_ROOT_ATTRS = ("RootGridSize", "MeshBlockSize", "RootGridX1", "RootGridX2", "RootGridX3",
               "VariableNames", "DatasetNames", "NumVariables")


def read(path: Path, *, fields: Sequence[str] | None = None) -> schema.Cells:
    """Leaf cells of an Athena++ .athdf file, variables as float32.

    Returns Cells with lower_lattice int32 (N, 3) in finest-cell units, level int8 (N,),
    values float32 (F, N) in code units, origin_world = (x1min, x2min, x3min) and
    spacing_world = root cell size / 2**(finest level).
    """
    import h5py  # a core dependency; imported here so `exabricks --help` stays fast

    path = Path(path)
    if not path.is_file():
        raise ExabricksError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise ExabricksError(
            f"{path}: not a readable HDF5 file (truncated or another format: {e})"
        ) from e
    try:
        with f:
            return _read(f, path, fields)
    except ExabricksError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:  # damaged datasets inside a valid file
        raise ExabricksError(f"{path}: cannot read the Athena++ data ({e})") from e


def field_names(path: Path) -> list[str]:
    """The variable names of an .athdf file (its VariableNames attribute; no data is read)."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise ExabricksError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    try:
        with h5py.File(path, "r") as f:
            for name in _ROOT_ATTRS:
                _attr(f, path, name)
            return _text(_attr(f, path, "VariableNames"))
    except ExabricksError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise ExabricksError(
            f"{path}: not a readable HDF5 file (truncated or another format: {e})"
        ) from e


def _attr(f, path: Path, name: str) -> np.ndarray:
    if name not in f.attrs:
        raise ExabricksError(f"{path}: not an Athena++ .athdf file (no root attribute {name!r})")
    return np.atleast_1d(np.asarray(f.attrs[name]))


def _dataset(f, path: Path, name: str):
    if name not in f:
        raise ExabricksError(f"{path}: dataset {name!r} is missing")
    return f[name]


def _text(values: np.ndarray) -> list[str]:
    return [v.decode("ascii") if isinstance(v, bytes) else str(v) for v in values]


def _root_grid(f, path: Path):
    """The root grid's cells and mesh block's (int64 (3,) each) and its world box,
    checked: 3D, Cartesian, uniform and finite."""
    for name in _ROOT_ATTRS:
        _attr(f, path, name)
    coords = _text(_attr(f, path, "Coordinates")) if "Coordinates" in f.attrs else ["cartesian"]
    if coords[0] != "cartesian":
        raise ExabricksError(f"{path}: {coords[0]} coordinates; only Cartesian meshes are supported")
    root = _attr(f, path, "RootGridSize").astype(np.int64)
    block = _attr(f, path, "MeshBlockSize").astype(np.int64)
    if root.shape != (3,) or block.shape != (3,) or np.any(root < 2) or np.any(block < 2):
        raise ExabricksError(
            f"{path}: root grid {root.tolist()} / mesh blocks {block.tolist()}: exabricks reads "
            f"3D meshes only"
        )
    extents = np.array([_attr(f, path, f"RootGridX{a}").astype(np.float64) for a in (1, 2, 3)])
    if extents.shape != (3, 3):
        raise ExabricksError(f"{path}: RootGridX1..3 must be (min, max, ratio)")
    if np.any(extents[:, 2] != 1.0):
        a = int(np.flatnonzero(extents[:, 2] != 1.0)[0]) + 1
        raise ExabricksError(
            f"{path}: non-uniform mesh (x{a}rat = {extents[a - 1, 2]}); exabricks needs uniform "
            f"spacing (x1rat = x2rat = x3rat = 1)"
        )
    lower_world, upper_world = extents[:, 0], extents[:, 1]
    if not np.all(np.isfinite(extents[:, :2])):
        raise ExabricksError(
            f"{path}: RootGridX1..3 min and max must be finite (found "
            f"{extents[:, :2].tolist()})"
        )
    if not np.all(upper_world > lower_world):
        raise ExabricksError(f"{path}: RootGridX max must exceed min")
    return root, block, lower_world, upper_world


def _read(f, path: Path, fields: Sequence[str] | None) -> schema.Cells:
    root, block, lower_world, upper_world = _root_grid(f, path)
    names = _text(_attr(f, path, "VariableNames"))
    datasets = _text(_attr(f, path, "DatasetNames"))
    counts = _attr(f, path, "NumVariables").astype(np.int64)
    if counts.shape[0] != len(datasets) or int(counts.sum()) != len(names):
        raise ExabricksError(f"{path}: VariableNames, DatasetNames and NumVariables disagree")
    if fields is None:
        fields = names
    for name in fields:
        if name not in names:
            raise ExabricksError(f"{path}: no variable {name!r} (variables: {', '.join(names)})")
    if len(set(fields)) != len(fields):
        raise ExabricksError(f"{path}: field listed twice in {list(fields)}")

    # Every dataset's shape and stored size are checked before it is read, and before
    # anything of the size the attributes claim is allocated.
    file_size = path.stat().st_size
    levels_ds = _dataset(f, path, "Levels")
    loc_ds = _dataset(f, path, "LogicalLocations")
    nb = levels_ds.shape[0] if len(levels_ds.shape) == 1 else -1
    if nb < 0 or loc_ds.shape != (nb, 3):
        raise ExabricksError(
            f"{path}: Levels {levels_ds.shape} and LogicalLocations {loc_ds.shape} disagree"
        )
    if nb == 0:
        raise ExabricksError(f"{path}: no mesh blocks")
    _check_stored(levels_ds, path, file_size)
    _check_stored(loc_ds, path, file_size)
    first = np.concatenate([[0], np.cumsum(counts)])
    used = sorted({int(np.searchsorted(first, names.index(n), side="right") - 1) for n in fields})
    for d in used:
        ds = _dataset(f, path, datasets[d])
        want = (int(counts[d]), nb, *block[::-1].tolist())
        if ds.shape != want:
            raise ExabricksError(
                f"{path}: dataset {datasets[d]!r} has shape {ds.shape}, expected {want}"
            )
        _check_stored(ds, path, file_size)
    levels = np.asarray(levels_ds[()], dtype=np.int64)
    loc = np.asarray(loc_ds[()], dtype=np.int64)
    finest = int(levels.max())
    if levels.min() < 0 or finest > MAX_LEVEL - 1:
        raise ExabricksError(f"{path}: block levels must lie in 0..{MAX_LEVEL - 1}")
    if np.any(root % block):
        raise ExabricksError(f"{path}: root grid {root.tolist()} is not a multiple of the mesh block")
    if int(root.max()) << finest >= 2**31:
        raise ExabricksError(f"{path}: the finest grid exceeds the int32 lattice")
    blocks_per_axis = (root // block)[None, :] << levels[:, None]
    if np.any(loc < 0) or np.any(loc >= blocks_per_axis):
        b = int(np.flatnonzero(np.any((loc < 0) | (loc >= blocks_per_axis), axis=1))[0])
        raise ExabricksError(
            f"{path}: block {b} at {loc[b].tolist()} lies outside its level-{levels[b]} grid"
        )
    _check_leaves(levels, loc, path)

    with np.errstate(all="ignore"):
        spacing = (upper_world - lower_world) / (root << finest)
    _checks.check_frame(path, lower_world, spacing, root << finest)
    _check_faces(f, path, levels, loc, block, finest, lower_world, spacing, file_size)

    # Built in int32 directly (checked above to fit): large files have 10^8+ cells.
    width = (np.int64(1) << (finest - levels)).astype(LATTICE_DTYPE)       # (B,)
    corner = (loc * block[None, :] * width[:, None]).astype(LATTICE_DTYPE)  # (B, 3)
    cz, cy, cx = np.meshgrid(*(np.arange(n, dtype=LATTICE_DTYPE) for n in block[::-1]),
                             indexing="ij")
    cell = np.stack([cx.ravel(), cy.ravel(), cz.ravel()], axis=1)           # (V, 3), x fastest
    lattice = (corner[:, None, :] + cell[None, :, :] * width[:, None, None]).reshape(-1, 3)

    nv = int(np.prod(block))
    values = np.empty((len(fields), nb * nv), dtype=VALUE_DTYPE)
    for i, name in enumerate(fields):
        v = names.index(name)
        d = int(np.searchsorted(first, v, side="right") - 1)
        with np.errstate(over="ignore", invalid="ignore"):  # float64 beyond float32: inf
            values[i] = f[datasets[d]][v - first[d]].reshape(-1)

    return schema.Cells(
        fields=tuple(fields),
        origin_world=lower_world.astype(WORLD_DTYPE),
        spacing_world=spacing.astype(WORLD_DTYPE),
        meta={"source": {"format": "athena++", "time": float(_attr(f, path, "Time")[0])
                         if "Time" in f.attrs else None, "max_level": finest}},
        lower_lattice=lattice,
        level=np.repeat((finest - levels).astype(LEVEL_DTYPE), nv),
        values=values,
    )


def _check_leaves(levels: np.ndarray, loc: np.ndarray, path: Path) -> None:
    """Raise unless the blocks are disjoint: no duplicate and no block inside another.

    Blocks sit on an octree of blocks, so block (L, loc) overlaps a coarser block
    (l, loc') exactly when loc >> (L - l) == loc'; looking every ancestor up in the
    sorted block keys costs O(B log B * levels).
    """
    finest = int(levels.max())
    bits = max(int(loc.max()).bit_length(), 1)
    if 3 * bits + 5 > 63:
        raise ExabricksError(f"{path}: block coordinates too large")

    def key(lv, lc):
        return (((lv << bits | lc[:, 2]) << bits | lc[:, 1]) << bits) | lc[:, 0]

    keys = key(levels, loc)
    order = np.argsort(keys)
    sorted_keys = keys[order]
    dup = np.flatnonzero(sorted_keys[1:] == sorted_keys[:-1])
    if dup.size:
        b = int(order[dup[0]])
        raise ExabricksError(
            f"{path}: mesh block {b} (level {levels[b]}, {loc[b].tolist()}) appears twice"
        )
    for up in range(1, finest + 1):
        fine = np.flatnonzero(levels >= up)
        ancestors = key(levels[fine] - up, loc[fine] >> up)
        hit = np.searchsorted(sorted_keys, ancestors)
        hit = np.minimum(hit, sorted_keys.shape[0] - 1)
        found = sorted_keys[hit] == ancestors
        if np.any(found):
            i = int(np.flatnonzero(found)[0])
            b, a = int(fine[i]), int(order[hit[i]])
            raise ExabricksError(
                f"{path}: mesh blocks overlap: block {b} (level {levels[b]}, {loc[b].tolist()}) "
                f"lies inside block {a} (level {levels[a]}, {loc[a].tolist()})"
            )


def _check_stored(ds, path: Path, file_size: int) -> None:
    """Raise unless the bytes that dataset `ds` claims (shape x item size) are in the file.

    Unfiltered datasets must fit in the file and be fully allocated (an HDF5 dataset
    can declare any shape and store nothing); filtered (compressed) ones must store
    something.  Only shapes and storage sizes are asked, nothing is read.
    """
    name = ds.name.lstrip("/")
    claimed = math.prod(ds.shape) * ds.dtype.itemsize
    stored = ds.id.get_storage_size()
    what = f"dataset {name!r} of shape {ds.shape}"
    if ds.id.get_create_plist().get_nfilters() == 0:
        _checks.claim(path, what, claimed, "the file", file_size)
        if stored < claimed:
            raise ExabricksError(
                f"{path}: {what} claims {claimed} bytes but only {stored} are stored "
                f"(unwritten or truncated)"
            )
    elif claimed and not stored:
        raise ExabricksError(f"{path}: {what} claims {claimed} bytes but none are stored")


def _check_faces(f, path, levels, loc, block, finest, lower_world, spacing, file_size) -> None:
    """Check x1f/x2f/x3f against the lattice, so a mislabelled block cannot slip through."""
    width = (1 << (finest - levels)).astype(np.float64)
    for a, name in enumerate(("x1f", "x2f", "x3f")):
        ds = _dataset(f, path, name)
        if ds.shape != (levels.shape[0], block[a] + 1):
            raise ExabricksError(f"{path}: dataset {name!r} has shape {ds.shape}")
        _check_stored(ds, path, file_size)
        faces = np.asarray(ds[()], dtype=np.float64)
        with np.errstate(all="ignore"):
            _check_face_values(path, name, faces, a, levels, loc, block, width, lower_world,
                               spacing)


def _check_face_values(path, name, faces, a, levels, loc, block, width, lower_world, spacing):
    """Raise unless faces (B, n + 1) of axis `a` sit where the lattice puts them (NaN never does)."""
    expect = lower_world[a] + spacing[a] * width[:, None] * (
        loc[:, a:a + 1] * block[a] + np.arange(block[a] + 1)[None, :]
    )
    # The faces are stored in float32: allow its rounding, relative to the cell width.
    tol = 1e-3 * spacing[a] * width[:, None] + 4 * np.finfo(np.float32).eps * np.abs(expect)
    bad = ~(np.abs(faces - expect) <= tol)
    if np.any(bad):
        b = int(np.flatnonzero(bad.any(axis=1))[0])
        raise ExabricksError(
            f"{path}: block {b}: {name} faces do not match a uniform mesh at its level and "
            f"logical location (non-uniform spacing is not supported)"
        )
