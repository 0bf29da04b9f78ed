"""The schema module: round trips, atomic writes, and refusals with clear messages."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from exabricks import schema
from exabricks.util.errors import ExabricksError

from helpers import assert_one_error_line, two_level_cells


def test_round_trip(tmp_path):
    cells = two_level_cells()
    path = tmp_path / "cells.npz"
    schema.save(path, cells)
    back = schema.load(path, "cells")
    assert back.fields == ("a", "b")
    for name in cells.SPECS:
        np.testing.assert_array_equal(getattr(back, name), getattr(cells, name))
    assert back.meta["software"].startswith("exabricks")
    assert [p.name for p in tmp_path.iterdir()] == ["cells.npz"]  # no temporary left
    with np.load(path, allow_pickle=False) as z:  # plain arrays only
        assert str(z["format"]) == "exabricks" and str(z["kind"]) == "cells"


def test_summary_counts_and_bounds():
    s = schema.summary(two_level_cells())
    assert s["counts"] == {"cells": 15, "cells_per_level": {"0": 8, "1": 7}}
    assert s["world_bounds"] == {"lower": [1.0, 2.0, 3.0], "upper": [3.0, 4.0, 5.0]}
    assert s["fields"][0] == {"name": "a", "min": 0.0, "max": 14.0}


def _rewrite(src, dst, drop=(), **replace):
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    arrays.update(replace)
    with open(dst, "wb") as f:
        np.savez(f, **arrays)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(kind=np.array("bricks")), "expected a cells file, found a bricks file"),
        (dict(version=np.array(99, np.int32)), "version 99 is newer"),
        (dict(drop=("level",)), "array 'level' is missing"),
        (dict(level=np.zeros(15, np.float64)), "dtype float64, expected int8"),
        (dict(format=np.array("other")), "format is 'other'"),
        (dict(drop=("meta",)), "not an exabricks file"),
        (dict(kind=np.array("pictures")), "unknown kind 'pictures'"),
        (dict(values=np.zeros((2, 14), np.float32)), "inconsistent"),
        (dict(lower_lattice=np.ones((15, 3), np.int32)), "not aligned"),
    ],
)
def test_refusals(tmp_path, change, message):
    good = tmp_path / "good.npz"
    schema.save(good, two_level_cells())
    bad = tmp_path / "bad.npz"
    _rewrite(good, bad, **change)
    with pytest.raises(ExabricksError, match=message.replace("(", r"\(")) as e:
        schema.load(bad, "cells")
    assert str(bad) in str(e.value)


def test_truncated_and_missing(tmp_path, cli):
    good = tmp_path / "good.npz"
    schema.save(good, two_level_cells())
    bad = tmp_path / "trunc.npz"
    bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    assert_one_error_line(cli("info", bad), str(bad), "not a readable exabricks")
    assert_one_error_line(cli("info", tmp_path / "nope.npz"), "no such file")


def test_write_refuses_invalid_and_leaves_nothing(tmp_path):
    cells = two_level_cells().replace(level=np.full(15, -1, np.int8))
    with pytest.raises(ExabricksError, match="has level -1, outside"):
        schema.save(tmp_path / "x.npz", cells)
    assert list(tmp_path.iterdir()) == []


def test_info_cli_json(tmp_path, cli):
    path = tmp_path / "cells.npz"
    schema.save(path, two_level_cells())
    out = json.loads(cli("info", path, "--json", check=0).stdout)
    assert out["kind"] == "cells" and out["counts"]["cells"] == 15
    text = cli("info", path, check=0).stdout
    assert "cells per level: level 0: 8, level 1: 7" in text


def test_files_of_other_kinds_are_named_as_such(tmp_path, cli):
    png = tmp_path / "image.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    assert_one_error_line(cli("info", png), str(png), "not a zip archive")
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    assert_one_error_line(cli("info", empty), str(empty), "empty file")


def test_large_stored_members_are_read_directly_and_crc_checked(tmp_path):
    """Members of at least NpzArchive.DIRECT_BYTES are read with one readinto: the
    values come back exact, and a flipped byte or a cut file is refused by name."""
    n = schema.NpzArchive.DIRECT_BYTES // 4 + 1000
    rng = np.random.default_rng(0)
    cells = schema.Cells(
        fields=("a",), origin_world=np.zeros(3), spacing_world=np.ones(3),
        lower_lattice=np.stack([np.arange(n), np.zeros(n), np.zeros(n)], 1).astype(np.int32),
        level=np.zeros(n, np.int8), values=rng.random((1, n), np.float32))
    path = tmp_path / "big.npz"
    schema.save(path, cells)
    back = schema.load(path, "cells")
    np.testing.assert_array_equal(back.values, cells.values)
    np.testing.assert_array_equal(back.lower_lattice, cells.lower_lattice)
    raw = bytearray(path.read_bytes())
    at = raw.find(cells.values[0, n // 2 : n // 2 + 4].tobytes())
    assert at > 0
    raw[at] ^= 0xFF
    bad = tmp_path / "flipped.npz"
    bad.write_bytes(bytes(raw))
    with pytest.raises(ExabricksError, match=r"flipped.npz: array 'values' .*CRC"):
        schema.load(bad, "cells")


def test_discard_hands_back_the_pages_of_a_part(tmp_path):
    """schema.discard: an in-memory array's whole pages inside the part read as zeros
    and leave the resident set (what ordering cells in place relies on); the bytes
    around the part are kept; a mapped array's part is handed back and read again."""
    def resident():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")

    a = np.arange(1 << 25, dtype=np.int32)  # 128 MiB, written
    before = resident()
    schema.discard(a[5:(1 << 25) - 5])
    assert before - resident() > 100 << 20
    assert a[:5].tolist() == [0, 1, 2, 3, 4] and a[-5:].tolist() == list(range((1 << 25) - 5, 1 << 25))
    assert not a[4096:(1 << 25) - 4096].any()
    np.save(tmp_path / "x.npy", np.arange(1000, dtype=np.int32))
    m = np.load(tmp_path / "x.npy", mmap_mode="r")
    schema.discard(m[100:900])
    assert m.tolist() == list(range(1000))
