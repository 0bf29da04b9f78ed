"""A RAMSES output (helpers.ramses_output: 2 cpus, Hilbert domains, levels 3..6) read
through yt and by the native reader (exabricks.readers.ramses), checked cell by cell
against the analytic fields it was written from and against each other."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from exabricks.util.errors import ExabricksError

from helpers import FUZZ_EXAMPLES, analytic_amr, ramses_output

pytest.importorskip("yt")

ON_DISK = ("Density", "Pressure")  # yt's names of the descriptor's density, pressure


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    return ramses_output.write(tmp_path_factory.mktemp("ramses"))


def test_the_leaves_lie_on_every_level_from_levelmin(written):
    _, leaves = written  # their tiling: test_code_outputs.py
    assert len(np.unique(leaves.width)) == ramses_output.LEVELMAX - ramses_output.LEVELMIN + 1


def test_hilbert_keys_are_yts():
    from yt.frontends.ramses.hilbert import hilbert3d

    points = np.random.default_rng(1).integers(0, 2 ** 7, (500, 3))
    np.testing.assert_array_equal(ramses_output.hilbert_keys(points, 7), hilbert3d(points, 7))


def test_yt_bridge_reads_every_leaf(written):
    from exabricks.readers import yt_bridge

    path, leaves = written
    cells = yt_bridge.read(path, fields=list(ON_DISK))
    assert cells.fields == ON_DISK and cells.meta["source"]["frontend"] == "RAMSESDataset"
    analytic_amr.assert_cells_match(cells.replace(fields=analytic_amr.FIELDS), leaves)


def test_domains_hold_their_hilbert_keys(written):
    """yt's cells of each cpu file are the leaves whose centres' keys lie in that cpu's
    bound keys of the info file, and regions (selected through those keys) miss none."""
    from exabricks.readers import yt_bridge

    path, leaves = written
    ds = yt_bridge.load(path)
    fine = ramses_output.LEVELMAX + 1
    keys = ramses_output.hilbert_keys(np.floor(leaves.centres * 2 ** fine).astype(np.int64), fine)
    seen = []
    for chunk in ds.all_data().chunks([], "io"):
        seen.append(chunk._current_chunk.objs[0].domain_id)
        low, high = ds.hilbert_indices[seen[-1]]
        assert chunk["index", "dx"].size == np.sum((keys >= low) & (keys < high)) > 0
    assert sorted(seen) == [1, 2]
    for low, high in [((0.1, 0.1, 0.1), (0.3, 0.25, 0.2)), ((0.4, 0.3, 0.5), (0.45, 0.42, 0.6)),
                      ((0.7, 0.6, 0.8), (0.9, 0.95, 0.99))]:
        box = ds.region(np.add(low, high) / 2, low, high)
        inside = np.all((leaves.centres >= low) & (leaves.centres < high), axis=1)
        assert box["index", "dx"].size == inside.sum() > 0


def test_detect_format_says_ramses(written):
    from exabricks.readers import detect_format, field_names

    path, _ = written
    assert detect_format(path) == "ramses"
    assert detect_format(path.parent) == "ramses"
    assert field_names(path.parent, format="ramses") == list(ON_DISK)


@pytest.mark.parametrize("given", ["info", "folder"])
def test_native_reader_gives_every_leaf(written, given):
    from exabricks.readers import ramses

    path, leaves = written
    cells = ramses.read(path if given == "info" else path.parent)
    assert cells.fields == ON_DISK and cells.meta["source"]["format"] == "ramses"
    assert cells.meta["source"]["time"] == 0.0
    analytic_amr.assert_cells_match(cells.replace(fields=analytic_amr.FIELDS), leaves)
    one = ramses.read(path, fields=["Pressure"])
    assert one.fields == ("Pressure",)
    np.testing.assert_array_equal(one.values[0], cells.values[1])


def test_native_reader_equals_yt_cell_for_cell(written):
    from exabricks.readers import ramses, yt_bridge

    path, _ = written
    mine, theirs = ramses.read(path), yt_bridge.read(path)
    assert mine.fields == theirs.fields == ON_DISK
    np.testing.assert_array_equal(mine.origin_world, theirs.origin_world)
    np.testing.assert_array_equal(mine.spacing_world, theirs.spacing_world)
    a = np.lexsort((mine.level, *mine.lower_lattice.T))
    b = np.lexsort((theirs.level, *theirs.lower_lattice.T))
    np.testing.assert_array_equal(mine.lower_lattice[a], theirs.lower_lattice[b])
    np.testing.assert_array_equal(mine.level[a], theirs.level[b])
    np.testing.assert_array_equal(mine.values[:, a], theirs.values[:, b])


@pytest.fixture
def damaged(written, tmp_path):
    """A copy of the written output folder to damage; its info file."""
    path, _ = written
    folder = tmp_path / path.parent.name
    shutil.copytree(path.parent, folder)
    return folder / path.name


def _refused(path, *words):
    from exabricks.readers import ramses

    with pytest.raises(ExabricksError) as e:
        ramses.read(path)
    message = str(e.value)
    assert "\n" not in message
    for word in words:
        assert str(word) in message, message
    return message


def test_truncated_amr_file_is_refused(damaged):
    amr = damaged.parent / "amr_00001.out00002"
    data = amr.read_bytes()
    amr.write_bytes(data[:len(data) // 2])
    _refused(damaged, amr, "holds only")


def test_missing_hydro_file_is_refused(damaged):
    hydro = damaged.parent / "hydro_00001.out00002"
    hydro.unlink()
    _refused(damaged, hydro, "no such file")


def test_hydro_nvar_disagreeing_with_the_descriptor_is_refused(damaged):
    hydro = damaged.parent / "hydro_00001.out00001"
    data = bytearray(hydro.read_bytes())
    assert np.frombuffer(bytes(data[16:20]), "<i4")[0] == 2  # record 2: nvar
    data[16:20] = np.int32(3).tobytes()
    hydro.write_bytes(bytes(data))
    _refused(damaged, hydro, "nvar = 3", "hydro_file_descriptor.txt")


def test_info_file_without_ncpu_is_refused(damaged):
    text = damaged.read_text()
    damaged.write_text("".join(line for line in text.splitlines(True) if not line.startswith("ncpu")))
    _refused(damaged, damaged, "ncpu")


def test_special_files_are_refused_not_opened(written, tmp_path):
    """A FIFO in place of the info file, the descriptor or an amr file is named, never
    opened (an open would block); an info file of megabytes is no info file."""
    from exabricks.readers import ramses

    path, _ = written
    for name in (path.name, "hydro_file_descriptor.txt", "amr_00001.out00002"):
        copy = tmp_path / name.replace(".", "_") / "output_00001"
        shutil.copytree(path.parent, copy)
        (copy / name).unlink()
        os.mkfifo(copy / name)
        with pytest.raises(ExabricksError, match=rf"{name}: a FIFO, not a regular file"):
            ramses.read(copy / path.name if name == path.name else copy)
    big = tmp_path / "big" / "output_00001"
    shutil.copytree(path.parent, big)
    (big / path.name).write_bytes(b"ncpu = 2\n" + b" " * (2 << 20))
    with pytest.raises(ExabricksError, match="bytes: not a RAMSES info file"):
        ramses.read(big)


@pytest.mark.fuzz
@settings(max_examples=FUZZ_EXAMPLES, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_damaged_outputs_are_refused_in_one_line(written, tmp_path_factory, data):
    """One of the output's files truncated, or bytes of it overwritten (with random
    bytes or an int32 aimed at a count): the reader reads it or refuses it with
    ExabricksError (the CLI's one `error:` line), never another exception."""
    from exabricks.readers import ramses

    path, _ = written
    copy = tmp_path_factory.mktemp("damaged") / "output_00001"
    shutil.copytree(path.parent, copy)
    victim = copy / data.draw(st.sampled_from(sorted(p.name for p in copy.iterdir())), label="file")
    raw = bytearray(victim.read_bytes())
    at = data.draw(st.integers(0, max(len(raw) - 4, 0)), label="at")
    how = data.draw(st.sampled_from(["truncate", "bytes", "int32"]), label="how")
    if how == "truncate":
        raw = raw[:at]
    elif how == "bytes":
        raw[at:at + 4] = data.draw(st.binary(min_size=1, max_size=4), label="bytes")
    else:
        value = data.draw(st.sampled_from([-1, 0, 1, 7, 2**31 - 1, -(2**31), 10**6]), label="value")
        raw[at & ~3:(at & ~3) + 4] = np.int32(value).tobytes()
    victim.write_bytes(bytes(raw))
    try:
        ramses.read(copy)
    except ExabricksError:
        pass
