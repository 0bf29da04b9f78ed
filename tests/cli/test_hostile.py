"""The hostile cases of issue 14, each reproduced once and kept as a regression test:
output paths that are not ours to replace, crafted intermediate files that used
to crash or hang the kernels, resources claimed before they are checked,
thresholds and values that slipped through, and messages that were not one
plain line. Each ends in success or one `error:` line with exit 1 (2 for usage),
with nothing replaced and nothing left behind."""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from exabricks import schema

from helpers import GERRIS, assert_one_error_line
from helpers.hostile import TIMEOUT, run


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in Path(directory).iterdir() if p.name.endswith(".tmp"))


def sha(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def rewrite(src: Path, dst: Path, **arrays) -> Path:
    """A copy of the .npz `src` at `dst` with some members replaced."""
    with np.load(src, allow_pickle=False) as z:
        members = {k: z[k] for k in z.files}
    members.update(arrays)
    np.savez(dst, **members)
    return dst


def crafted(plume_trio, tmp_path, which: int, **arrays) -> list[Path]:
    paths = list(plume_trio)
    paths[which] = rewrite(plume_trio[which], tmp_path / plume_trio[which].name, **arrays)
    return paths


def bvh_arrays(plume_trio):
    with np.load(plume_trio[2], allow_pickle=False) as z:
        return {k: z[k].copy() for k in ("first", "count", "lower_lattice", "upper_lattice")}


# ---------------------------------------------------------------------------
# 1. output paths


def test_device_nodes_are_written_into_never_replaced(plume_trio, tmp_path):
    proc = run("bvh", plume_trio[1], "-o", "/dev/null")
    assert proc.returncode == 0, proc.stderr
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    if os.path.exists("/dev/full"):
        assert_one_error_line(run("bvh", plume_trio[1], "-o", "/dev/full"), "/dev/full", "No space left")
        assert stat.S_ISCHR(os.stat("/dev/full").st_mode)
    assert not [p for p in os.listdir("/dev") if p.startswith(".eb-")]


def test_a_fifo_receives_the_output(plume_trio, tmp_path):
    fifo = tmp_path / "out.npz"
    os.mkfifo(fifo)
    received = tmp_path / "received"
    with open(received, "wb") as sink:
        reader = subprocess.Popen(["cat", str(fifo)], stdout=sink)
        proc = run("bvh", plume_trio[1], "-o", fifo)
        reader.wait(timeout=TIMEOUT)
    data = received.read_bytes()
    assert proc.returncode == 0, proc.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and data[:2] == b"PK"


def test_a_symlinked_output_writes_the_file_it_names_and_keeps_the_link(plume_trio, tmp_path):
    link = tmp_path / "link.npz"
    link.symlink_to("target.npz")
    assert run("bvh", plume_trio[1], "-o", link).returncode == 0
    assert link.is_symlink() and os.readlink(link) == "target.npz"
    assert schema.peek(tmp_path / "target.npz")[0] == "bvh"


def test_a_directory_is_not_an_output(plume_trio, tmp_path):
    proc = run("bvh", plume_trio[1], "-o", tmp_path)
    assert proc.returncode == 2 and "is a directory" in proc.stderr  # click's usage error


@pytest.mark.parametrize("command", ["brick", "regions", "bvh"])
def test_an_output_naming_an_input_is_refused(command, plume_trio, tmp_path):
    inputs = {"brick": None, "regions": plume_trio[0], "bvh": plume_trio[1]}
    source = inputs[command]
    if source is None:
        source = tmp_path / "cells.npz"
        assert run("ingest", GERRIS, "-o", source, "--field", "T").returncode == 0
    copy = tmp_path / f"in-{command}.npz"
    copy.write_bytes(Path(source).read_bytes())
    before = sha(copy)
    link = tmp_path / "alias.npz"
    link.symlink_to(copy)
    for out in (copy, link):
        assert_one_error_line(run(command, copy, "-o", out), "would overwrite the input")
    assert sha(copy) == before and not leftovers(tmp_path)


def test_compare_diff_onto_an_input_is_refused(tmp_path):
    from exabricks.film.image_io import write_image

    a = tmp_path / "a.png"
    write_image(a, np.zeros((12, 12, 4), np.float32))
    before = sha(a)
    proc = run("compare", a, a, "--diff", a)
    assert proc.returncode == 2 and "would overwrite the input" in proc.stderr
    assert sha(a) == before


@pytest.mark.parametrize("name, needle", [
    ("", "output path is empty"),
    ("nodir/x.npz", "does not exist"),
    ("a" * 300 + ".npz", "file name too long"),
])
def test_unwritable_output_names_get_a_plain_message(name, needle, plume_trio, tmp_path):
    assert_one_error_line(run("bvh", plume_trio[1], "-o", name, cwd=tmp_path), needle)


def test_a_long_output_name_keeps_a_short_temporary(plume_trio, tmp_path):
    name = "a" * 249 + ".npz"
    assert run("bvh", plume_trio[1], "-o", name, cwd=tmp_path).returncode == 0
    assert (tmp_path / name).is_file() and not leftovers(tmp_path)


# ---------------------------------------------------------------------------
# 2. crafted files that used to crash or hang the kernels


def test_a_bvh_leaf_with_a_negative_count_is_refused(plume_trio, tmp_path):
    a = bvh_arrays(plume_trio)
    leaf = int(np.flatnonzero(a["count"] > 0)[0])
    a["count"][leaf] = -2_000_000_000
    a["first"][leaf] = 2_000_000_000
    paths = crafted(plume_trio, tmp_path, 2, count=a["count"], first=a["first"])
    for command in (["render", *paths, "-o", tmp_path / "x.png", "--size", "16", "16"],
                    ["probe", *paths, "--points", _points(tmp_path), "-o", tmp_path / "v.npy"]):
        assert_one_error_line(run(*command), "negative region count")
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "v.npy").exists()


