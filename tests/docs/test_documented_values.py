"""What the documents say an example prints or shows, where the example itself cannot
run in tests/docs/test_docs_examples.py or its output is a figure in the prose
(issue 64, item 3): the value is taken from the document and checked against the
code, so that the sentence goes stale in a test, not in a reader's hands."""

from __future__ import annotations

import ast
import re

import numpy as np
import pytest

from helpers import AMREX, GERRIS, ROOT


def _python_blocks(doc: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / doc).read_text(), re.S)


def test_the_time_of_a_step_is_where_time_series_md_reads_it():
    """docs/time-series.md prints each step's time with an expression of `dataset`
    (its series is a run's steps, which no checkout ships): that expression gives a
    plotfile's time, the one `exabricks info` prints."""
    import exabricks as eb
    from exabricks.describe import describe

    block = next(b for b in _python_blocks("docs/time-series.md") if "open_series" in b)
    call = next(node for node in ast.walk(ast.parse(block)) if isinstance(node, ast.Call)
                and getattr(node.func, "id", "") == "print")
    expression = ast.unparse(call.args[0])
    assert "dataset" in expression
    time = eval(expression, {"dataset": eb.open(AMREX)})  # noqa: S307 - our own document
    info = describe(AMREX)
    assert time == pytest.approx(0.4793328726939373) and time == pytest.approx(info["time"])


def _span(rgba: np.ndarray) -> tuple[float, float]:
    """The share of the frame's width and height that its visible pixels span."""
    rows, cols = np.nonzero(rgba[..., 3] > 0.02)
    return (cols.max() - cols.min() + 1) / rgba.shape[1], (rows.max() - rows.min() + 1) / rgba.shape[0]


@pytest.mark.slow  # two 512² frames and the plume's structures built: about 6 s on 2 cores
def test_how_much_of_the_frame_the_plume_fills_is_what_python_md_says():
    """docs/python.md: with the default camera the plume's visible pixels span W% of
    the frame's width and H% of its height; with the camera it gives, X% of the width."""
    import exabricks as eb

    text = " ".join((ROOT / "docs" / "python.md").read_text().split())
    said = re.search(r"visible pixels span (\d+)% of the frame's width and (\d+)% of its height\)\. "
                     r"`position=(\([^)]*\)), look_at=(\([^)]*\))`.*?the plume then spans (\d+)% of the width",
                     text)
    assert said, "docs/python.md: the sentence on the default camera's framing moved"
    width, height, position, look_at, near = said.groups()
    renderer = eb.Renderer(GERRIS)
    options = dict(field="T", colormap="inferno", size=(512, 512))
    default = _span(renderer.render(**options).rgba)
    own = _span(renderer.render(position=ast.literal_eval(position), look_at=ast.literal_eval(look_at),
                                **options).rgba)
    assert default == pytest.approx((int(width) / 100, int(height) / 100), abs=0.02)
    assert own[0] == pytest.approx(int(near) / 100, abs=0.02)
