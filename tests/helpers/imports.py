"""The package's imports as its tests read them: every module of exabricks/, what
each imports (inside functions too; not the names of an `if TYPE_CHECKING:`
block, which never run) and the folder it lives in."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "exabricks"


def modules() -> dict[str, Path]:
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports(name: str, path: Path, modules) -> list[tuple[str, str]]:
    """(module imported, name imported from it or '') of every import in `path`."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    tree = ast.parse(path.read_text())
    for block in [n for n in ast.walk(tree) if isinstance(n, ast.If)
                  and ast.unparse(n.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING")]:
        block.body = []  # names for type checkers only: never imported when the code runs
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                out.append((full, "") if full in modules else (base, alias.name))
        elif isinstance(node, ast.Import):
            out += [(alias.name, "") for alias in node.names]
    return [(m, n) for m, n in out if m in modules and m != name]


def part(module: str) -> str:
    """The folder a module lives in (exabricks.engine.renderer: "engine"), or the
    module itself for one at the root (exabricks.api: "api"; the facade: "exabricks")."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def folder_graph() -> dict[str, set[str]]:
    """{folder (or root module): the folders and root modules it imports}."""
    found = modules()
    graph: dict[str, set[str]] = {}
    for m, p in found.items():
        graph.setdefault(part(m), set()).update(
            part(t) for t, _ in imports(m, p, found) if part(t) != part(m))
    return graph
