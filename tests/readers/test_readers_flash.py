"""A FLASH4 plotfile written in FLASH's own HDF5 layout (helpers.flash_output), checked
as FLASH writes it: the leaves tile the domain, the block tree is balanced (what yt
and the other readers make of it: test_code_outputs.py)."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import analytic_amr, flash_output

pytest.importorskip("h5py")


@pytest.fixture(scope="module")
def plotfile(tmp_path_factory):
    return flash_output.write(tmp_path_factory.mktemp("flash"))


def test_written_leaves_tile_the_domain(plotfile):
    _, leaves = plotfile
    analytic_amr.assert_leaves_tile(leaves)
    assert len(np.unique(leaves.width)) >= 3


def test_block_tree_is_paramesh_balanced():
    """PARAMESH never puts leaves two levels apart side by side (faces, edges, corners)."""
    leaf = [b for b in flash_output.block_tree() if not b.children]
    lower = np.stack([b.lower for b in leaf])
    upper = lower + np.array([b.size for b in leaf])[:, None]
    level = np.array([b.level for b in leaf])
    touch = np.all((lower[:, None] <= upper[None]) & (lower[None] <= upper[:, None]), axis=2)
    assert np.abs(level[:, None] - level[None])[touch].max() <= 1
