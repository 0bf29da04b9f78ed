"""Builders by pieces (issue 12, deliverable 2): `brick`, `regions` and `bvh`
with --piece K/N, then `join`, give exactly the one-process build, on the real
datasets and on the thin-shell octree layout; every share is a valid file of
its kind; bad sets of pieces are refused with one error line."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from exabricks import schema
from exabricks.util.errors import ExabricksError
from exabricks.readers import read
from exabricks.builders.bricks import build_bricks
from exabricks.builders.bvh import build_bvh
from exabricks.builders.join import join_bricks, join_bvh, join_regions
from exabricks.builders.piece_order import MAX_RUNS, RUN_CELLS, RUNS_KEY, order_cells
from exabricks.formats.pieces import Piece, task_range
from exabricks.builders.regions import build_regions

from helpers import AMREX, ATHENA, ENZO, GERRIS, assert_one_error_line

STAGES = ((build_bricks, join_bricks), (build_regions, join_regions), (build_bvh, join_bvh))


@functools.lru_cache(maxsize=None)
def dataset_cells(name):
    if name == "shell":  # 1.1 M cells, 131 K bricks: every builder splits into 64 subtrees
        from benchmarks.make_big import thin_shell_cells

        return thin_shell_cells(256)
    return read({"amrex": AMREX, "athena": ATHENA, "enzo": ENZO, "gerris": GERRIS}[name])


def assert_same(a, b, what):
    arrays = b.arrays()
    for k, v in a.arrays().items():
        assert v.dtype == arrays[k].dtype and np.array_equal(v, arrays[k], equal_nan=True), \
            (what, k)
    assert a.meta["statistics"] == b.meta["statistics"], what


@pytest.mark.parametrize("name,counts", [("shell", (2, 3, 8)), ("gerris", (2, 5)),
                                         ("amrex", (3,)), ("athena", (2,)), ("enzo", (4,))])
@pytest.mark.slow
def test_joined_pieces_equal_the_whole_build(name, counts):
    """Each stage's N shares, joined in piece order, equal the whole build array for
    array; each share alone is a valid file of its kind."""
    whole = dataset_cells(name)
    for build, join in STAGES:
        built = build(whole)
        for n in counts:
            shares = [build(whole, piece=Piece(k, n)) for k in range(n)]
            for k, s in enumerate(shares):
                schema.validate(s, f"{name} share {k}/{n}")
                assert s.meta["piece"]["index"] == k and s.meta["piece"]["count"] == n
            joined = join([(f"{k}.npz", s) for k, s in enumerate(shares)])
            assert_same(built, joined, (name, build.__name__, n))
            if name == "shell":  # a real split: every share builds part of the whole
                own = [s.meta["piece"].get("own", [0, 1]) for s in shares]
                assert all(o[1] > o[0] for o in own)
                assert all(s.n_bricks if build is build_bricks else
                           s.n_regions if build is build_regions else 1 for s in shares)
        whole = built


def ordered(name):
    """The dataset's cells as `exabricks ingest` writes them (exabricks.builders.piece_order),
    from copies: ordering permutes the cells' own arrays in place."""
    cells = dataset_cells(name)
    return order_cells(cells.replace(lower_lattice=cells.lower_lattice.copy(),
                                     level=cells.level.copy()))


@pytest.mark.parametrize("name,counts", [("shell", (3, 8)), ("gerris", (2, 40)),
                                         pytest.param("amrex", (3,), marks=pytest.mark.slow),
                                         pytest.param("athena", (2,), marks=pytest.mark.slow),
                                         pytest.param("enzo", (4,), marks=pytest.mark.slow)])
