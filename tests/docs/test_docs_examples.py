"""Every example of README.md, docs/*.md and docs/examples/ runs as written, from a
folder outside the checkout (issue 48, item 7).

The examples are read from the documents, never listed here, so that an example
added broken fails: the ```python blocks; the ```sh, ```console and ```bash blocks
and the indented or unlabelled blocks that start with a command (`exabricks`,
`make`, `mpiexec`, ...), a command a line (`\\` continues it); the complete ```json
objects, saved as the file that opens the paragraph above them (docs/scene.md's
`plume.json`); and the scripts and scene files of docs/examples/ (its notebooks:
tests/docs/test_notebooks.py, every one of them). A document's examples run in order
in one fresh folder, prepared as docs/python.md, "Running the examples", says (its
setup block, with REPO this checkout; CHECKOUT_DOCS, README's quick start, in a folder
that looks like the checkout's root after `make demo`): shell commands through bash, Python blocks in
one namespace in this process, and then every output they name (`-o`, `.save(...)`,
`render_job(_, ...)`) must exist. The scene-file fragments of the documents (```json
blocks that are not a whole object) are checked against the scene schema.

What does not run is named here with the reason: usage lines (a block from the first
command with a placeholder on: INPUT, SOURCE, `[--option]`, `…`), EXEMPT_DOCS and
EXEMPT (an exemption that matches nothing fails). The SLOW examples run in the slow
variant of their document's test only."""

from __future__ import annotations

import ast
import fnmatch
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from helpers import ROOT
from helpers.pictures import assert_visible_png

