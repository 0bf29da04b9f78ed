"""`exabricks info` of sources (issue 48 item 5): format, time, levels, cells per
level, fields with their ranges and world bounds of anything `render SOURCE` takes,
checked against references that do not go through our readers: yt 4.4.3's own
leaf cells (`ds.all_data()`) for AMReX, Athena++ and Enzo, and the raw ExaJet and
raw-volume bytes read with NumPy. (The .npz summaries: tests/formats/test_schema.py.)"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from exabricks import schema
from exabricks.describe import describe, field_range
from exabricks.stages.ingest import ingest

from helpers import AMREX, ATHENA, ENZO, GERRIS, LEAF_COUNTS, assert_one_error_line


def _strict(text: str):
    """`text` parsed as strict JSON (NaN and Infinity refused)."""
    def refuse(name):
        raise AssertionError(f"not strict JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def _yt_reference(path, ftype: str) -> dict:
    """What yt says of `path`, with levels numbered as exabricks numbers them (0 finest)."""
    yt = pytest.importorskip("yt")
    yt.set_log_level(40)
    ds = yt.load(str(path))
    ad = ds.all_data()
    top = ds.index.max_level
    level = top - ad["index", "grid_level"].d.astype(np.int64)
    coarse = (ds.domain_width / ds.domain_dimensions).to("code_length").d
    names = [n for t, n in ds.field_list if t == ftype]
    ranges = {}
    for n in names:
        v = ad[ftype, n].d
        # the reader stores float32: rounding is monotonic, so the float32 extremes are
        # the rounded float64 ones
        ranges[n] = (float(np.float32(v.min())), float(np.float32(v.max())))
    return {
        "cells": int(level.size),
        "per_level": {str(L): int(c) for L, c in enumerate(np.bincount(level)) if c},
        "width": {str(top - l): (coarse / float(ds.refine_by) ** l).tolist() for l in range(top + 1)},
        "ranges": ranges,
        "time": float(ds.current_time.to("code_time").d),
        "lower": ds.domain_left_edge.to("code_length").d.tolist(),
        "upper": ds.domain_right_edge.to("code_length").d.tolist(),
    }


@pytest.mark.parametrize("name, path, fmt, ftype", [
    ("amrex", AMREX, "amrex", "boxlib"),
    ("athena", ATHENA, "athena", "athena_pp"),
    ("enzo", ENZO, "yt", "enzo"),
])
def test_source_summary_matches_yt(name, path, fmt, ftype):
    s = describe(path)
    ref = _yt_reference(path, ftype)
    assert s["kind"] == "source" and s["format"] == fmt and s["path"] == str(path)
    assert s["counts"]["cells"] == ref["cells"] == LEAF_COUNTS[name]
    assert s["counts"]["cells_per_level"] == ref["per_level"]
    assert s["levels"] == len(ref["per_level"])
    for level in s["counts"]["cells_per_level"]:
        np.testing.assert_allclose(s["cell_width_per_level"][level], ref["width"][level], rtol=1e-12)
    assert {f["name"]: (f["min"], f["max"]) for f in s["fields"]} == ref["ranges"]
    assert all(f["nonfinite"] == 0 for f in s["fields"])
    assert s["time"] == pytest.approx(ref["time"], rel=1e-12)
    np.testing.assert_allclose(s["world_bounds"]["lower"], ref["lower"], atol=1e-12)
    np.testing.assert_allclose(s["world_bounds"]["upper"], ref["upper"], atol=1e-12)
    assert s["masked"] is None
    assert _strict(json.dumps(s, allow_nan=False)) == s


def _exajet_reference():
    """Levels, per-level counts, field ranges and lattice box of the plume, from its bytes."""
    raw = np.fromfile(GERRIS, "<i4").reshape(-1, 4)
    level = raw[:, 3]
    upper = raw[:, :3] + (1 << level)[:, None]
    ranges = {}
    for p in GERRIS.parent.glob(GERRIS.stem + ".*.scalars"):
        v = np.fromfile(p, "<f4")
        assert v.size == raw.shape[0]
        ranges[p.name.split(".")[-2]] = (float(v.min()), float(v.max()))
    return {"per_level": {str(L): int(c) for L, c in enumerate(np.bincount(level)) if c},
            "ranges": ranges, "lower": raw[:, :3].min(axis=0).tolist(),
            "upper": upper.max(axis=0).tolist(), "cells": raw.shape[0]}


def test_exajet_summary_matches_its_bytes():
    s = describe(GERRIS)
    ref = _exajet_reference()
    assert s["format"] == "exajet" and s["time"] is None
    assert s["counts"]["cells"] == ref["cells"] == LEAF_COUNTS["gerris"]
    assert s["counts"]["cells_per_level"] == ref["per_level"]
    assert s["cell_width_per_level"]["3"] == [8.0, 8.0, 8.0]  # spacing 1: lattice units
    assert {f["name"]: (f["min"], f["max"]) for f in s["fields"]} == ref["ranges"]
    assert s["world_bounds"] == {"lower": ref["lower"], "upper": ref["upper"]}


def test_cli_text_and_json_of_a_source(cli):
    ref = _exajet_reference()
    text = cli("info", GERRIS, check=0).stdout
    assert text.startswith(f"{GERRIS}: exajet source\n")
    assert f"  cells: {ref['cells']:,}\n" in text
    assert f"  levels: {len(ref['per_level'])} (level 0 is the finest)\n" in text
    assert f"  level 0: {ref['per_level']['0']:,} cells of width [1.0, 1.0, 1.0]\n" in text
    lo, hi = ref["ranges"]["T"]
    assert f"  field T: [{lo!r}, {hi!r}]\n" in text
    assert "time" not in text  # ExaJet files record none
    doc = _strict(cli("info", "--json", GERRIS, check=0).stdout)
    assert doc["kind"] == "source" and doc["time"] is None
    assert doc["counts"]["cells_per_level"] == ref["per_level"]


def test_field_range_over_sources_and_files(tmp_path, cli):
    """--field-range reads a source's field as it reads a cells file's, and mixes them."""
    lo, hi = _exajet_reference()["ranges"]["T"]
    assert field_range([GERRIS], "T") == (lo, hi)
    cells = tmp_path / "cells.npz"
    schema.save(cells, ingest(GERRIS, fields=["T"]))
    out = cli("info", "--field-range", "T", GERRIS, cells, check=0).stdout.split()
    assert [float(x) for x in out] == [lo, hi]
    assert_one_error_line(cli("info", "--field-range", "nope", GERRIS), str(GERRIS), "'nope'")
    # an exabricks file takes no ingest options, a source does
    assert_one_error_line(cli("info", cells, "--dims", 2, 2, 2), str(cells), "no ingest options")


def test_source_and_its_cells_file_agree(tmp_path):
    cells = tmp_path / "cells.npz"
    schema.save(cells, ingest(GERRIS))
    a, b = describe(GERRIS), describe(cells)
    assert b["kind"] == "cells"
    assert a["counts"]["cells_per_level"] == b["counts"]["cells_per_level"]
    assert [(f["name"], f["min"], f["max"]) for f in a["fields"]] == \
        [(f["name"], f["min"], f["max"]) for f in b["fields"]]
    assert a["world_bounds"] == b["world_bounds"]


def test_raw_volume_with_non_finite_values(tmp_path, cli):
    """A raw volume is read with its --dims; NaN and infinity are counted, left out of
    the range, and the JSON stays strict."""
    volume = np.arange(64, dtype="<f4").reshape(4, 4, 4) * 0.5 - 3.0
    volume[1, 2, 3], volume[3, 0, 0] = np.nan, np.inf
    path = tmp_path / "v.raw"
    volume.tofile(path)
    doc = _strict(cli("info", "--json", path, "--dims", 4, 4, 4, check=0).stdout)
    finite = volume[np.isfinite(volume)]
    (field,) = doc["fields"]
    assert field == {"name": "value", "min": float(finite.min()), "max": float(finite.max()),
                     "nonfinite": 2}
    assert doc["format"] == "raw" and doc["counts"]["cells"] == 64  # no two voxels alike: no merge
    assert doc["world_bounds"] == {"lower": [0.0, 0.0, 0.0], "upper": [4.0, 4.0, 4.0]}
    text = cli("info", path, "--dims", 4, 4, 4, check=0).stdout
    assert "field value: [-3.0, 28.5] (2 non-finite)" in text
    assert_one_error_line(cli("info", path), str(path), "--dims")


@pytest.mark.parametrize("flags, needles", [
    (["--fields", "value", "--fields", "value"], ["--fields", "given twice"]),
    (["--name", "v\nerror: forged line"], ["--name", "control character"]),
    (["--name", ""], ["--name", "empty"]),
])
def test_bad_field_names_of_a_source_are_one_error_line(tmp_path, cli, flags, needles):
    """No forged output line, no field without a name, no StopIteration: the one
    rule of field names (schema.field_names_problem), naming the option."""
    path = tmp_path / "v.raw"
    np.arange(8, dtype="<f4").tofile(path)
    proc = cli("info", path, "--dims", 2, 2, 2, *flags)
    assert_one_error_line(proc, str(path), *needles)
    assert proc.stdout == ""


def test_a_file_with_a_control_character_in_a_field_name_is_refused(tmp_path):
    cells = ingest(GERRIS, fields=["T"])
    path = tmp_path / "c.npz"
    with pytest.raises(Exception, match="control character"):
        schema.save(path, cells.replace(fields=("T\nerror: forged",)))
    assert schema.field_names_problem(["T", "rho", "a b", "ρ"]) is None


@pytest.mark.parametrize("case", ["missing", "fifo", "garbage", "garbage athdf", "plain directory"])
def test_bad_input_is_one_error_line(tmp_path, cli, case):
    path = tmp_path / {"garbage athdf": "x.athdf", "plain directory": "dir"}.get(case, case)
    if case == "fifo":
        os.mkfifo(path)
    elif case.startswith("garbage"):
        path.write_bytes(b"not a dataset\n" * 8)
    elif case == "plain directory":
        path.mkdir()
    assert_one_error_line(cli("info", path), str(path))