def test_pieces_of_ordered_cells_read_only_their_share(name, counts):
    """Cells in piece order hold the same bricks, and N pieces that each read only
    their run of cells, joined, equal the whole build of the cells as read (40 pieces
    of gerris' 16 runs: some pieces are empty)."""
    cells, cells_ordered = dataset_cells(name), ordered(name)
    whole = build_bricks(cells)
    runs = cells_ordered.meta[RUNS_KEY]["starts"]
    assert runs[0] == 0 and len(runs) <= MAX_RUNS and cells_ordered.n_cells == cells.n_cells
    assert_same(whole, build_bricks(cells_ordered), (name, "ordered"))
    for n in counts:
        shares = [build_bricks(cells_ordered, piece=Piece(k, n)) for k in range(n)]
        cut = [s.meta["piece"]["cells"] for s in shares]
        assert all(a in runs + [cells.n_cells] and b in runs + [cells.n_cells] for a, b in cut)
        assert_same(whole, join_bricks([(f"{k}.npz", s) for k, s in enumerate(shares)]), (name, n))
    if name == "shell":  # a real split: the runs cut the cells about evenly
        assert len(runs) >= cells.n_cells // RUN_CELLS
        sizes = [b - a for a, b in cut]
        assert max(sizes) < 1.3 * cells.n_cells / len(cut)


def test_ordering_a_copy_equals_ordering_in_place():
    """Read-only (mapped) cells are ordered into new arrays, the same as in place."""
    cells = dataset_cells("amrex")
    lower, level = cells.lower_lattice.copy(), cells.level.copy()
    lower.flags.writeable = level.flags.writeable = False
    copy = order_cells(cells.replace(lower_lattice=lower, level=level))
    assert_same(ordered("amrex").replace(meta={"statistics": 0}), copy.replace(meta={"statistics": 0}),
                "copy")
    assert np.array_equal(lower, cells.lower_lattice)


def test_task_ranges_cover_every_task_once():
    for sizes in ([], [5], [0, 0, 3], [1] * 64, list(range(64)), [100, 1, 1, 1]):
        for n in (1, 2, 3, 7, 64, 100):
            runs = [task_range(sizes, Piece(k, n)) for k in range(n)]
            assert runs[0][0] == 0 and runs[-1][1] == len(sizes)
            assert all(a[1] == b[0] for a, b in zip(runs, runs[1:]))
            assert all(t0 <= t1 for t0, t1 in runs)


@pytest.mark.parametrize("text,message", [("3/3", "does not exist"), ("x", "K/N"),
                                          ("0/0", "count"), ("-1/2", "K/N"), ("1/99999999", "K/N")])
def test_piece_parse_refuses_nonsense(text, message):
    with pytest.raises(ExabricksError, match=message):
        Piece.parse(text)


@pytest.fixture(scope="module")
def enzo_files(tmp_path_factory):
    """The enzo dataset's stages, whole and in pieces, through the commands."""
    from helpers import run_cli

    d = tmp_path_factory.mktemp("pieces")
    run_cli("ingest", ENZO, "-o", d / "cells.npz", check=0)
    for stage, src, dst, n in (("brick", "cells", "bricks", 3), ("regions", "bricks", "regions", 2),
                               ("bvh", "regions", "bvh", 4)):
        run_cli(stage, d / f"{src}.npz", "-o", d / f"{dst}.npz", check=0)
        for k in range(n):
            run_cli(stage, d / f"{src}.npz", "--piece", f"{k}/{n}", "-o", d / f"{dst}.{k}.npz",
                    check=0)
    return d


@pytest.mark.parametrize("kind,n", [("bricks", 3), ("regions", 2), ("bvh", 4)])
@pytest.mark.slow
def test_join_command_equals_the_whole_command(enzo_files, tmp_path, cli, kind, n):
    d = enzo_files
    parts = [d / f"{kind}.{k}.npz" for k in reversed(range(n))]  # any order
    cli("join", *parts, "-o", tmp_path / "joined.npz", check=0)
    joined = schema.load(tmp_path / "joined.npz", kind)
    assert_same(schema.load(d / f"{kind}.npz", kind), joined, kind)
    part = schema.load(parts[0], kind)
    assert joined.meta["source_inputs"] == part.meta["inputs"]
    assert joined.meta["built_from"] == part.meta["built_from"]
    # The same content as the one process's build, so files built from either chain.
    assert joined.meta["content_sha256"] == schema.load(d / f"{kind}.npz", kind).meta["content_sha256"]
    if kind == "regions":
        assert joined.meta["consistency"]["n_regions"] == joined.n_regions


