"""Messages that blamed the wrong thing (issue 64, item 5): each is one `error:` line
that names the user's flag or input and says what is wrong with it."""

from __future__ import annotations

import os
import shutil

import pytest

from exabricks.util.errors import ExabricksError

from helpers import AMREX, GERRIS, assert_one_error_line, run_cli


def test_an_unknown_colormap_names_colormap_and_the_closest_name(tmp_path):
    """`--colormap infern` blamed --field; it names --colormap, the name given and
    inferno. A slice's and an iso-surface's colormaps name their own flags."""
    proc = run_cli("render", GERRIS, "--field", "T", "--colormap", "infern", "--size", "8", "8",
                   "-o", tmp_path / "x.png")
    assert_one_error_line(proc, "error: --colormap: unknown colormap 'infern'; did you mean 'inferno'?")
    assert "--field" not in proc.stderr and not (tmp_path / "x.png").exists()


def test_a_range_low_above_high_names_range_and_says_so(tmp_path):
    proc = run_cli("render", GERRIS, "--range", "0.5", "0.1", "--size", "8", "8", "-o", tmp_path / "x.png")
    assert_one_error_line(proc, "error: --range: low 0.5 > high 0.1")
    assert "default field" not in proc.stderr and not (tmp_path / "x.png").exists()


def test_the_library_says_the_same():
    import exabricks as eb

    renderer = eb.Renderer(GERRIS)
    with pytest.raises(ExabricksError, match=r"^--colormap: unknown colormap 'Viridis'; did you mean 'viridis'\?"):
        renderer.scene(field="T", colormap="Viridis")
    with pytest.raises(ExabricksError, match=r"^--range: low 2 = high 2 "):
        renderer.scene(field="T", range=(2, 2))
    with pytest.raises(ExabricksError, match=r"unknown colormap 'zzzz' \(any matplotlib"):
        renderer.scene(field="T", colormap="zzzz")  # nothing close: no hint


@pytest.mark.parametrize("command", ["render", "info"])
def test_a_run_folder_of_plotfiles_gets_a_hint_naming_them(command, tmp_path):
    """An AMReX run's folder, given where one of its plotfiles belongs, said only
    "cannot tell the format; use --format"."""
    run = tmp_path / "run"
    run.mkdir()
    for step in ("plt00000", "plt00010", "plt00020", "plt00100"):
        os.symlink(AMREX, run / step)
    (run / "inputs").write_text("amr.plot_int = 10\n")
    args = ["render", run, "-o", tmp_path / "x.png"] if command == "render" else ["info", run]
    proc = run_cli(*args)
    assert_one_error_line(proc, f"{run} is a folder of 4 AMReX plotfiles (plt00000, plt00010, ..., plt00100)",
                          f"give one, e.g. {run / 'plt00100'}", f"exabricks series '{run}/plt*'")


def test_a_folder_without_plotfiles_still_says_use_format(tmp_path):
    folder = tmp_path / "notes"
    (folder / "plt00000").mkdir(parents=True)  # named as a plotfile, holding none
    shutil.copy(AMREX.parent / "inputs_3d", folder / "inputs_3d")
    proc = run_cli("info", folder)
    assert_one_error_line(proc, "cannot tell the format of", "use --format")
