"""benchmarks/benchdoc.py and the pure helpers of the bench_*.py scripts: one section of
docs/benchmarks.md replaced, the rest byte for byte the same; flag and format helpers; the
notes around the tables computed from the results."""

from __future__ import annotations


import numpy as np
import pytest


from benchmarks import bench_ingest
from benchmarks import bench_preprocess
from benchmarks import bench_render
from benchmarks import benchdoc

from exabricks import schema  # noqa: E402

HEAD = "# Benchmarks\n\nIntro line.\n\n"
FIRST = "## ingest\n\nold ingest figures\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n"
MIDDLE = "## render (PoCL)\n\nold render text\n### a sub-heading stays inside\nmore\n\n"
LAST = ("## exabricks vs yt, cell location and the uniform-grid ceiling\n\n"
        "another script's text ## not a heading\n")


def test_replace_middle_section_leaves_the_others_byte_identical(tmp_path):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(HEAD + FIRST + MIDDLE + LAST)
    benchdoc.replace_section("render (PoCL)", "\nnew render\n\nfigures\n\n", doc)
    assert doc.read_text() == HEAD + FIRST + "## render (PoCL)\n\nnew render\n\nfigures\n\n" + LAST


def test_replace_first_and_last_sections(tmp_path):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(HEAD + FIRST + MIDDLE + LAST)
    benchdoc.replace_section("ingest", "new ingest", doc)
    assert doc.read_text() == HEAD + "## ingest\n\nnew ingest\n\n" + MIDDLE + LAST
    title = "exabricks vs yt, cell location and the uniform-grid ceiling"
    benchdoc.replace_section(title, "peers", doc)
    assert doc.read_text() == HEAD + "## ingest\n\nnew ingest\n\n" + MIDDLE + f"## {title}\n\npeers\n"


def test_missing_section_is_appended_and_a_prefix_title_does_not_match(tmp_path):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(HEAD + FIRST + MIDDLE)
    benchdoc.replace_section("in", "not the ingest section", doc)
    text = doc.read_text()
    assert text == HEAD + FIRST + MIDDLE + "## in\n\nnot the ingest section\n"
    benchdoc.replace_section("preprocessing per dataset", "table", doc)
    assert doc.read_text() == text + "\n## preprocessing per dataset\n\ntable\n"


def test_a_section_is_replaced_in_the_file_by_concept_that_holds_it(tmp_path, monkeypatch):
    """docs/benchmarks.md and its files by concept (docs/benchmarks-*.md) are one set:
    a section is replaced where it stands, a new one goes to benchmarks.md and its
    contents."""
    index, gpu = tmp_path / "benchmarks.md", tmp_path / "benchmarks-gpu.md"
    monkeypatch.setattr(benchdoc, "DOCS", index)
    index.write_text(HEAD + "Contents:\n\n- [ingest](#ingest)\n\n" + FIRST)
    gpu.write_text("# GPU\n\n" + MIDDLE)
    benchdoc.replace_section("render (PoCL)", "on the GPU page", index)
    assert gpu.read_text() == "# GPU\n\n## render (PoCL)\n\non the GPU page\n"
    assert index.read_text() == HEAD + "Contents:\n\n- [ingest](#ingest)\n\n" + FIRST
    benchdoc.replace_section("New: figures (x)", "new", index)
    assert index.read_text() == (HEAD + "Contents:\n\n- [ingest](#ingest)\n- [New: figures (x)](#new-figures-x)"
                                 "\n\n" + FIRST + "## New: figures (x)\n\nnew\n")


def test_new_document_starts_with_the_intro(tmp_path):
    doc = tmp_path / "benchmarks.md"
    benchdoc.replace_section("ingest", "figures", doc)
    assert doc.read_text() == benchdoc.INTRO + "\n## ingest\n\nfigures\n"


def test_median_spread_and_formats():
    assert benchdoc.median_spread([3, 1, 2, 10, 4]) == (3.0, 1.0, 10.0)
    assert benchdoc.fmt_spread([0.5, 0.25, 1.0], digits=2) == "0.50 (0.25-1.00) s"
    assert benchdoc.fmt_bytes(912) == "912 B"
    assert benchdoc.fmt_bytes(25_088) == "24.5 KiB"
    assert benchdoc.fmt_bytes(1_352_000) == "1.29 MiB"
    assert benchdoc.fmt_bytes(1000 * 2**20) == "0.98 GiB"
    assert benchdoc.fmt_seconds([9.19, 8.8, 10.3]) == "9.19 (8.80-10.30)"
    assert benchdoc.fmt_seconds([0.116, 0.1, 0.2]) == "0.116 (0.100-0.200)"
    assert benchdoc.fmt_seconds([0.00187]) == "0.00187 (0.00187-0.00187)"
    assert bench_preprocess.rate(23_586_557, [4.44]) == "5.31"
    assert bench_preprocess.rate(505_856, [0.0148]) == "34.2"


def test_only_selects_in_canonical_order():
    keys = ("gerris", "amrex", "athena", "enzo", "big")
    assert benchdoc.chosen(None, keys) == list(keys)
    assert benchdoc.chosen(["big,amrex", "gerris"], keys) == ["gerris", "amrex", "big"]
    with pytest.raises(SystemExit, match="nope"):
        benchdoc.chosen(["nope"], keys)


