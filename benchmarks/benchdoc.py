"""What every benchmark in workflows/ shares: the machine line, median and
spread of repeated runs, replacing one "## section" of docs/benchmarks.md, the
common flags (--runs, --write-docs, --only), timing of calls and of child
processes (wall, CPU, peak RSS), and the benchmark inputs (the four shared real
datasets and the generated 23.6 M-cell one, made under bench-data/ on first use).

Each bench_*.py script owns one section (its heading); `replace_section` swaps
that section's text and leaves every other section as it is, so the scripts can
run in any order and `make bench` runs them all.
"""

from __future__ import annotations

import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "benchmarks.md"
INTRO = ("# Benchmarks\n\nMeasured figures of each stage and of the comparisons, with the "
         "commands that reproduce them (`make bench` runs them all).\n")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def opencl_device() -> str:
    """The OpenCL device the renderer picks by default, with its platform and version."""
    try:
        from exabricks.device import opencl

        d = opencl.choose_device(None)
        return (f"{d.name.strip()} ({d.platform.name.strip()}, {d.platform.version.strip()}, "
                f"{d.max_compute_units} compute units)")
    except Exception as e:  # noqa: BLE001 - a benchmark without OpenCL still reports the rest
        return f"unavailable ({e})"


def machine(opencl: bool = False) -> str:
    """One line: date, CPU model, cores, Python (and the OpenCL device)."""
    line = (f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {cpu_model()}, "
            f"{os.cpu_count()} cores, Python {platform.python_version()}")
    return line + (f", OpenCL: {opencl_device()}" if opencl else "")


def median_spread(values) -> tuple[float, float, float]:
    """(median, min, max) of repeated measurements."""
    v = np.asarray(values, dtype=np.float64)
    return float(np.median(v)), float(v.min()), float(v.max())


def fmt_spread(values, unit: str = "s", digits: int = 3) -> str:
    """'median (min-max)' of repeated timings, e.g. '0.352 (0.317-0.381)'."""
    m, lo, hi = median_spread(values)
    return f"{m:.{digits}f} ({lo:.{digits}f}-{hi:.{digits}f})" + (f" {unit}" if unit else "")


def ms_table(rows) -> list[str]:
    """A Markdown table of (title, {column: seconds per run}) rows: one column per key
    of the first row, each cell the median and min-max in milliseconds."""
    columns = list(rows[0][1])
    out = ["| dataset | " + " | ".join(f"{c} (ms)" for c in columns) + " |", "|---|" + "---:|" * len(columns)]
    for title, times in rows:
        out.append(f"| {title} | " + " | ".join(fmt_spread([t * 1e3 for t in times[c]], unit="", digits=1)
                                                for c in columns) + " |")
    return out


def fmt_seconds(values) -> str:
    """'median (min-max)' of timings in seconds, no unit: 2 decimals from 1 s up, else at
    least 3 significant digits ('9.19 (8.80-10.30)', '0.116 (0.100-0.200)', '0.00187 (...)')."""
    m = float(np.median(np.asarray(values, dtype=np.float64)))
    digits = 2 if m >= 1 or m <= 0 else max(3, 2 - math.floor(math.log10(m)))
    return fmt_spread(values, "", digits)


def section_file(title: str, docs: Path = DOCS) -> Path:
    """The file of docs/benchmarks.md's set (it and its files by concept,
    docs/benchmarks-*.md) that holds the section ``## {title}``: `docs` when none
    does yet (a new section goes there, listed in its contents)."""
    if docs == DOCS:
        for path in sorted(DOCS.parent.glob("benchmarks*.md")):
            if re.search(rf"^## {re.escape(title)}$", path.read_text(), re.M):
                return path
    return docs


