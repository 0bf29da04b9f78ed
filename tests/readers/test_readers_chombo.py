"""The Chombo plotfile of helpers.chombo_output, checked as Chombo writes it: its levels
are properly nested (what yt and the other readers make of it: test_code_outputs.py)."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import chombo_output

h5py = pytest.importorskip("h5py")


@pytest.fixture(scope="module")
def plotfile(tmp_path_factory):
    return chombo_output.write(tmp_path_factory.mktemp("chombo"))


def test_levels_are_properly_nested(plotfile):
    """Each level's boxes, grown by one cell of the level below, lie in that level's
    boxes (or outside the domain): Chombo's proper nesting with a buffer of one."""
    path, _ = plotfile
    with h5py.File(path, "r") as f:
        boxes = [np.array(f[f"level_{lev}/boxes"][:].tolist()) for lev in range(f.attrs["num_levels"])]
        domain = [np.array(f[f"level_{lev}"].attrs["prob_domain"].tolist()) for lev in range(len(boxes))]
    for lev in range(1, len(boxes)):
        first, last = domain[lev - 1][:3], domain[lev - 1][3:]
        covered = np.zeros(last - first + 1, bool)                # the coarse level's cells
        for box in boxes[lev - 1] - np.concatenate([first, first]):
            covered[box[0]:box[3] + 1, box[1]:box[4] + 1, box[2]:box[5] + 1] = True
        for box in boxes[lev]:
            lo = np.maximum(box[:3] // 2 - 1, first) - first
            hi = np.minimum(box[3:] // 2 + 1, last) - first
            assert covered[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1].all()