DOCS = ("README.md", *sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md")))
EXAMPLES = ROOT / "docs" / "examples"
SETUP_DOC = "docs/python.md"  # its ```sh block that sets REPO prepares every folder
# Documents whose examples run from the checkout's root after `make demo`, as they say:
# `.venv/bin/exabricks` and the data by its path in the checkout (a folder that links
# the checkout's folders and the environment of this process as .venv).
CHECKOUT_DOCS = ("README.md", "docs/first-picture.md")

EXEMPT_DOCS = {
    "docs/gallery.md": "written by benchmarks/gallery.py (make gallery): each shot renders bench-data/gallery "
                       "from the checkout's root",
    **{doc: "written by the benchmark scripts (make bench): their commands run from the checkout's root "
            "over bench-data/" for doc in DOCS if doc.startswith("docs/benchmarks")},
}

# (document pattern, regular expression searched in a command or a Python block,
#  "command" or "block": the matching command only, or its whole block; reason)
EXEMPT = [
    ("*", r"bench-data/|-m benchmarks\.", "block",
     "the benchmarks' and the docs pictures' commands: run from the checkout's root over bench-data/ "
     "(make gallery, make bench)"),
    ("*", r"^make ", "command",
     "a target of the checkout's Makefile or of workflows/Makefile, run in the checkout (CI runs the root "
     "targets, tests/workflows/test_workflows.py the pipelines)"),
    ("*", r"^(sbatch|srun|mpiexec) |workflows/slurm/", "command",
     "SLURM or MPI (tests/workflows/test_workflows.py with make test-slurm, tests/engine/test_mpi.py)"),
    ("docs/commands.md", r"build_piece\.sbatch", "block", "joins what the sbatch array builds"),
    ("docs/install.md", r"pip install", "block",
     "a new environment from PyPI (Intel's CPU runtime is 0.9 GB): tests/device/test_runtime.py installs "
     "the wheel that make wheel builds, with the cpu extra, into a fresh venv with no system driver visible "
     "and renders the demo"),
    ("README.md", r"exabricks view ", "command", "serves the viewer until interrupted (tests/viewer/test_view.py)"),
    ("docs/commands.md", r"--size 16384 16384", "command",
     "a 16384² poster: a 4 GiB scratch file and CPU minutes (tests/engine/test_streaming.py draws posters in tiles)"),
    ("docs/view.md", r"^exabricks view ", "command", "serves the viewer until interrupted (tests/viewer/test_view.py)"),
    ("docs/time-series.md", r"plt00000", "block",
     "a run's steps on one hierarchy (plt00000, plt00010, ...): none ships; tests/builders/test_values.py runs "
     "values and render --values on a series"),
    ("docs/time-series.md", r"run/plt\*", "command",
     "a run's steps (run/plt*): none ships; tests/library/test_series.py runs open_series, render_series and "
     "the series command on workflows/make_series.py's series"),
    ("docs/workflows.md", r"steps/\*/", "command", "the steps a series pipeline writes (make series)"),
    ("docs/annotate.md", r"annotate\(rgba, scene", "block",
     "the function's signature over names the text defines (rgba, scene, bricks)"),
]

# (document, regular expression, reason): run by the slow variant of the document's test only
SLOW = [
    ("docs/commands.md", r"--spp 16 --progressive 10", "16 samples a pixel under a memory budget"),
    ("docs/commands.md", r"--ao-samples 8", "ambient occlusion: 8 rays a sample"),
    ("docs/python.md", r"ao_samples=8|plume-scene\.json", "ambient occlusion, 4 samples a pixel"),
    ("docs/python.md", r"eb\.Renderer\(ds\)", "24 frames"),
    ("docs/python.md", r"^import yt", "yt's import and an Enzo dataset through it"),
    ("docs/python.md", r"render_job\(", "a 2048² poster in tiles"),
    ("docs/scene.md", r"--scene plume\.json", "800x600 with ambient occlusion, 4 and 16 samples a pixel"),
    ("docs/workflows.md", r"--frames 0:120|^exabricks movie 'frames/", "120 frames and their movie"),
]

PLACEHOLDER = re.compile(r"\b(INPUT|SOURCE|CELLS|FILE|NAME|STEP|DATASET|KEYFRAMES|BRICKS|REGIONS|BVH)\b(?!=)"
                         r"|\[--|…")
COMMAND = re.compile(r"(exabricks|\.venv/bin/exabricks|time exabricks|make|mpiexec|srun|sbatch|for \w+ in|mkdir"
                     r"|ln|python3?|\S*/python3?|\S*\.sh|[A-Za-z_]\w*=\S*)(\s|$)")
SHELL = {"sh", "bash", "console", "shell"}


@dataclass(frozen=True)
class Example:
    doc: str
    line: int       # of its first line in the document
    block: int      # the line of its block's first line
    kind: str       # "sh" (one command), "python" (a block), "file" (a JSON object saved as `name`)
    text: str
    name: str = ""

    @property
    def where(self) -> str:
        return f"{self.doc}:{self.line}"


def code_blocks(doc: str):
    """(first line of the code, language, text) of each fenced and indented code block."""
    lines = (ROOT / doc).read_text().splitlines()
    i, blank_before = 0, True
    while i < len(lines):
        fence = re.match(r"^(`{3,}|~{3,})\s*([\w+-]*)", lines[i])
        if fence:
            start, body = i + 1, []
            i += 1
            while i < len(lines) and not lines[i].startswith(fence.group(1)):
                body.append(lines[i])
                i += 1
            yield start + 1, fence.group(2), "\n".join(body)
            i, blank_before = i + 1, False
            continue
        if lines[i].startswith("    ") and lines[i].strip() and blank_before:
            start, body = i, []
            while i < len(lines) and (lines[i].startswith("    ") or not lines[i].strip()):
                body.append(lines[i][4:])
                i += 1
            yield start + 1, "", "\n".join(body).rstrip("\n")
            blank_before = True
            continue
        blank_before = not lines[i].strip()
        i += 1


def _commands(text: str, first: int):
    """(line, command) of a shell block: `\\` continues a line; blanks and comments skipped."""
    pending, start = [], None
    for n, line in enumerate(text.splitlines(), first):
        if not pending and (not line.strip() or line.lstrip().startswith("#")):
            continue
        start = n if not pending else start
        pending.append(line)
        if not line.rstrip().endswith("\\"):
            yield start, "\n".join(pending)
            pending = []
    if pending:
        yield start, "\n".join(pending)


def _file_name(doc: str, line: int) -> str:
    """The `NAME.json` that opens the paragraph before line `line` ("" if none)."""
    lines = (ROOT / doc).read_text().splitlines()[:line - 2]
    while lines and not lines[-1].strip():
        lines.pop()
    paragraph = []
    while lines and lines[-1].strip():
        paragraph.insert(0, lines.pop())
    found = re.match(r"`([\w.-]+\.json)`", " ".join(paragraph).strip())
    return found.group(1) if found else ""


def examples(doc: str) -> tuple[list[Example], list[tuple[Example, str]], list[tuple[int, str]]]:
    """The document's examples in order, those that do not run with the reason, and
    its scene-file fragments (line, text)."""
    run, skipped, fragments = [], [], []
    for line, lang, text in code_blocks(doc):
        if lang == "python":
            run.append(Example(doc, line, line, "python", text))
        elif lang == "json":
            try:
                obj = json.loads(text)
            except json.JSONDecodeError:
                fragments.append((line, text))
                continue
            assert isinstance(obj, dict), f"{doc}:{line}: a JSON example is an object or a fragment of one"
            name = _file_name(doc, line)
            assert name, f"{doc}:{line}: a whole JSON object opens its paragraph with its file name, `NAME.json`"
            run.append(Example(doc, line, line, "file", text, name))
        elif lang in SHELL or (lang == "" and text.strip() and COMMAND.match(text.strip())):
            usage = False
            for n, command in _commands(text, line):
                usage = usage or bool(PLACEHOLDER.search(re.sub(r"#.*", "", command)))
                example = Example(doc, n, line, "sh", command)
                (skipped.append((example, "a usage line (placeholders)")) if usage else run.append(example))
    if doc in EXEMPT_DOCS:
        return [], [(e, EXEMPT_DOCS[doc]) for e in run], []
    kept = []
    for example in run:
        reason = exemption(example, run)
        (skipped.append((example, reason)) if reason else kept.append(example))
    return kept, skipped, fragments


def _matches(example: Example, entry) -> bool:
    pattern, regex, scope, _ = entry
    return fnmatch.fnmatch(example.doc, pattern) and bool(re.search(regex, example.text, re.M))


def exemption(example: Example, others: list[Example]) -> str:
    for entry in EXEMPT:
        if _matches(example, entry):
            return entry[3]
        if entry[2] == "block" and any(_matches(o, entry) for o in others if o.block == example.block):
            return entry[3]
    return ""


def slow(example: Example) -> bool:
    return any(doc == example.doc and re.search(regex, example.text, re.M) for doc, regex, _ in SLOW)


def outputs(example: Example) -> list[str]:
    """The files an example names as its outputs (globs for printf-numbered frames)."""
    if example.kind == "sh":
        words = shlex.split(example.text.replace("\\\n", " "), comments=True)
        names = [words[i + 1] for i, w in enumerate(words[:-1]) if w == "-o"]
    elif example.kind == "python":
        names = []
        for node in ast.walk(ast.parse(example.text)):
            if not isinstance(node, ast.Call):
                continue
            name = getattr(node.func, "attr", getattr(node.func, "id", ""))
            at = {"save": 0, "render_job": 1}.get(name)
            if at is not None and len(node.args) > at and isinstance(node.args[at], ast.Constant):
                names.append(node.args[at].value)
    else:
        names = [example.name]
    # printf-numbered frames and shell variables ($k of a loop) as globs
    return [re.sub(r"%0?\d*d|\$\w+|\$\{\w+\}", "*", n).rstrip(";") for n in names]


def _env() -> dict:
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "exabricks").exists(), f"no exabricks command beside {sys.executable} (pip install -e .)"
    return {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"}


def _bash(script: str, folder: Path, where: str) -> str:
    proc = subprocess.run(["bash", "-e", "-c", script], cwd=folder, env=_env(), capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, (f"{where}: exit status {proc.returncode}\n{script}\n"
                                  f"stdout: {proc.stdout[-2000:]}\nstderr: {proc.stderr[-4000:]}")
    return proc.stdout


def _setup_block() -> tuple[int, str]:
    for line, lang, text in code_blocks(SETUP_DOC):
        if lang in SHELL and re.search(r"^REPO=", text, re.M):
            return line, text
    raise AssertionError(f"{SETUP_DOC}: no ```sh block that sets REPO (\"Running the examples\")")


def _is_setup(example: Example) -> bool:
    return example.doc == SETUP_DOC and example.block == _setup_block()[0]


@pytest.fixture(scope="session")
def prepared(tmp_path_factory) -> Path:
    """A folder prepared as docs/python.md, "Running the examples", says."""
    folder = tmp_path_factory.mktemp("examples")
    line, text = _setup_block()
    script = re.sub(r"^REPO=.*$", f"REPO={shlex.quote(str(ROOT))}", text, count=1, flags=re.M)
    _bash(script, folder, f"{SETUP_DOC}:{line}")
    return folder


def _folder(prepared: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "examples"
    shutil.copytree(prepared, folder, symlinks=True)
    assert not folder.resolve().is_relative_to(ROOT.resolve())
    return folder


def checkout_folder(tmp_path: Path) -> Path:
    """A folder that looks like the checkout's root after `make demo` (CHECKOUT_DOCS):
    the checkout's folders and files linked in, and this process's environment as
    `.venv` (in a checkout after `make demo`, that is the checkout's .venv)."""
    folder = tmp_path / "checkout"
    folder.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in (".venv", ".git", "out", "site", "dist"):
            (folder / entry.name).symlink_to(entry)
    (folder / ".venv").symlink_to(Path(sys.prefix))
    assert (folder / ".venv" / "bin" / "exabricks").exists(), f"no exabricks command in {sys.prefix}"
    return folder


def _docs_with_examples():
    # Every run is in the slow suite (CI runs it): together they take about a minute
    # on 2 cores, which `make test` cannot spare; the checks of the scene files and
    # of the exemptions below stay in the fast one.
    for doc in DOCS:
        run = [e for e in examples(doc)[0] if not _is_setup(e)]
        if any(not slow(e) for e in run):
            yield pytest.param(doc, False, id=doc, marks=pytest.mark.slow)
        if any(slow(e) for e in run):
            yield pytest.param(doc, True, id=f"{doc}-slow", marks=pytest.mark.slow)


def _quick_start(namespace: dict, folder: Path) -> None:
    """README's quick start: what it says `info` prints, and its pictures."""
    printed = "".join(namespace["__stdout__"])
    assert "cells: 67,712" in printed and "levels: 5" in printed, printed
    assert all(f"field {f}:" in printed for f in "PTUVW"), printed
    for name in ("plume-T.png", "phi.png", "plume-T-python.png"):
        assert_visible_png(folder / name)
    import exabricks as eb

    assert eb.Image.read(folder / "phi.png").rgba.shape[1] > 512  # annotated: the colour bar beside
    assert namespace["ds"].fields == ("P", "T", "U", "V", "W")


def _first_picture(namespace: dict, folder: Path) -> None:
    printed = "".join(namespace["__stdout__"])
    assert "exajet source" in printed and "cells: 67,712" in printed and "field T: [" in printed
    for name in ("plume-auto.png", "plume-inferno.png", "plume-iso.png", "phi.png"):
        assert_visible_png(folder / name)


def _python_page(namespace: dict, folder: Path) -> None:
    import numpy as np

    import exabricks as eb

    assert namespace["amrex"].fields == ("phi",)
    assert eb.Image.read(folder / "plume.png").rgba.shape[0] > 512  # annotated: a panel added
    assert namespace["speed"].rgba[..., 3].max() > 0.05
    assert len(namespace["frames"]) == 24 and np.isfinite(namespace["values"][:2]).all()
    assert namespace["mixed"].fields[-2:] == ("speed", "hot")


# What a document's examples leave in their namespace, beyond running (the Python ones).
CHECKS = {"docs/python.md": _python_page, "README.md": _quick_start, "docs/first-picture.md": _first_picture}


@pytest.mark.parametrize("doc, with_slow", list(_docs_with_examples()))
def test_the_examples_of_a_document_run_as_written(doc, with_slow, request, tmp_path, monkeypatch):
    every = [e for e in examples(doc)[0] if not _is_setup(e)]
    run = [e for e in every if with_slow or not slow(e)]
    if any(e.kind == "python" and re.search(r"^\s*import yt\b", e.text, re.M) for e in run):
        pytest.importorskip("yt")
    folder = (checkout_folder(tmp_path) if doc in CHECKOUT_DOCS
              else _folder(request.getfixturevalue("prepared"), tmp_path))
    monkeypatch.chdir(folder)
    namespace: dict = {"__name__": "__main__", "__stdout__": []}
    i = 0
    while i < len(run):
        example = run[i]
        if example.kind == "sh":  # the commands of one block in one shell
            group = [example]
            while i + len(group) < len(run) and run[i + len(group)].kind == "sh" \
                    and run[i + len(group)].block == example.block:
                group.append(run[i + len(group)])
            namespace["__stdout__"].append(_bash("\n".join(e.text for e in group), folder, example.where))
            i += len(group)
            continue
        if example.kind == "python":
            code = compile("\n" * (example.line - 1) + example.text, str(ROOT / doc), "exec")
            exec(code, namespace)  # noqa: S102 - our own documents
        else:
            (folder / example.name).write_text(example.text)
        i += 1
    for example in run:
        for name in outputs(example):
            assert list(folder.glob(name)), f"{example.where}: no output {name}"
    if doc in CHECKS and run == every:
        CHECKS[doc](namespace, folder)


def test_the_documents_have_examples_and_every_exemption_is_used():
    found = {doc: examples(doc) for doc in DOCS}
    run = [e for kept, _, _ in found.values() for e in kept]
    skipped = [e for _, skipped, _ in found.values() for e, _ in skipped]
    assert len(run) >= 40, len(run)
    everything = run + skipped
    for entry in EXEMPT:
        assert any(_matches(e, entry) for e in everything), f"exemption matches no example: {entry}"
    for doc, regex, _ in SLOW:
        assert any(e.doc == doc and re.search(regex, e.text, re.M) for e in run), \
            f"SLOW matches no example: {doc} {regex}"
    assert set(EXEMPT_DOCS) <= set(DOCS)
    assert any(_is_setup(e) for e in found[SETUP_DOC][0])


@pytest.mark.parametrize("doc", [d for d in DOCS if examples(d)[2]])
def test_the_scene_file_fragments_of_a_document_are_valid(doc):
    from exabricks.scene.file import validate_scene

    for line, text in examples(doc)[2]:
        try:
            obj = json.loads("{" + text + "}")
        except json.JSONDecodeError as e:
            raise AssertionError(f"{doc}:{line}: not a JSON object's keys: {e}") from None
        validate_scene(obj, f"{doc}:{line}")


# The dataset of each scene file of docs/examples/, by the file name's first word.
SCENE_DATA = {"plume": "plume7-1.cells", "blast": "Blast.out2.00001.athdf"}


@pytest.mark.parametrize("scene", sorted(p.name for p in EXAMPLES.glob("*.json")))
def test_the_scene_files_of_the_examples_are_valid(scene):
    from exabricks.scene.file import scene_file_references

    assert SCENE_DATA.get(scene.split("-")[0]), \
        f"docs/examples/{scene}: which dataset? (SCENE_DATA, by the name's first word)"
    scene_file_references(EXAMPLES / scene)  # checked against the schema, and the files it names exist


@pytest.mark.slow
@pytest.mark.parametrize("scene", sorted(p.name for p in EXAMPLES.glob("*.json")))
def test_the_scene_files_of_the_examples_render(scene, prepared, tmp_path):
    data = SCENE_DATA[scene.split("-")[0]]
    folder = _folder(prepared, tmp_path)
    _bash(f"exabricks render {data} --scene {scene} -o scene.png", folder, f"docs/examples/{scene}")
    assert (folder / "scene.png").stat().st_size > 1000


@pytest.mark.slow
@pytest.mark.parametrize("script", sorted(p.name for p in EXAMPLES.glob("*.py")))
def test_the_scripts_of_the_examples_run_from_any_folder(script, tmp_path):
    """Each script takes `-o OUTPUT` (its default writes the docs' picture)."""
    if re.search(r"^\s*import yt\b", (EXAMPLES / script).read_text(), re.M):
        pytest.importorskip("yt")
    _bash(f"{shlex.quote(sys.executable)} {shlex.quote(str(EXAMPLES / script))} -o out.png", tmp_path,
          f"docs/examples/{script}")
    assert (tmp_path / "out.png").stat().st_size > 1000
