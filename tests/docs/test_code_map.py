"""docs/contributing.md's code map names every module of the package and every
kernel file, and nothing that does not exist (issue 50, item 5): a module added
without its line, or a line left behind by a move, fails here."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAP = ROOT / "docs" / "contributing.md"
TICKED = re.compile(r"`([^`]+)`")


def _section(title: str) -> list[str]:
    text = MAP.read_text()
    start = text.index(f"\n{title}\n")
    end = text.find("\n## ", start + 1)
    return [line for line in text[start:end].splitlines() if line.startswith("|")]


def named_modules() -> set[str]:
    """Paths the concept table names: `exabricks/x.py`, and `exabricks/pkg/` (`a`, `b`)
    as exabricks/pkg/a.py, exabricks/pkg/b.py (or the subpackages a/, b/)."""
    named = set()
    for line in _section("## Where each concept lives"):
        where = line.rstrip("|").rsplit("|", 1)[-1]
        folder = None
        for token in TICKED.findall(where):
            if token.startswith("exabricks/"):
                named.add(token.rstrip("/").removesuffix(".py"))
                folder = token.rstrip("/") if token.endswith("/") else None
            elif folder is not None and re.fullmatch(r"[a-z_0-9]+(\.py)?", token):
                named.add(f"{folder}/{token.removesuffix('.py')}")
    return named


def test_the_code_map_names_every_module_and_nothing_else():
    named = named_modules()
    modules = {p.relative_to(ROOT).with_suffix("").as_posix()
               for p in (ROOT / "exabricks").rglob("*.py") if p.name != "__main__.py"}
    packages = {p.parent.relative_to(ROOT).as_posix() for p in (ROOT / "exabricks").rglob("__init__.py")}

    def covered(module: str) -> bool:  # named itself, or its package named as a whole
        parts = module.split("/")
        return any("/".join(parts[:k]) in named for k in range(2, len(parts) + 1))

    missing = sorted(m for m in modules if not covered(m))
    assert not missing, f"docs/contributing.md's code map misses {missing}"
    stale = sorted(n for n in named if n not in modules | packages and not (ROOT / n).exists())
    assert not stale, f"docs/contributing.md's code map names what does not exist: {stale}"


def test_the_kernel_table_names_every_kernel_file_and_nothing_else():
    named = {t for line in _section("### The kernels (`kernels/`)")[2:]
             for t in TICKED.findall(line.split("|")[1])}
    files = {p.name for p in (ROOT / "kernels").iterdir() if p.suffix in (".cl", ".h", ".inc")}
    assert named == files, (f"missing {sorted(files - named)}, stale {sorted(named - files)}")


@pytest.mark.parametrize("name", ["design", "benchmarks"])
def test_the_contents_of_the_split_documents_are_their_sections(name):
    """docs/design.md and docs/benchmarks.md and their files by concept
    (docs/NAME-*.md) each list their own sections, and NAME.md links every
    section of the others."""
    index = (ROOT / "docs" / f"{name}.md").read_text()
    for path in sorted((ROOT / "docs").glob(f"{name}*.md")):
        text = path.read_text()
        listed = re.findall(r"^- \[([^\]]+)\]\(#[^)]+\)$", text, re.M)
        headings = re.findall(r"^## (.+)$", text, re.M)
        assert headings and listed == headings, (
            f"{path.name}: not listed: {[h for h in headings if h not in listed]}, "
            f"not a section: {[c for c in listed if c not in headings]}")
        if path.name != f"{name}.md":
            linked = re.findall(rf"\[([^\]]+)\]\({re.escape(path.name)}#[^)]+\)", index)
            assert linked == headings, (path.name, linked, headings)


def test_the_flag_table_of_scene_md_is_the_declared_options():
    """docs/scene.md's flag table names every render option declared in
    exabricks.scene.options (the scene's and the job's) and no other."""
    from exabricks.scene.options import JOB_OPTIONS, SCENE_OPTIONS

    text = (ROOT / "docs" / "scene.md").read_text()
    table = text[text.index("| Flag | Scene key | Meaning |"):]
    table = table[:table.index("\n\n")]
    named = set()
    for line in table.splitlines()[2:]:
        for flag in re.findall(r"--([a-z][a-z-]*)", line.split("|")[1]):
            named.add(flag)
    declared = {o.flag.removeprefix("--") for o in (*SCENE_OPTIONS, *JOB_OPTIONS)}
    negated = {f"no-{o.flag.removeprefix('--')}" for o in (*SCENE_OPTIONS, *JOB_OPTIONS) if o.kind == "flag"}
    named -= negated
    assert named == declared, f"not in the table: {sorted(declared - named)}, not declared: {sorted(named - declared)}"


def test_the_layers_of_the_code_map_are_the_imports():
    """docs/contributing.md says that a folder (or a root module) uses those above it
    in its table and is used by those below: no import, inside functions too, runs
    from a row to a row below it."""
    from helpers.imports import folder_graph

    row = {}
    for k, line in enumerate(_section("## Where each concept lives")[2:]):
        where = line.rstrip("|").rsplit("|", 1)[-1]
        for name in re.findall(r"`exabricks/([a-z_]+)(?:/|\.py)`", where):
            row.setdefault(name, k)
    graph = folder_graph()
    unplaced = sorted(p for p in graph if p not in row and p != "exabricks")
    assert not unplaced, f"not in the table: {unplaced}"
    upward = sorted(f"{a} -> {b}" for a, targets in graph.items() for b in targets
                    if "exabricks" not in (a, b) and row[a] < row[b])
    assert not upward, f"imports from a row to a row below it: {upward}"
