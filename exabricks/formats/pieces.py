"""Builders by pieces: `brick`, `regions` and `bvh` for one piece each, then
`join` (docs/design-structures.md, "Builders by pieces").

Every builder splits the top of its tree breadth first into subtrees, builds
them independently and puts their results together in subtree order, so that
its output does not depend on the thread count.  The same cut makes pieces: a
piece is a run of consecutive subtrees, balanced by their size (`task_range`).
Piece K of N computes the top (every piece computes the same one) and only its
own subtrees, and writes a file of the builder's kind holding its share, with
meta["piece"] saying which share it is.  exabricks.builders.join puts the
shares back together in piece order; the result equals the one-process build,
array for array.

A share is a valid file of its kind: a bricks share holds the bricks of one
run of cells (offsets from 0), a regions share the regions of one run of
subtrees (brick ids of the whole bricks file).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..util.errors import ExabricksError

# A share's meta["piece"]: index, count, and per kind where its share lies.
PIECE_KEY = "piece"
# A cells file's meta entry: the runs a brick piece reads (exabricks.builders.piece_order).
RUNS_KEY = "piece_runs"


@dataclass(frozen=True)
class Piece:
    """Share `index` of `count` (0-based), e.g. a SLURM array task's."""

    index: int = 0
    count: int = 1

    def __post_init__(self):
        if not 1 <= self.count <= 1 << 16:
            raise ExabricksError(f"the piece count must lie in 1..{1 << 16}, got {self.count}")
        if not 0 <= self.index < self.count:
            raise ExabricksError(f"piece {self.index} of {self.count} does not exist: "
                                 f"pieces are numbered 0..{self.count - 1}")

    @classmethod
    def parse(cls, text: str) -> "Piece":
        """"K/N": piece K of N."""
        m = re.fullmatch(r"\s*(\d{1,6})\s*/\s*(\d{1,6})\s*", text)
        if not m:
            raise ExabricksError(f"a piece is K/N (piece K of N, from 0), got {text!r}")
        return cls(int(m.group(1)), int(m.group(2)))

    @property
    def whole(self) -> bool:
        return self.count == 1


WHOLE = Piece()


def task_range(sizes, piece: Piece) -> tuple[int, int]:
    """The run of tasks [t0, t1) that `piece` builds: consecutive tasks, cut where
    the running total of `sizes` (int, one per task) passes each k/N of the total.
    Every piece computes the same cut; pieces may be empty."""
    sizes = np.asarray(sizes, np.int64)
    before = np.concatenate([[0], np.cumsum(sizes)[:-1]]) if sizes.size else sizes
    total = int(sizes.sum())

    def cut(k):
        if k >= piece.count:
            return sizes.size
        return int(np.searchsorted(before * piece.count, k * total, side="left")) if k else 0

    return cut(piece.index), cut(piece.index + 1)


def share_meta(piece: Piece, **where) -> dict:
    """meta entry of a share: {"piece": {"index", "count", **where}} (nothing when whole)."""
    return {} if piece.whole else {PIECE_KEY: {"index": piece.index, "count": piece.count, **where}}
