"""The package's structure as the contributing rules state it (issue 33): no
import cycles between its modules, function-level imports included (not the
`if TYPE_CHECKING:` names of the package's lazy facade, which never run), and no
private name imported from another module."""

from __future__ import annotations

import ast

from helpers.imports import PACKAGE, folder_graph, imports, modules


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state, path = {}, []

    def visit(m):
        state[m] = "open"
        path.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == "open":
                return path[path.index(t):] + [t]
            if t not in state and (found := visit(t)):
                return found
        path.pop()
        state[m] = "done"
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_no_import_cycles():
    found = modules()
    graph = {m: {t for t, _ in imports(m, p, found)} for m, p in found.items()}
    found = _cycle(graph)
    assert not found, "import cycle: " + " -> ".join(found)


def test_no_import_cycles_between_folders():
    """The folders (and the root's modules) are layers (docs/contributing.md,
    "Where each concept lives"): no two import each other, even through others
    and inside functions."""
    found = _cycle(folder_graph())
    assert not found, "folders import each other: " + " -> ".join(found)


def test_the_root_holds_at_most_twelve_modules():
    """The root keeps the library's face and what joins the layers; the rest lives in
    the folder of its concept."""
    root = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(root) <= 12, root


def test_no_private_name_is_imported_from_another_module():
    found = modules()
    used = [(m, t, n) for m, p in found.items() for t, n in imports(m, p, found)
            if n.startswith("_") and not n.startswith("__")]
    assert not used, used


def test_command_modules_are_thin():
    """A command parses its options and calls the library (rasterio's `rio` style):
    every command module is at most 120 lines (main.py, the group and the one
    place errors become exit statuses, and options.py, the shared options, are
    not commands)."""
    long = {p.name: n for p in (PACKAGE / "cli").glob("*.py")
            if p.name not in ("main.py", "options.py", "__init__.py")
            and (n := len(p.read_text().splitlines())) > 120}
    assert not long, long


def test_no_module_over_600_lines_and_no_function_over_100():
    """One concept a file, and functions that read in one screenful or two: a module
    that grows past 600 lines has a second concept to move out (as the regions'
    k-d partition and merge, the AMReX headers or a domain's share of the data
    were), a function past 100 lines a step to name."""
    long_modules, long_functions = {}, {}
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text()
        name = path.relative_to(PACKAGE.parent).as_posix()
        if (n := len(text.splitlines())) > 600:
            long_modules[name] = n
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                    and (n := node.end_lineno - node.lineno + 1) > 100:
                long_functions[f"{name}:{node.name}"] = n
    assert not long_modules and not long_functions, (long_modules, long_functions)


def test_tests_mirror_the_package():
    """Every test module lives in the folder of what it tests (tests/engine/ for
    exabricks/engine/, ...), none at the root, and none imports another test module
    or conftest: what tests share is in tests/helpers/ or a fixture."""
    tests = PACKAGE.parent / "tests"
    at_root = sorted(p.name for p in tests.glob("test_*.py"))
    assert not at_root, at_root
    shared = []
    for path in tests.rglob("test_*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom)
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            shared += [f"{path.relative_to(tests)}: {n}" for n in names
                       if n == "conftest" or n.startswith("test_")]
    assert not shared, shared