def test_stage_commands_and_ingest_flags(tmp_path):
    enzo = benchdoc.datasets()["enzo"]
    assert enzo.format == "yt" and benchdoc.datasets()["amrex"].format == "auto"
    steps = bench_preprocess.commands(enzo, tmp_path)
    assert [s for s, _ in steps] == ["ingest", "brick", "regions", "bvh"]
    ingest = steps[0][1]
    assert ingest[-2:] == ["--format", "yt"] and "-q" in ingest
    assert ingest[ingest.index("-o") + 1] == str(tmp_path / "cells.npz")
    assert steps[3][1][-3:] == [str(tmp_path / "regions.npz"), "-o", str(tmp_path / "bvh.npz")]
    assert bench_ingest.ingest_flags({"format": "raw", "dims": (4, 5, 6), "max_level": 2}) == [
        "--format", "raw", "--dims", "4", "5", "6", "--max-level", "2"]


def test_report_notes_are_computed_from_the_results():
    """The prose around the tables takes its figures from the results (hand-computed here)."""
    # 100 regions of 55 B and 30 B of BVH each over 10 bricks of 85 cells, one float32
    # field: 850 B of regions + BVH against 340 B of scalars per brick, 2.5x: within the
    # thin shells' 3x target, above the big input's 1.5x; no target for a real dataset.
    result = {"cells": 850, "fields": 1, "n_bricks": 10, "region_stats": {"n_regions": 100},
              "bytes": {"scalars": 3400, "regions": 5500, "bvh": 3000}}
    head = ("10.0 regions x (55 B of region + 30 B of BVH) = 850 B against 340 B of scalars "
            "(85.0 cells x 1 field(s)): 2.50x")
    sets = benchdoc.datasets()
    lines = bench_preprocess.size_notes([{**result, "dataset": sets[k]}
                                         for k in ("shell", "big", "gerris")])[-3:]
    assert lines == [f"- {sets['shell'].name}: {head}, within the 3x target",
                     f"- {sets['big'].name}: {head}, above the 1.5x target",
                     f"- {sets['gerris'].name}: {head}"]
    assert bench_preprocess.defaults() == {"max_brick_width": 32, "leaf_size": 4}

    cells = schema.Cells(fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                         lower_lattice=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.int32),
                         level=np.array([0, 0, 1], np.int8), values=np.ones((1, 3), np.float32))
    assert bench_ingest.levels_note("toy", cells) == (
        "- toy: 3 leaf cells on 2 levels (level 0: 2, level 1: 1)")
    assert bench_ingest.target_note({"a": 6e6, "b": 4e6}) == (
        "Target: >= 5 M cells/s end to end: met on a; missed on b.")
    assert bench_ingest.target_note({}) == "Target: >= 5 M cells/s (not measured)."

    notes = bench_render.time_notes({
        "x": {"avg_bricks_per_region_by_count": 3.3, "avg_bricks_per_region_by_volume": 1.5},
        "y": {"avg_bricks_per_region_by_count": 4.0, "avg_bricks_per_region_by_volume": 2.7}})
    assert "3.3-4.0 bricks per region by count and 1.5-2.7 by volume" in notes
    assert bench_render.time_notes({}) == ""


def test_merge_rows_and_stale_regions(tmp_path):
    """bench_merge's table rows come from the results; a cached regions file built
    with another merge setting (or older than its bricks) is rebuilt."""
    from benchmarks import bench_merge

    from exabricks.builders.regions import EXACT, Merge, build_regions
    from exabricks.builders.bricks import build_bricks

    sets = benchdoc.datasets()
    setting = {"regions": 10, "regions_s": 0.5, "bvh_s": 0.25, "regions_per_cell": 2.0,
               "bvh_per_cell": 1.0, "ratio": 0.75, "bricks_per_region": 3.0, "ms": 12.0}
    result = {"dataset": sets["shell"], "cells": 1000, "bricks": 10, "index_per_cell": 0.5,
              "scalars": 4000, "merged": setting, "exact": None}
    exact_row, merged_row = bench_merge.rows(result)
    assert merged_row == (f"| {sets['shell'].name} | merged | 10 | 3.0 | 0.50 | 2.00 | 1.00 "
                          "| 0.75 | 0.5 | 0.25 | 12 |")
    assert "| exact (of the 2.33 M k-d bricks" in exact_row and "| 83,364,768 |" in exact_row
    assert "(not built)" in exact_row

    cells = schema.Cells(fields=("v",), origin_world=np.zeros(3), spacing_world=np.ones(3),
                         lower_lattice=np.array([[0, 0, 0], [1, 0, 0]], np.int32),
                         level=np.zeros(2, np.int8), values=np.ones((1, 2), np.float32))
    bricks = build_bricks(cells)
    for merge, current in ((Merge(), True), (EXACT, False)):
        regions = build_regions(bricks, merge)
        path = tmp_path / "regions.npz"
        schema.save(path, regions.replace(meta={**regions.meta}))
        assert benchdoc.up_to_date(path) is current
    assert not benchdoc.up_to_date(tmp_path / "missing.npz")