@pytest.mark.slow
def test_joined_files_render_like_the_whole_ones(enzo_files, tmp_path, cli):
    d = enzo_files
    for kind, n in (("bricks", 3), ("regions", 2), ("bvh", 4)):
        cli("join", *[d / f"{kind}.{k}.npz" for k in range(n)], "-o", tmp_path / f"{kind}.npz",
            check=0)
    for where, out in ((d, tmp_path / "whole.exr"), (tmp_path, tmp_path / "joined.exr")):
        cli("render", where / "bricks.npz", where / "regions.npz", where / "bvh.npz",
            "--size", "48", "32", "-o", out, check=0)
    from exabricks.film.image_io import read_image

    np.testing.assert_array_equal(read_image(tmp_path / "whole.exr")[0],
                                  read_image(tmp_path / "joined.exr")[0])


def _rewrite_piece(src, dst, **changes):
    obj = schema.load(src)
    schema.save(dst, obj.replace(meta={**obj.meta, "piece": {**obj.meta["piece"], **changes}}))


@pytest.mark.parametrize("case", ["missing", "twice", "kinds", "counts", "whole", "cells", "other-build",
                                  "cell-run", "cell-run-text", "index", "bvh-blocks", "bvh-subtrees",
                                  "output-is-input"])
def test_join_refuses_a_bad_set_of_pieces(enzo_files, tmp_path, cli, case):
    d = enzo_files
    b = [d / f"bricks.{k}.npz" for k in range(3)]
    v = [d / f"bvh.{k}.npz" for k in range(4)]
    out = tmp_path / "out.npz"
    if case == "missing":
        args, needles = b[:2], ["piece 2 of 3 is missing"]
    elif case == "twice":
        args, needles = [b[0], b[1], b[1], b[2]], ["piece 1 is also given"]
    elif case == "kinds":
        args, needles = [d / "regions.0.npz", d / "regions.1.npz", d / "bvh.0.npz"], [
            "bvh.0.npz", "expected a regions file"]
    elif case == "counts":
        from helpers import run_cli

        run_cli("brick", d / "cells.npz", "--piece", "1/2", "-o", tmp_path / "half.npz", check=0)
        args, needles = [b[0], tmp_path / "half.npz", b[2]], ["half.npz", "is piece 1 of 2",
                                                             "one of 3"]
    elif case == "whole":
        args, needles = [d / "bricks.npz"], ["not a piece of a build", "bricks.npz"]
    elif case == "cells":
        args, needles = [d / "cells.npz"], ["holds cells"]
    elif case == "other-build":
        from helpers import run_cli

        run_cli("brick", d / "cells.npz", "--max-brick-width", "8", "--piece", "1/3", "-o",
                tmp_path / "narrow.npz", check=0)
        args, needles = [b[0], tmp_path / "narrow.npz", b[2]], ["other inputs or with other"]
    elif case == "cell-run":
        _rewrite_piece(b[1], tmp_path / "b1.npz", cells=[0, 10])
        args, needles = [b[0], tmp_path / "b1.npz", b[2]], ["b1.npz", "holds cells [0, 10]"]
    elif case == "cell-run-text":
        _rewrite_piece(b[1], tmp_path / "b1.npz", cells=["a", "b"])
        args, needles = [b[0], tmp_path / "b1.npz", b[2]], ["b1.npz", "holds cells"]
    elif case == "index":
        _rewrite_piece(b[1], tmp_path / "b1.npz", index=7)
        args, needles = [*b, tmp_path / "b1.npz"], ["b1.npz", "piece 7 of 3 does not exist"]
    elif case == "bvh-blocks":
        info = schema.load(v[0]).meta["piece"]
        _rewrite_piece(v[0], tmp_path / "v0.npz", blocks=[10 ** 9] * len(info["blocks"]))
        args, needles = [tmp_path / "v0.npz", *v[1:]], ["v0.npz", "is not where its meta says"]
    elif case == "bvh-subtrees":
        _rewrite_piece(v[0], tmp_path / "v0.npz", subtrees=[[10 ** 6, 0, 1]])
        args, needles = [tmp_path / "v0.npz", *v[1:]], ["v0.npz", "does not describe"]
    else:
        args, needles, out = b, ["input"], b[0]
    before = {p: p.read_bytes() for p in args if p.exists()}
    proc = cli("join", *args, "-o", out)
    assert_one_error_line(proc, *needles)
    assert case == "output-is-input" or not out.exists()
    assert all(p.read_bytes() == data for p, data in before.items())