@pytest.mark.parametrize("target", ["self", "root"])
def test_a_bvh_cycle_is_refused(target, plume_trio, tmp_path):
    a = bvh_arrays(plume_trio)
    inner = int(np.flatnonzero(a["count"] == 0)[1])
    a["first"][inner] = inner if target == "self" else 0
    paths = crafted(plume_trio, tmp_path, 2, first=a["first"])
    assert_one_error_line(run("render", *paths, "-o", tmp_path / "x.png", "--size", "16", "16"),
                          f"BVH node {inner}", "must follow it")


def test_a_bvh_node_with_two_parents_is_refused(plume_trio, tmp_path):
    a = bvh_arrays(plume_trio)
    inner = np.flatnonzero(a["count"] == 0)
    a["first"][inner[2]] = a["first"][inner[1]]
    paths = crafted(plume_trio, tmp_path, 2, first=a["first"])
    assert_one_error_line(run("render", *paths, "-o", tmp_path / "x.png"), "one parent per node")


def test_region_levels_outside_the_range_are_refused(plume_trio, tmp_path):
    with np.load(plume_trio[1], allow_pickle=False) as z:
        level = z["finest_level"].copy()
    level[0] = -40
    paths = crafted(plume_trio, tmp_path, 1, finest_level=level)
    assert_one_error_line(run("render", *paths, "-o", tmp_path / "x.png"),
                          "region 0 has level -40")


@pytest.mark.parametrize("which, member", [(1, "upper_lattice"), (2, "lower_lattice")])
def test_infinite_bounds_are_refused(which, member, plume_trio, tmp_path):
    with np.load(plume_trio[which], allow_pickle=False) as z:
        bounds = z[member].copy()
    bounds[0, 1] = np.inf if member == "upper_lattice" else -np.inf
    paths = crafted(plume_trio, tmp_path, which, **{member: bounds})
    assert_one_error_line(run("render", *paths, "-o", tmp_path / "x.png"), "must be finite")


def test_a_negative_brick_id_is_named_as_such(plume_trio, tmp_path):
    with np.load(plume_trio[1], allow_pickle=False) as z:
        ids = z["brick_ids"].copy()
    ids[3] = -5
    paths = crafted(plume_trio, tmp_path, 1, brick_ids=ids)
    assert_one_error_line(run("render", *paths, "-o", tmp_path / "x.png"), "negative brick id (-5)")


def test_an_absurd_sampling_rate_is_refused_at_once(plume_trio, tmp_path):
    proc = run("render", *plume_trio, "-o", tmp_path / "x.png", "--sampling-rate", "1e30", timeout=30)
    assert_one_error_line(proc, "samples on a ray", "lower it")


