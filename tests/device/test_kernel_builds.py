"""Kernel builds: a build that takes long says so on a terminal and nowhere else
(exabricks.util.progress.waiting in exabricks.device.opencl), and `exabricks devices --warm`
builds every program that a default render and `make demo`'s picture need."""

from __future__ import annotations

import fcntl
import os
import pty
import re
import shlex
import struct
import subprocess
import sys
import termios

import pytest
from click.testing import CliRunner

from helpers import DEVICES, GERRIS, ROOT

pytestmark = pytest.mark.skipif(not DEVICES, reason="no OpenCL device")

# A program build (from the driver's cache, with half a second added to stand for a
# compile) in a fresh process, announced after 0.1 s.
BUILD = """
import logging, sys, time
import pyopencl as cl
from exabricks.device import opencl
from exabricks.engine import variants
if sys.argv[1:] == ["-v"]:
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
build = cl.Program.build
def slow(self, *a, **kw):
    time.sleep(0.5)
    return build(self, *a, **kw)
cl.Program.build = slow
context = opencl.context_for(opencl.choose_device(None))[0]
opencl.program_for(context, variants.variant().defines)
print("built", len(opencl.BUILDS))
"""
NOTICE = "compiling the renderer for "


def run_build(*args, tty: bool, columns: int = 160) -> tuple[str, str]:
    """(stdout, stderr) of BUILD, its stderr a pseudo-terminal of `columns` or a pipe."""
    env = {**os.environ, "EXABRICKS_ANNOUNCE_AFTER": "0.1"}
    env.pop("EXABRICKS_QUIET", None)
    command = [sys.executable, "-c", BUILD, *args]
    if not tty:
        proc = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout, proc.stderr
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    out = proc.stdout.read().decode()
    assert proc.wait(timeout=300) == 0
    return out, b"".join(chunks).decode()


def test_a_long_build_says_so_on_a_terminal_only():
    out, terminal = run_build(tty=True)
    assert out.strip() == "built 1"
    assert NOTICE in terminal and "(first use of these options; cached afterwards)" in terminal
    assert re.search(r" \d+ s [|/\\-]", terminal)  # the seconds tick, with a spinner
    assert terminal.endswith("\r\x1b[K")  # the line goes when the build is done
    _, narrow = run_build(tty=True, columns=60)  # a line never wraps
    drawn = [line for line in narrow.replace("\x1b[K", "").split("\r") if line]
    assert drawn and all(len(line) < 60 for line in drawn) and drawn[0].startswith(NOTICE)
    out, log = run_build(tty=False)
    assert out.strip() == "built 1" and log == ""  # a batch log: nothing
    out, log = run_build("-v", tty=False)  # -v in a batch log: one line, no spinner
    lines = log.splitlines()
    assert len(lines) == 1 and lines[0].startswith(NOTICE) and re.search(r"took \d+\.\d s$", lines[0])
    assert "\r" not in log and "\x1b" not in log


def test_a_quick_wait_stays_silent_on_a_terminal(monkeypatch):
    from exabricks.util import progress

    class Terminal:
        def __init__(self):
            self.text = ""

        def isatty(self):
            return True

        def write(self, s):
            self.text += s

        def flush(self):
            pass

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.delenv("EXABRICKS_QUIET", raising=False)
    with progress.waiting("compiling", after=5.0) as wait:
        pass
    assert not wait.shown and terminal.text == ""
    with progress.waiting("compiling", after=0.0) as wait:
        import time

        time.sleep(0.3)
    assert wait.shown and "compiling" in terminal.text and terminal.text.endswith("\r\x1b[K")


def demo_render_flags() -> list[str]:
    """The flags of the Makefile's `$(OUT)/plume.png` render (make demo's picture)."""
    text = (ROOT / "Makefile").read_text().replace("\\\n", " ")
    rule = text[text.index("$(OUT)/plume.png:"):]
    line = next(l for l in rule.splitlines() if " render " in l)
    flags = shlex.split(line.split("-o $@", 1)[1])
    return [f.replace("$(DATA)", str(GERRIS.parent)) for f in flags]