def replace_section(title: str, body: str, docs: Path = DOCS) -> None:
    """Replace the section headed ``## {title}`` in the file of `docs`' set that
    holds it (`section_file`), or append it to `docs` and to its contents."""
    docs = section_file(title, docs)
    text = docs.read_text() if docs.exists() else INTRO
    section = f"## {title}\n\n{body.strip()}\n"
    pattern = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(text):
        text = pattern.sub(lambda _: section + "\n", text, count=1).rstrip("\n") + "\n"
    else:
        listed = list(re.finditer(r"^- \[[^\]]+\]\(#[^)]+\)$", text, re.M))
        if listed:  # the contents list its sections
            at = listed[-1].end()
            text = text[:at] + f"\n- [{title}](#{anchor(title)})" + text[at:]
        text = text.rstrip("\n") + "\n\n" + section
    tmp = docs.with_suffix(".md.tmp")
    tmp.write_text(text)
    tmp.replace(docs)


def anchor(title: str) -> str:
    """The anchor GitHub gives a heading."""
    return re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")


# ---------------------------------------------------------------------------
# Command line, timing and child processes shared by the bench_*.py scripts


def publish(title: str, body: str, write_docs: bool) -> None:
    """Print a section's body; with --write-docs also put it into docs/benchmarks.md
    (or the file by concept that holds it)."""
    print(body)
    if write_docs:
        replace_section(title, body)


def add_common_args(parser, runs: int = 5, runs_help: str | None = None) -> None:
    """--runs N (timed runs after one warm-up), --write-docs, --only KEY (repeatable)."""
    parser.add_argument("--runs", type=int, default=runs,
                        help=runs_help or f"timed runs after one warm-up (default {runs}; "
                        "figures are the median with min-max)")
    parser.add_argument("--write-docs", action="store_true",
                        help="replace this script's section of docs/benchmarks.md "
                        "(default: print only)")
    parser.add_argument("--only", action="append", metavar="KEY",
                        help="only this dataset/case (repeatable, or comma-separated; default: all)")


def chosen(only, keys) -> list[str]:
    """The keys of `keys` that --only selects (all when `only` is empty), in `keys` order."""
    if not only:
        return list(keys)
    wanted = {k.strip() for item in only for k in item.split(",") if k.strip()}
    unknown = wanted - set(keys)
    if unknown:
        raise SystemExit(f"unknown --only key(s) {', '.join(sorted(unknown))}; "
                         f"known: {', '.join(keys)}")
    return [k for k in keys if k in wanted]


def cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and its waited-for children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def timed(fn, runs: int) -> tuple[list[float], list[float]]:
    """(wall seconds, CPU seconds) of `runs` calls of `fn` after one warm-up call."""
    fn()
    walls, cpus = [], []
    for _ in range(runs):
        c, t = cpu_seconds(), time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t)
        cpus.append(cpu_seconds() - c)
    return walls, cpus


def exabricks_command() -> list[str]:
    """The `exabricks` console script next to this Python (else `python -m exabricks.cli.main`)."""
    script = Path(sys.executable).with_name("exabricks")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "exabricks.cli.main"]


# Runs a command and writes "wall cpu maxrss_kib" of it to the file argv[1].  Started
# as a small fresh process, so that the command's ru_maxrss is its own: Linux carries
# the high-water mark of the memory a process had before exec() into its
# ru_maxrss, and a child forked (or vforked) straight from a benchmark that holds
# gigabytes would report those gigabytes as its own peak.
_LAUNCHER = """
import os, sys, time
t = time.perf_counter()
pid = os.posix_spawnp(sys.argv[2], sys.argv[2:], os.environ)
_, status, ru = os.wait4(pid, 0)
wall = time.perf_counter() - t
with open(sys.argv[1], "w") as f:
    f.write(f"{wall} {ru.ru_utime + ru.ru_stime} {ru.ru_maxrss}")
sys.exit(os.waitstatus_to_exitcode(status) & 255)
"""