def test_too_deep_a_bvh_is_refused():
    from exabricks.util.constants import MAX_TREE_DEPTH

    # A chain: node 2k is inner with children 2k+1 (a leaf) and 2k+2.
    depth = MAX_TREE_DEPTH + 1
    m = 2 * depth - 1
    first = np.zeros(m, np.int32)
    count = np.zeros(m, np.int32)
    inner = np.arange(0, m - 1, 2)
    first[inner] = inner + 1
    leaves = np.setdiff1d(np.arange(m), inner)
    first[leaves] = np.arange(leaves.size)
    count[leaves] = 1
    box = np.zeros((m, 3), np.float32)
    bvh = schema.Bvh(fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                     lower_lattice=box, upper_lattice=box + 1, first=first, count=count,
                     region_index=np.arange(leaves.size, dtype=np.int32),
                     value_range=np.zeros((m, 1, 2), np.float32),
                     finest_level=np.zeros(m, np.int8))
    with pytest.raises(Exception, match=f"{depth + 0} levels deep"):
        schema.validate(bvh)
    schema.validate(bvh.replace(**_shallower(bvh)))


def _shallower(bvh):
    """The same chain one level shorter (at the limit, so valid)."""
    m = bvh.n_nodes - 2
    first, count = bvh.first[:m].copy(), bvh.count[:m].copy()
    first[m - 1], count[m - 1] = bvh.region_index.size - 2, 1
    return dict(first=first, count=count, lower_lattice=bvh.lower_lattice[:m],
                upper_lattice=bvh.upper_lattice[:m], value_range=bvh.value_range[:m],
                finest_level=bvh.finest_level[:m], region_index=bvh.region_index[:-1])


def _points(tmp_path) -> Path:
    path = tmp_path / "points.npy"
    np.save(path, np.full((4, 3), 0.5))
    return path


# ---------------------------------------------------------------------------
# 3. resources claimed before they are checked


def test_a_zip_bomb_is_refused_before_decompressing(plume_trio, tmp_path):
    bomb = tmp_path / "bomb.npz"
    with np.load(plume_trio[0], allow_pickle=False) as z:
        members = {k: z[k] for k in z.files if k != "values"}
    np.savez(bomb, **members)
    # A values member whose .npy header claims 1 GiB of float32, deflated to ~1 MB.
    header = np.lib.format.header_data_from_array_1_0(np.zeros((1, 1), np.float32))
    header["shape"] = (1, 1 << 28)
    with zipfile.ZipFile(bomb, "a", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("values.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array_header_1_0(f, header)
            zeros = bytes(1 << 24)
            for _ in range(64):
                f.write(zeros)
    proc = run("info", bomb, timeout=30)
    assert_one_error_line(proc, "values", "inconsistent")


def test_an_image_larger_than_memory_allows_is_refused(plume_trio, tmp_path):
    import resource

    def limit():  # 3 GiB of address space: far below a 20000^2 float RGBA image
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))

    proc = run("render", *plume_trio, "-o", tmp_path / "x.exr", "--size", "20000", "20000",
               preexec_fn=limit)
    assert_one_error_line(proc, "GiB")
    assert not (tmp_path / "x.exr").exists() and not leftovers(tmp_path)


# ---------------------------------------------------------------------------
# 6, 7. thresholds, values and messages


@pytest.mark.parametrize("flag", ["--max-rmse", "--min-psnr", "--max-abs", "--min-ssim"])
def test_nan_thresholds_are_refused(flag, tmp_path):
    from exabricks.film.image_io import write_image

    a = tmp_path / "a.png"
    write_image(a, np.zeros((12, 12, 4), np.float32))
    proc = run("compare", a, a, flag, "nan")
    assert proc.returncode == 2 and "not nan" in proc.stderr


@pytest.mark.parametrize("spacing", [np.inf, 1e-320, 0.0, np.nan])
def test_spacing_must_be_finite_positive_and_normal(spacing, tmp_path):
    from helpers import two_level_cells

    cells = two_level_cells()
    path = tmp_path / "c.npz"
    schema.save(path, cells)
    rewrite(path, path, spacing_world=np.array([1.0, spacing, 1.0]))
    assert_one_error_line(run("info", path), "spacing finite, positive and normal")


