"""Builds that belong together (exabricks/schema.py, `content_sha256` and
`built_from`; issue 32): every file records the content digest of what it was
built from, and render, probe and join refuse a file of another build in one
line by comparing stored digests; inputs are hashed from the bytes read."""

from __future__ import annotations

import hashlib
import os
import shutil

import numpy as np
import pytest

from exabricks import schema
from exabricks.readers import read
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.builders.regions import build_regions

from helpers import GERRIS, assert_one_error_line
from helpers.hostile import run


def _save_built(path, obj, upstream, upstream_path):
    """Save `obj` as the stage commands do: meta with inputs and built_from."""
    obj = obj.replace(meta=schema.make_meta(inputs=[upstream_path], upstream=upstream,
                                            statistics=obj.meta.get("statistics", {})))
    schema.save(path, obj)
    return schema.load(path)


def _build(d, cells_path, max_brick_width):
    """bricks, regions and bvh files built from `cells_path` into folder `d`."""
    d.mkdir(exist_ok=True)
    cells = schema.load(cells_path, "cells", digest=True)
    bricks = _save_built(d / "bricks.npz", build_bricks(cells, max_brick_width=max_brick_width),
                         cells, cells_path)
    regions = _save_built(d / "regions.npz", build_regions(bricks), bricks, d / "bricks.npz")
    _save_built(d / "bvh.npz", build_bvh(regions), regions, d / "regions.npz")
    return [d / "bricks.npz", d / "regions.npz", d / "bvh.npz"]


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    d = tmp_path_factory.mktemp("chain")
    schema.save(d / "cells.npz", read(GERRIS, fields=["T"]))
    return d / "cells.npz", _build(d / "a", d / "cells.npz", 32), _build(d / "b", d / "cells.npz", 8)


def test_every_file_records_what_it_was_built_from(builds):
    cells, (bricks, regions, bvh), _ = builds
    for path, source in ((bricks, cells), (regions, bricks), (bvh, regions)):
        meta, upstream = schema.peek(path)[2], schema.peek(source)[2]
        assert meta["built_from"]["content_sha256"] == upstream["content_sha256"]
        assert meta["inputs"][0]["sha256"] == hashlib.sha256(source.read_bytes()).hexdigest()


def test_the_content_digest_is_of_what_the_file_holds(builds):
    _, (bricks, _, _), _ = builds
    loaded = schema.load(bricks)
    assert loaded.meta["content_sha256"] == schema.content_sha256(loaded)


@pytest.mark.parametrize("mix, wrong", [((0, 1, 1), 1), ((1, 1, 0), 2), ((0, 0, 1), 2)])
def test_render_and_probe_refuse_another_builds_files(mix, wrong, builds, tmp_path):
    _, a, b = builds
    trio = [(a, b)[which][k] for k, which in enumerate(mix)]
    proc = run("render", *trio, "-o", tmp_path / "x.png", "--size", "16", "16")
    assert_one_error_line(proc, str(trio[wrong]), "was built from another")
    assert not (tmp_path / "x.png").exists()
    points = tmp_path / "p.npy"
    np.save(points, np.zeros((2, 3)))
    assert_one_error_line(run("probe", *trio, "--points", points, "-o", tmp_path / "v.npy"),
                          "was built from another")
    assert_one_error_line(run("render", *trio, "-o", tmp_path / "x.png", "--memory-budget", "64M"),
                          "was built from another")


def test_join_refuses_shares_of_two_cells_files(builds, tmp_path):
    """The cells file is replaced by a rename between the two shares' builds."""
    cells, _, _ = builds
    path = tmp_path / "cells.npz"
    shutil.copy(cells, path)
    loaded = schema.load(cells)
    values = loaded.values.copy()
    values[0, 0] += 1.0
    for k in range(2):
        proc = run("brick", path, "--piece", f"{k}/2", "-o", tmp_path / f"p{k}.npz")
        assert proc.returncode == 0, proc.stderr
        schema.save(tmp_path / "other.npz", loaded.replace(values=values))
        os.replace(tmp_path / "other.npz", path)
    proc = run("join", tmp_path / "p0.npz", tmp_path / "p1.npz", "-o", tmp_path / "j.npz")
    assert_one_error_line(proc, "p1.npz", "other inputs")
    assert not (tmp_path / "j.npz").exists()


def test_an_input_is_hashed_from_the_bytes_read_not_the_path_again(builds, tmp_path):
    cells, _, _ = builds
    path = tmp_path / "cells.npz"
    shutil.copy(cells, path)
    original = hashlib.sha256(path.read_bytes()).hexdigest()
    loaded = schema.load(path, "cells", mapped=True, checked=True, digest=True)
    replacement = tmp_path / "new.npz"
    schema.save(replacement, loaded.replace(values=loaded.values + 1))
    os.replace(replacement, path)  # a rename while the command runs
    assert schema.make_meta(inputs=[path])["inputs"][0]["sha256"] == original
    assert float(loaded.values[0, 0]) == float(schema.load(cells).values[0, 0])
