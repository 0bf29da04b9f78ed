"""The documentation site (mkdocs.yml, `make docs`; issue 64, item 2): every page in
its navigation, every public name of `import exabricks as eb` in the API reference,
every render option in the generated table, and the examples of the docstrings that
the API reference shows run as written from the checkout's root. `make docs` (CI,
in `make test-all`) builds the site in strict mode: a broken link or anchor fails."""

from __future__ import annotations

import doctest
import importlib
import importlib.util
import re

import pytest

from helpers import ROOT

DOCS = ROOT / "docs"


def _hooks():
    spec = importlib.util.spec_from_file_location("exabricks_docs_hooks", DOCS / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _nav_pages() -> list[str]:
    return re.findall(r":\s*([\w./-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)


def test_the_navigation_holds_every_page_once():
    pages = sorted(p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md"))
    nav = _nav_pages()
    assert sorted(nav) == pages, (f"not in mkdocs.yml's nav: {sorted(set(pages) - set(nav))}, "
                                  f"not a page: {sorted(set(nav) - set(pages))}")
    nav = (ROOT / "mkdocs.yml").read_text().split("\nnav:\n", 1)[1]
    sections = re.findall(r"^  - (\w[\w -]*):\s*$", nav, re.M)
    assert sections == ["Tutorials", "How-to guides", "Reference", "Explanation"]


def test_the_options_table_names_every_declared_option():
    from exabricks.scene.options import JOB_OPTIONS, SCENE_OPTIONS

    table = _hooks().options_table()
    rows = [line for line in table.splitlines() if line.startswith("| `--")]
    assert len(rows) == len(SCENE_OPTIONS) + len(JOB_OPTIONS)
    for option in (*SCENE_OPTIONS, *JOB_OPTIONS):
        assert any(row.startswith(f"| `{option.flag} ") or row.startswith(f"| `{option.flag}`")
                   for row in rows), option.flag
    spp = next(row for row in rows if row.startswith("| `--spp "))
    assert "| `spp` |" in spp and "an integer from 1 to 4096" in spp
    assert "<!-- render-options -->" in (DOCS / "reference" / "scene-options.md").read_text()


def test_the_api_reference_documents_every_public_name():
    import exabricks as eb

    page = (DOCS / "reference" / "python-api.md").read_text()
    documented = {path.rsplit(".", 1)[-1] for path in re.findall(r"^::: ([\w.]+)$", page, re.M)}
    public = {name for name in eb.__all__ if not name.startswith("_")}
    assert public <= documented, sorted(public - documented)
    for path in re.findall(r"^::: (exabricks\.[\w.]+)$", page, re.M):
        module, _, name = path.rpartition(".")
        if module and name in public:
            assert getattr(importlib.import_module(module), name) is getattr(eb, name), path


@pytest.mark.parametrize("name", ["open", "render"])
def test_the_docstring_examples_run_from_the_checkout(name, monkeypatch):
    """Their Examples sections (doctest), from the checkout's root as README's quick start."""
    import exabricks as eb

    monkeypatch.chdir(ROOT)
    tests = doctest.DocTestFinder().find(getattr(eb, name), name, globs={"eb": eb})
    assert tests and tests[0].examples, f"eb.{name} has no Examples"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for test in tests:
        runner.run(test)
    assert runner.summarize(verbose=False).failed == 0
