"""README.md is the way in (issue 64, item 1): at most 600 words; what exabricks is
and one picture; the two set-up commands first, as the Makefile and CI have them;
a quick start whose paths exist in the checkout; and where to go next. Its quick
start runs as written from the checkout's root in tests/docs/test_docs_examples.py
(CHECKOUT_DOCS), which checks the pictures it makes and what `info` prints."""

from __future__ import annotations

import re

from helpers import ROOT
from helpers.pictures import assert_visible_png

README = ROOT / "README.md"


def _blocks(text: str) -> list[tuple[str, str]]:
    """(language, text) of the fenced code blocks of `text`."""
    return re.findall(r"^```(\w*)\n(.*?)^```", text, re.S | re.M)


def _section(title: str) -> str:
    text = README.read_text()
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def test_readme_is_at_most_600_words():
    assert len(README.read_text().split()) <= 600


def test_the_readme_picture_exists_and_shows_data():
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README.read_text())
    assert len(pictures) == 1, pictures
    path = ROOT / pictures[0]
    assert path.is_file(), pictures[0]
    assert_visible_png(path, least=0.2)


def test_the_set_up_commands_come_first_and_are_the_makefiles():
    """The first code block is `make demo` and `make test`; the Makefile has both, and
    CI (.ci/run) runs `make test-all`, which runs the fast suite and builds the site."""
    first = _blocks(README.read_text())[0][1]
    commands = [line.split("#")[0].strip() for line in first.splitlines() if line.strip()]
    assert commands == ["make demo", "make test"], commands
    makefile = (ROOT / "Makefile").read_text()
    for target in ("demo", "test", "test-all", "docs", "wheel"):
        assert re.search(rf"^{re.escape(target)}:", makefile, re.M), target
    assert re.search(r"^test-all:.*\bdocs\b", makefile, re.M)
    assert "make test-all" in (ROOT / ".ci" / "run").read_text()


def test_the_quick_start_names_what_exists_and_runs_from_the_checkout():
    """Every path the quick start names exists in the checkout; its commands are
    `.venv/bin/exabricks` (what `make demo` made); all but the viewer run in
    tests/docs/test_docs_examples.py."""
    quick = _section("Quick start")
    assert "make demo" in quick and ".venv/bin/activate" in README.read_text()
    paths = re.findall(r"(?:exabricks|tests)/[\w./-]+", quick)
    assert paths, quick
    for path in paths:
        assert (ROOT / path).exists(), path
    blocks = _blocks(quick)
    commands = [line for lang, text in blocks if lang == "sh" for line in text.splitlines()
                if line.strip() and not line.startswith((" ", "#"))]
    assert len(commands) >= 4 and all(c.startswith(".venv/bin/exabricks ") for c in commands), commands
    assert [c.split()[1] for c in commands].count("view") == 1  # served until Ctrl-C: the one not run
    assert any(lang == "python" for lang, _ in blocks)


def test_where_next_links_pages_that_exist():
    links = re.findall(r"\]\(([^)#]+)", _section("Where next"))
    assert len(links) >= 8
    for link in links:
        assert (ROOT / link).is_file(), link


def test_readme_says_how_to_install_without_pypi():
    text = _section("Installing elsewhere")
    assert "not on PyPI" in text and "make wheel" in text and "pip install ." in text
    assert "pip install 'exabricks" not in README.read_text()
