"""Kernel builds: what the first frame of each program variant costs (cold caches).

    .venv/bin/python -m benchmarks.bench_compile [--only volume,surfaces,...] [--runs 1]
                                                [--before DIR] [--write-docs]

The renderer builds one OpenCL program per variant of a frame (kernels/render.cl
with the defines of the feature table, exabricks.engine.variants). PoCL compiles
a program when it is built and its work-group function at the first enqueue,
and caches both (POCL_CACHE_DIR, pyopencl's cache under XDG_CACHE_HOME), so a
user pays this once per variant and machine: on the first render with
iso-surfaces, say. The variants are a program per axis of the table on this
machine's default device (variants.representative_frames), named by their
defines; for each, a child process with empty caches (a fresh temporary
directory for both) draws its frame of the embedded plume at 8x8 pixels twice
(exabricks.warm.draw); the build is the first frame less the second.

--before DIR also builds the kernel sources of DIR (another checkout's kernels/,
with this checkout's host code) for a column before a kernel change, variant by
variant in the same run. --write-docs replaces the "## Kernel builds" section of
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import benchdoc

ROOT = Path(__file__).resolve().parents[1]


SECTION = "Kernel builds"

def frames() -> dict:
    """Variant label -> its frame (a point of variants.AXES) on the default device."""
    from exabricks.device import opencl
    from exabricks.engine import variants

    kind = variants.device_kind(opencl.choose_device(None))
    return {v.label: f for v, f in variants.representative_frames(kind).items()}


NOTES = """
*build* is the first frame less the second, in a process whose PoCL and pyopencl
caches start empty: clBuildProgram (Clang and LLVM's optimisation of the program)
plus PoCL's work-group function for the 8x8 work-groups at the first enqueue. A
user pays it once per variant and machine; the caches keep it. The programs are
one per axis of the feature table (exabricks.engine.variants.representative_frames),
each drawn from a frame of the embedded plume. `--before DIR` adds a column of
another checkout's kernels: at e9aeb32, whose rare surface paths were inlined into
every copy of the ray loop, a surfaces program took 175-262 s where it took 8-14 s
after (docs/design-kernels.md, "Kernel builds and the host–kernel contract").
"""


def child(name: str, kernels: str | None) -> None:
    """Draw the variant's 8x8 frame twice; print the two wall times."""
    import exabricks as eb
    from exabricks.device import opencl
    from exabricks.warm import draw, embedded_dataset

    if kernels:
        opencl.kernel_dir = lambda: Path(kernels)
    axes = vars(frames()[name])
    renderer = eb.Renderer(eb.open(embedded_dataset(), cache=False))
    walls = []
    for _ in range(2):
        start = time.perf_counter()
        draw(renderer, axes)
        walls.append(time.perf_counter() - start)
    print(*walls)


def build_seconds(name: str, kernels: Path | None) -> float:
    """The variant's build in a child process with empty caches."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "POCL_CACHE_DIR": f"{tmp}/pocl", "XDG_CACHE_HOME": f"{tmp}/xdg"}
        command = [sys.executable, __file__, "--child", name, str(kernels or "")]
        proc = subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True)
        if proc.returncode:
            raise SystemExit(f"{name}: the child failed: {proc.stderr.strip()[-2000:]}")
        first, second = map(float, proc.stdout.split()[-2:])
    return first - second


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        child(argv[1], argv[2] if len(argv) > 2 else None)
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    benchdoc.add_common_args(parser, runs=1, runs_help="cold builds per variant (default 1)")
    parser.add_argument("--before", type=Path, metavar="DIR",
                        help="also build the kernel sources of DIR (a column before a change)")
    args = parser.parse_args(argv)
    names = benchdoc.chosen(args.only, list(frames()))
    rows = []
    for name in names:
        after = statistics.median(build_seconds(name, None) for _ in range(args.runs))
        row = f"| `{name}` | "
        if args.before:
            before = statistics.median(build_seconds(name, args.before) for _ in range(args.runs))
            row += f"{before:.1f} | {before / after:.1f} | "
        rows.append(row + f"{after:.1f} |")
        print(rows[-1], flush=True)
    before_head = f"before s ({args.before}) | before / now | " if args.before else ""
    body = "\n".join([
        f"`.venv/bin/python -m benchmarks.bench_compile --runs {args.runs}"
        + (f" --only {','.join(names)}" if args.only else "")
        + (f" --before {args.before}" if args.before else "") + " --write-docs`",
        "",
        f"- machine: {benchdoc.machine(opencl=True)}",
        "",
        f"| program (defines) | {before_head}build s |",
        "|---|" + "---:|" * (3 if args.before else 1),
        *rows,
        NOTES,
    ])
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