def tests_module(name: str):
    """The module `name` of tests/ (`helpers`, `helpers.browser`, `reference`): the
    harnesses and references the tests hold, for a benchmark that drives the same
    parts. Imported by file, under its own name, without putting tests/ on sys.path."""
    import importlib
    import importlib.machinery
    import importlib.util

    top, _, _ = name.partition(".")
    if top not in sys.modules:
        spec = importlib.machinery.PathFinder.find_spec(top, [str(ROOT / "tests")])
        module = importlib.util.module_from_spec(spec)
        sys.modules[top] = module
        spec.loader.exec_module(module)
    return importlib.import_module(name)


def run_child(args: list[str], cwd: Path = ROOT) -> tuple[float, float, int]:
    """Run `args` quietly; (wall s, CPU s, peak RSS bytes) of that command alone.

    The command runs under a tiny launcher (see _LAUNCHER) that times it and takes
    its rusage from os.wait4 (ru_maxrss: KiB on Linux).  Exits with the command's
    stderr when it fails.
    """
    env = {**os.environ, "EXABRICKS_QUIET": "1"}
    with tempfile.TemporaryFile() as err, tempfile.NamedTemporaryFile("r") as result:
        proc = subprocess.run([sys.executable, "-S", "-c", _LAUNCHER, result.name, *map(str, args)],
                              cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        if proc.returncode:
            err.seek(0)
            raise SystemExit(f"{' '.join(map(str, args))} failed ({proc.returncode}): "
                             f"{err.read().decode(errors='replace').strip()}")
        wall, cpu, maxrss_kib = result.read().split()
    return float(wall), float(cpu), int(maxrss_kib) * 1024


def fmt_bytes(n: float) -> str:
    """Bytes in binary units with 3 significant digits: '912 B', '24.5 KiB', '1.29 MiB'."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(n) < 1000 or unit == "GiB":
            break
        n /= 1024
    if unit == "B":
        return f"{int(n)} B"
    return f"{n:.3g} {unit}" if abs(n) >= 1 else f"{n:.2f} {unit}"


def load_average() -> str:
    """The 1-minute load average, for the record of a shared machine."""
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "?"


# ---------------------------------------------------------------------------
# Inputs: the four shared real datasets and the generated >= 20 M-cell one


def data_dir() -> Path:
    """Where the shared real datasets are (as tests/conftest.py looks for them)."""
    for candidate in (os.environ.get("EXABRICKS_TEST_DATA"), ROOT / "tests" / "data",
                      ROOT.parent / "shared" / "data"):
        if candidate and Path(candidate, "amrex-advection3d").is_dir():
            return Path(candidate)
    return ROOT / "tests" / "data"


def up_to_date(output: Path, source: Path | None = None) -> bool:
    """Whether a cached stage output can be reused: it exists, is not older than
    `source` (the stage's input), and a regions file was built with the current
    default merge setting (exabricks.builders.regions.Merge)."""
    output = Path(output)
    if not output.is_file():
        return False
    if source is not None and Path(source).is_file() \
            and output.stat().st_mtime_ns < Path(source).stat().st_mtime_ns:
        return False
    from exabricks import schema

    kind, _, meta = schema.peek(output)
    if kind == "regions":
        from exabricks.builders.regions import Merge

        return meta.get("parameters", {}).get("merge") == Merge().as_dict()
    return True


class Dataset:
    """A benchmark input: key, name, source path, field rendered, `exabricks ingest` flags."""

    def __init__(self, key: str, name: str, path: Path, field: str, ingest_flags=(), make=None):
        self.key, self.name, self.field = key, name, field
        self.ingest_flags = list(ingest_flags)
        self._path, self._make = Path(path), make

    @property
    def path(self) -> Path:
        """The source, made first when it is generated and missing."""
        return self._make() if self._make else self._path

    @property
    def format(self) -> str:
        f = self.ingest_flags
        return f[f.index("--format") + 1] if "--format" in f else "auto"


BENCH = ROOT / "bench-data"
BIG_RAW = BENCH / "big512.raw"
BIG_CELLS = BENCH / "big512.cells"
BIG_AMREX = BENCH / "plt_big512"


def _make_big():
    from benchmarks import make_big

    return make_big


def ensure_raw() -> Path:
    """bench-data/big512.raw: benchmarks/make_big.py's 512^3 float32 volume (made when missing)."""
    if not BIG_RAW.is_file():
        BENCH.mkdir(exist_ok=True)
        print(f"making {BIG_RAW} (benchmarks/make_big.py)", flush=True)
        _make_big().generate(BIG_RAW, 512, 7)
    return BIG_RAW


def ensure_exajet() -> Path:
    """bench-data/big512.cells (+ big512.value.scalars): the 512^3 volume merged to AMR
    (23.6 M cells, 6 levels) in ExaJet form, made when missing."""
    scalars = BIG_CELLS.with_name("big512.value.scalars")
    if BIG_CELLS.is_file() and scalars.is_file():
        return BIG_CELLS
    from exabricks.builders.uniform import amr_from_uniform

    make_big = _make_big()
    volume = np.fromfile(ensure_raw(), dtype="<f4").reshape(512, 512, 512)
    print(f"making {BIG_CELLS} (AMR merge of {BIG_RAW.name})", flush=True)
    lower, level, values = amr_from_uniform(
        volume, max_level=make_big.MAX_LEVEL, threshold=make_big.THRESHOLD)
    make_big.write_exajet(BIG_CELLS, [(lower, level, values)], ["value"])
    return BIG_CELLS


def ensure_amrex() -> Path:
    """bench-data/plt_big512: the 512^3 volume as a 3-level AMReX plotfile, made when missing."""
    if not (BIG_AMREX / "Header").is_file():
        volume = np.fromfile(ensure_raw(), dtype="<f4").reshape(512, 512, 512)
        print(f"making {BIG_AMREX} (make_big.py --amrex)", flush=True)
        _make_big().write_amrex(volume, BIG_AMREX)
    return BIG_AMREX


SHELL_CELLS = BENCH / "shell1024.cells"


def ensure_shell(size: int = 1024) -> Path:
    """bench-data/shellSIZE.cells (+ shellSIZE.rho.scalars): make_big.py's octree-like
    thin-shell layout (at 1024: 20.6 M cells on 4 levels; at 256: 1.1 M), made when
    missing."""
    cells = BENCH / f"shell{size}.cells"
    if not (cells.is_file() and cells.with_name(f"shell{size}.rho.scalars").is_file()):
        make_big = _make_big()
        BENCH.mkdir(exist_ok=True)
        print(f"making {cells} (make_big.py --thin-shell --size {size})", flush=True)
        make_big.write_exajet(cells, make_big.thin_shell_slabs(size), ["rho"])
    return cells


def datasets() -> dict[str, Dataset]:
    """The four shared real datasets and the generated big and thin-shell ones, by key."""
    data = data_dir()
    return {d.key: d for d in (
        Dataset("gerris", "Gerris plume (ExaJet)",
                ROOT / "exabricks" / "data" / "gerris-plume" / "plume7-1.cells", "T"),
        Dataset("amrex", "AMReX advection", data / "amrex-advection3d" / "plt00020", "phi"),
        Dataset("athena", "Athena++ blast", data / "athena-blast3d" / "Blast.out2.00001.athdf",
                "rho"),
        Dataset("enzo", "Enzo moving7 (yt)", data / "enzo-moving7" / "moving7_0010", "Density",
                ["--format", "yt"]),
        Dataset("big", "make_big.py 512^3 AMR (ExaJet)", BIG_CELLS, "value", make=ensure_exajet),
        Dataset("shell", "make_big.py thin shells (ExaJet)", SHELL_CELLS, "rho",
                make=ensure_shell),
    )}
