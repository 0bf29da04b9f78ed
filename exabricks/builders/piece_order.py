"""Cells in the order of the top of their k-d partition, and the runs of that
order from which `brick --piece K/N` reads only its share (docs/design-structures.md,
"Builders by pieces": "Pieces of `brick` read only their cells").

`ingest` ends with `order_cells`: the partition of exabricks.builders.cell_tree
is split breadth first until there is about one node per RUN_CELLS cells (at
most MAX_RUNS), and the cells are stored in the order that leaves them in.
Every node of that top is then one run of consecutive cells, and meta[RUNS_KEY]
records where each run starts: a subtree still to split, or a brick the top
finished.  A node's split depends on its cells alone, so a piece that builds
the subtrees of a run of these runs from those cells only gets the bricks the
whole build gets there (`share_runs`).

The top is split with max brick width RUNS_WIDTH: its nodes are nodes of the
partition at every width up to that one (a node that is no brick at the widest
is none at a narrower one), and a build with a wider --max-brick-width reads
the whole file as before.  Nothing in the runs is trusted: a piece computes
each run's box and levels from its cells and checks the cells it reads, so
runs that a crafted file misplaces make other (valid) bricks, never a wrong
read.
"""

from __future__ import annotations

import numba
import numpy as np

from .. import schema
from ..util.constants import MAX_BRICK_WIDTH
from ..util.errors import ExabricksError
from ..formats.pieces import RUNS_KEY, Piece, task_range
from .cell_tree import ID, LEVEL, PACK_STEP, START, build_top, pack, take_columns

# A run per this many cells, at most MAX_RUNS (pieces are balanced over runs).
RUN_CELLS = 1 << 12
MAX_RUNS = 4096
# The widest --max-brick-width whose partition the runs are nodes of (the default).
RUNS_WIDTH = MAX_BRICK_WIDTH


def order_cells(cells: schema.Cells, *, run_cells: int = RUN_CELLS) -> schema.Cells:
    """`cells` in the order of the top of their partition, with meta[RUNS_KEY]:
    about one run per `run_cells` cells, at most MAX_RUNS.

    The cells must be checked (exabricks.builders.cells.validate_cells: no
    overlap).  Their lower_lattice and level arrays are permuted in place when
    they are this process's own (writable, not mapped): their pages are handed
    back as the partition's rows are made, and the rows' as they are copied
    back, so that ordering holds about the rows (20 bytes a cell) and the
    values, not the cells twice.  The values are gathered into a new array."""
    n = cells.n_cells
    target = int(min(MAX_RUNS, max(1, n // run_cells)))
    lower, level = cells.lower_lattice, cells.level
    own = all(a.flags.writeable and schema.mapping(a) is None for a in (lower, level))
    rec, root = pack(lower, level, 4 * numba.get_num_threads(), discard_input=own)
    brick_end = np.full(n, -1, np.int32)
    pending, s, _ = build_top(rec, root, np.int64(RUNS_WIDTH), brick_end, target)
    if s >= 0:  # validate_cells refuses overlapping cells before
        raise ExabricksError("cells overlap")
    starts = np.union1d(pending[:, START], np.flatnonzero(brick_end >= 0))
    del brick_end
    if not own:
        lower, level = np.empty_like(lower), np.empty_like(level)
    order = np.empty(n, np.int32)
    for a in range(0, n, PACK_STEP):
        rows = rec[a:a + PACK_STEP]
        lower[a:a + PACK_STEP] = rows[:, :3]
        level[a:a + PACK_STEP] = rows[:, LEVEL]
        order[a:a + PACK_STEP] = rows[:, ID]
        schema.discard(rows)
    del rec
    values = take_columns(np.ascontiguousarray(cells.values), order)
    meta = {**cells.meta, RUNS_KEY: {"max_brick_width": RUNS_WIDTH,
                                     "starts": [int(x) for x in starts]}}
    return cells.replace(lower_lattice=lower, level=level, values=values, meta=meta)


def reads_share(meta: dict, piece: Piece, max_brick_width: int) -> bool:
    """Whether `piece` of a build at `max_brick_width` reads only its share of a
    cells file with this meta (the runs themselves are checked by `share_runs`)."""
    info = meta.get(RUNS_KEY)
    return (not piece.whole and isinstance(info, dict)
            and type(info.get("max_brick_width")) is int
            and max_brick_width <= info["max_brick_width"])


def share_runs(cells: schema.Cells, piece: Piece, max_brick_width: int) -> np.ndarray | None:
    """The bounds, int64 (K + 1,), of the runs of `cells` that `piece` builds:
    its share is [bounds[0], bounds[-1]) (empty when K is 0).  None when
    `reads_share` says no (a whole build, no runs, or runs made for narrower
    bricks than `max_brick_width`): the piece then reads the whole file."""
    if not reads_share(cells.meta, piece, max_brick_width):
        return None
    n = cells.n_cells
    starts = cells.meta[RUNS_KEY].get("starts")
    if not (isinstance(starts, list) and 1 <= len(starts) <= n
            and all(type(x) is int and 0 <= x < n for x in starts)):
        raise ExabricksError(f"meta[{RUNS_KEY!r}] is not a list of starts of its {n} cells: "
                             "write the file again with exabricks ingest")
    bounds = np.array(starts + [n], np.int64)
    if bounds[0] != 0 or np.any(np.diff(bounds) <= 0):
        raise ExabricksError(f"meta[{RUNS_KEY!r}] starts do not increase from 0: "
                             "write the file again with exabricks ingest")
    t0, t1 = task_range(np.diff(bounds), piece)
    return bounds[t0:t1 + 1]
