"""The FLASH4 plotfile of helpers.flash_output, checked as FLASH writes it: its block
tree is balanced (what yt and the other readers make of it: test_code_outputs.py)."""

from __future__ import annotations

import numpy as np

from helpers import flash_output

def test_block_tree_is_paramesh_balanced():
    """PARAMESH never puts leaves two levels apart side by side (faces, edges, corners)."""
    leaf = [b for b in flash_output.block_tree() if not b.children]
    lower = np.stack([b.lower for b in leaf])
    upper = lower + np.array([b.size for b in leaf])[:, None]
    level = np.array([b.level for b in leaf])
    touch = np.all((lower[:, None] <= upper[None]) & (lower[None] <= upper[:, None]), axis=2)
    assert np.abs(level[:, None] - level[None])[touch].max() <= 1