def test_a_cell_overwritten_by_a_copy_of_another_is_refused_by_brick(tmp_path):
    cells_path = tmp_path / "cells.npz"
    assert run("ingest", GERRIS, "-o", cells_path, "--field", "T").returncode == 0
    with np.load(cells_path, allow_pickle=False) as z:
        lower, level = z["lower_lattice"].copy(), z["level"].copy()
    lower[10], level[10] = lower[500], level[500]
    rewrite(cells_path, cells_path, lower_lattice=lower, level=level)
    proc = run("brick", cells_path, "-o", tmp_path / "b.npz")
    assert_one_error_line(proc, "cells overlap", "cell 500")
    assert not (tmp_path / "b.npz").exists()


def test_overlapping_bricks_are_refused_by_regions(plume_trio, tmp_path):
    with np.load(plume_trio[0], allow_pickle=False) as z:
        lower, level, dims = z["lower_lattice"].copy(), z["level"].copy(), z["dims"]
    same = np.flatnonzero((level == level[0]) & (dims == dims[0]).all(axis=1))
    lower[same[1]] = lower[same[0]]
    paths = crafted(plume_trio, tmp_path, 0, lower_lattice=lower)
    assert_one_error_line(run("regions", paths[0], "-o", tmp_path / "r.npz"), "bricks overlap")


@pytest.mark.parametrize("stage", ["brick", "regions"])
def test_a_damaged_member_is_caught_by_the_mapped_checked_load(tmp_path, stage):
    """The builders map their input's large members (schema.load(mapped=True,
    checked=True)): a flipped byte in one is still caught by its CRC."""
    import zipfile

    from exabricks.builders.bricks import build_bricks

    g = np.stack(np.meshgrid(*[np.arange(72)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = schema.Cells(fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                         lower_lattice=g.astype(np.int32), level=np.zeros(len(g), np.int8),
                         values=np.linspace(0, 1, len(g), dtype=np.float32)[None])
    path = tmp_path / "in.npz"
    schema.save(path, cells if stage == "brick" else build_bricks(cells))
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("values.npy")
    assert info.file_size >= schema.NpzArchive.DIRECT_BYTES  # mapped, not read whole
    data = bytearray(path.read_bytes())
    data[info.header_offset + info.file_size // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    out = tmp_path / "out.npz"
    assert_one_error_line(run(stage, path, "-o", out), "'values'", "bad CRC")
    assert not out.exists()


@pytest.mark.parametrize("content", [b"PK", b"PK\x03\x04", b"hello\n", b"\x93NUMPY"])
def test_files_that_are_not_npz_get_a_plain_message(content, tmp_path):
    path = tmp_path / "x.npz"
    path.write_bytes(content)
    proc = run("info", path)
    assert_one_error_line(proc, str(path))
    assert "allow_pickle" not in proc.stderr


def test_text_points_get_a_plain_message(plume_trio, tmp_path):
    points = tmp_path / "p.npy"
    points.write_text("0 0 0\n1 1 1\n")
    proc = run("probe", *plume_trio, "--points", points, "-o", tmp_path / "v.npy")
    assert_one_error_line(proc, "not a .npy array file")
    assert "allow_pickle" not in proc.stderr


@pytest.mark.parametrize("option", ["--camera", "--transfer-function"])
def test_deeply_nested_json_is_named(option, plume_trio, tmp_path):
    path = tmp_path / "deep.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    proc = run("render", *plume_trio, "-o", tmp_path / "x.png", option, path)
    assert_one_error_line(proc, str(path), "nested too deeply")


def test_deeply_nested_meta_is_named(plume_trio, tmp_path):
    path = rewrite(plume_trio[1], tmp_path / "r.npz", meta=np.array("[" * 100_000 + "]" * 100_000))
    assert_one_error_line(run("info", path), "nested too deeply")


def test_no_runtime_warning_precedes_an_error(tmp_path):
    """Values beyond float32 used to warn about an overflow before the error line."""
    raw = tmp_path / "v.raw"
    np.full(8, 1e300, np.float64).tofile(raw)
    proc = run("ingest", raw, "--format", "raw", "--dims", "2", "2", "2", "--dtype", "float64",
               "-o", tmp_path / "c.npz")
    assert "Warning" not in proc.stderr
    assert proc.returncode in (0, 1)
    if proc.returncode:
        assert_one_error_line(proc)