def test_warm_builds_what_the_default_and_demo_renders_need(tmp_path):
    """After `devices --warm`, neither a default render of the embedded dataset nor
    make demo's render (its flags read from the Makefile) builds a program."""
    from exabricks.device import opencl
    from exabricks.cli.main import cli

    runner = CliRunner()
    warm = runner.invoke(cli, ["devices", "--warm", "--json"])
    assert warm.exit_code == 0, warm.output
    assert "--warm" in (ROOT / "Makefile").read_text().split("$(OUT)/plume.png:")[1].split(" render ")[0]
    built = len(opencl.BUILDS)
    for name, flags in (("default", []), ("demo", demo_render_flags())):
        assert name == "default" or "--iso" in flags
        result = runner.invoke(cli, ["render", str(GERRIS), "-o", str(tmp_path / f"{name}.png"),
                                     *flags, "--size", "16", "16"])
        assert result.exit_code == 0, result.output
        assert (tmp_path / f"{name}.png").is_file()
        assert len(opencl.BUILDS) == built, f"the {name} render built {opencl.BUILDS[built:]}"


@pytest.mark.slow
def test_after_warm_in_a_new_kernel_cache_a_default_render_compiles_nothing(tmp_path):
    """Across processes, with PoCL's kernel cache empty at first: `devices --warm`
    compiles (and says so with -v), a default render afterwards compiles nothing:
    neither a program nor a work-group function."""
    env = {**os.environ, "POCL_CACHE_DIR": str(tmp_path / "pocl")}
    eb = [sys.executable, "-m", "exabricks.cli.main", "-v"]
    warm = subprocess.run([*eb, "devices", "--warm"], env=env, capture_output=True, text=True,
                          timeout=600)
    assert warm.returncode == 0, warm.stderr
    assert "kernels ready for a volume (the default render)" in warm.stdout
    if "Portable Computing Language" in warm.stdout:  # PoCL: its cache started empty
        assert "compiling the renderer for " in warm.stderr
    render = subprocess.run([*eb, "render", str(GERRIS), "-o", str(tmp_path / "a.png"), "--size",
                             "32", "32"], env=env, capture_output=True, text=True, timeout=600)
    assert render.returncode == 0, render.stderr
    assert "compiling" not in render.stderr, render.stderr


def test_warm_draws_each_frame_with_the_program_the_table_names():
    """`devices --warm` (the first pictures) builds exactly the programs that the
    feature table gives their frames, one frame each, on the default device."""
    from exabricks.device import opencl
    from exabricks.engine import variants
    from exabricks.warm import FIRST, warm

    kind = variants.device_kind(opencl.choose_device(None))
    before = len(opencl.BUILDS)
    rows = warm(None, "first")
    built = [defines for source, defines, _ in opencl.BUILDS[before:] if source == opencl.ENTRY_SOURCE]
    want = {variants.program_variant(variants.frame(kind=kind, **axes)).defines for _, axes in FIRST}
    assert [r["frame"] for r in rows] == [what for what, _ in FIRST]
    assert set(built) <= want  # this process may hold some already
    warmed = {defines for _, defines, _ in opencl.BUILDS if defines in want}
    assert warmed == want


@pytest.mark.slow
def test_warm_all_builds_every_declared_program():
    """`devices --warm all`: every program a frame of one field can reach on the
    device, each drawn by a frame of its own axes."""
    from exabricks.device import opencl
    from exabricks.engine import variants
    from exabricks.warm import warm

    kind = variants.device_kind(opencl.choose_device(None))
    rows = warm(None, "all")
    want = {v.defines for v in variants.declared(kind)}
    assert len(rows) == len(want)
    warmed = {defines for _, defines, _ in opencl.BUILDS if defines in want}
    assert warmed == want


@pytest.mark.parametrize("integrator", ["headlight", "shadow"])
def test_what_a_frame_changes_per_frame_builds_nothing(integrator):
    """After one frame, another camera, transfer function, iso-value, seed, light
    direction, exposure or size draws with the same program: no build."""
    import exabricks as eb
    from exabricks.device import opencl

    ds = eb.open(GERRIS, fields=["T", "P"], cache=False)
    base = dict(field="T", size=(16, 16), integrator=integrator, iso=[0.45], seed=1)
    if integrator != "headlight":
        base["light"] = (1, 0, 0)
    eb.render(ds, **base)
    built = len(opencl.BUILDS)
    (lo, hi) = ds.bounds
    for change in (dict(position=tuple(2 * h - l for l, h in zip(lo, hi)), look_at=ds.bounds[0]),
                   dict(colormap="inferno", range=(0.0, 0.5)), dict(iso=[0.3]), dict(seed=7),
                   dict(exposure=1.5), dict(size=(24, 12)),
                   *([dict(light=(0, 1, 1))] if integrator != "headlight" else [])):
        eb.render(ds, **{**base, **change})
        assert len(opencl.BUILDS) == built, (change, opencl.BUILDS[built:])