def test_piece_option_refuses_nonsense(enzo_files, tmp_path, cli):
    proc = cli("brick", enzo_files / "cells.npz", "--piece", "3/3", "-o", tmp_path / "b.npz")
    assert proc.returncode == 2 and "does not exist" in proc.stderr
    assert not (tmp_path / "b.npz").exists()


def test_share_meta_is_json(enzo_files):
    """What a job script reads back: the piece of every share, as plain JSON."""
    for kind, n in (("bricks", 3), ("regions", 2), ("bvh", 4)):
        for k in range(n):
            _, _, meta = schema.peek(enzo_files / f"{kind}.{k}.npz")
            assert json.loads(json.dumps(meta["piece"]))["index"] == k


def rewrite(src, dst, **arrays):
    """A copy of the .npz `src` at `dst` with some members replaced, unchecked."""
    with np.load(src, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    np.savez(dst, **{**members, **arrays})


def test_info_counts_the_runs(enzo_files, cli):
    runs = schema.peek(enzo_files / "cells.npz")[2][RUNS_KEY]["starts"]
    assert f"piece runs: {len(runs):,}" in cli("info", enzo_files / "cells.npz", check=0).stdout


def test_a_piece_reads_only_its_cells(enzo_files, tmp_path, cli):
    """Cells outside a piece's share that no whole build accepts (a level out of range,
    a corner off its level's lattice) do not stop that piece: it never reads them; the
    piece equals the one from the intact file."""
    d = enzo_files
    cells = schema.load(d / "cells.npz", "cells")
    share = schema.load(d / "bricks.1.npz", "bricks").meta["piece"]["cells"]
    lower, level = cells.lower_lattice.copy(), cells.level.copy()
    level[share[0] - 1] = 99
    lower[share[1]] += 1
    broken = tmp_path / "cells.npz"
    rewrite(d / "cells.npz", broken, lower_lattice=lower, level=level)
    cli("brick", broken, "--piece", "1/3", "-o", tmp_path / "b1.npz", check=0)
    assert_same(schema.load(d / "bricks.1.npz", "bricks"), schema.load(tmp_path / "b1.npz"), "piece")
    assert_one_error_line(cli("brick", broken, "-o", tmp_path / "b.npz"), "cells.npz", "level 99")
    # A piece whose share holds a bad cell names it by its index in the file.
    level[share[0] - 1], lower[share[1]] = cells.level[share[0] - 1], cells.lower_lattice[share[1]]
    level[share[0] + 5] = 99
    rewrite(d / "cells.npz", broken, lower_lattice=lower, level=level)
    assert_one_error_line(cli("brick", broken, "--piece", "1/3", "-o", tmp_path / "b1.npz"),
                          "cells.npz", f"from {share[0]}", "cell 5 ", "level 99")


@pytest.mark.slow
def test_a_cell_in_two_pieces_is_refused_by_regions(enzo_files, tmp_path, cli):
    """A crafted file in piece order with one cell copied into another piece's share:
    each piece bricks what it reads, and the joined bricks, which share that cell,
    are refused where regions check that no two bricks share a cell."""
    d = enzo_files
    cells = schema.load(d / "cells.npz", "cells")
    share = schema.load(d / "bricks.2.npz", "bricks").meta["piece"]["cells"]
    lower, level = cells.lower_lattice.copy(), cells.level.copy()
    lower[share[0]], level[share[0]] = lower[0], level[0]
    rewrite(d / "cells.npz", tmp_path / "cells.npz", lower_lattice=lower, level=level)
    assert_one_error_line(cli("brick", tmp_path / "cells.npz", "-o", tmp_path / "b.npz"),
                          "cells.npz", "overlap")
    for k in range(3):
        cli("brick", tmp_path / "cells.npz", "--piece", f"{k}/3", "-o", tmp_path / f"b{k}.npz", check=0)
    cli("join", *[tmp_path / f"b{k}.npz" for k in range(3)], "-o", tmp_path / "b.npz", check=0)
    assert_one_error_line(cli("regions", tmp_path / "b.npz", "-o", tmp_path / "r.npz"), "b.npz",
                          "share a cell")
    assert not (tmp_path / "r.npz").exists()


def test_pieces_of_regions_find_bricks_that_share_a_cell():
    """Each regions piece checks only the bricks of its own tasks; a brick moved onto
    its neighbour's cells is found by the pieces whose tasks hold the shared cells
    (each with the one-process build's message), and the other pieces pass."""
    bricks = build_bricks(dataset_cells("shell"))
    lower = bricks.lower_lattice.copy()
    b = int(np.flatnonzero(bricks.level == 0)[len(bricks.level) // 3])
    lower[b, 0] += 1  # one cell along x: onto the cells of the next brick, or off the shell
    crafted = bricks.replace(lower_lattice=lower)
    with pytest.raises(ExabricksError) as whole:
        build_regions(crafted)
    n, refused = 8, []
    for k in range(n):
        try:
            build_regions(crafted, piece=Piece(k, n))
        except ExabricksError as e:
            assert "share a cell" in str(e) and str(e) == str(whole.value)
            refused.append(k)
    assert 1 <= len(refused) < n


@pytest.mark.parametrize("runs,needles", [
    ({"max_brick_width": 32, "starts": [0, 7, 7]}, ["do not increase"]),
    pytest.param({"max_brick_width": 32, "starts": [3, 9]}, ["do not increase from 0"],
                 marks=pytest.mark.slow),
    ({"max_brick_width": 32, "starts": [0, 10 ** 30]}, ["starts of its"]),
    pytest.param({"max_brick_width": 32, "starts": "0"}, ["starts of its"], marks=pytest.mark.slow),
    ({"max_brick_width": "32", "starts": [0]}, None),  # no width: the whole file is read
    pytest.param([0, 1], None, marks=pytest.mark.slow),
])
def test_bad_runs_are_refused_or_ignored(enzo_files, tmp_path, cli, runs, needles):
    """Runs that are not increasing starts of the file's cells are refused with one
    line; runs without a width are not runs, and the piece reads the whole file."""
    cells = schema.load(enzo_files / "cells.npz", "cells")
    bad = tmp_path / "cells.npz"
    schema.save(bad, cells.replace(meta={**cells.meta, RUNS_KEY: runs}))
    proc = cli("brick", bad, "--piece", "1/3", "-o", tmp_path / "b.npz")
    if needles is None:
        assert proc.returncode == 0, proc.stderr
    else:
        assert_one_error_line(proc, "cells.npz", RUNS_KEY, *needles)
        assert not (tmp_path / "b.npz").exists()


@pytest.mark.slow
def test_wider_bricks_than_the_runs_read_the_whole_file(enzo_files, tmp_path, cli):
    """--max-brick-width above the runs' width: the pieces cut the partition as
    before (the runs are not nodes of it), and still join to the whole build."""
    d = enzo_files
    cli("brick", d / "cells.npz", "--max-brick-width", "64", "-o", tmp_path / "whole.npz", check=0)
    for k in range(2):
        cli("brick", d / "cells.npz", "--max-brick-width", "64", "--piece", f"{k}/2", "-o",
            tmp_path / f"b{k}.npz", check=0)
    cli("join", tmp_path / "b0.npz", tmp_path / "b1.npz", "-o", tmp_path / "joined.npz", check=0)
    assert_same(schema.load(tmp_path / "whole.npz"), schema.load(tmp_path / "joined.npz"), "wide")
