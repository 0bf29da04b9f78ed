"""Kernel builds: what the first frame of each program variant costs (cold caches).

    .venv/bin/python -m benchmarks.bench_compile [--only volume,surfaces,...] [--runs 1]
                                                [--before DIR] [--write-docs]

The renderer builds one OpenCL program per variant of a frame (kernels/render.cl
with -D defines: sample packets or one sample at a time, surfaces, level of
detail, the reconstruction, the cell-location lookup, the number of fields).
PoCL compiles a program when it is built and its work-group function at the
first enqueue, and caches both (POCL_CACHE_DIR, pyopencl's cache under
XDG_CACHE_HOME), so a user pays this once per variant and machine: on the first
render with iso-surfaces, say. For each variant a child process with empty caches
(a fresh temporary directory for both) renders an 8x8 frame of a 64-cell,
two-field dataset twice; the build is the first frame less the second.

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

# name: (what the frame draws, Renderer keywords, scene keywords)
VARIANTS = {
    "volume": ("volume, one sample at a time (the GPU's path)", {"packets": False}, {}),
    "volume-packets": ("volume, sample packets (the CPU default)", {"packets": True}, {}),
    "surfaces": ("iso-surface in the volume, one sample at a time", {"packets": False},
                 {"iso": True}),
    "surfaces-packets": ("iso-surface in the volume, sample packets", {"packets": True},
                         {"iso": True}),
    "surfaces-2-fields": ("iso-surface coloured by a second field, sample packets",
                          {"packets": True}, {"iso": True, "color_field": True}),
    "lod": ("volume with level of detail (`--lod`), sample packets", {"packets": True},
            {"lod": 3.0}),
    "nearest": ("iso-surface in the volume, nearest-cell reconstruction", {},
                {"iso": True, "reconstruction": "nearest"}),
    "vertex": ("iso-surface in the volume, vertex reconstruction", {},
               {"iso": True, "reconstruction": "vertex"}),
    "cell-location": ("volume, cell-location lookup", {"lookup": "cell-location"}, {}),
}

NOTES = """
*build* is the first frame less the second, in a process whose PoCL and pyopencl
caches start empty: clBuildProgram (Clang and LLVM's optimisation of the program)
plus PoCL's work-group function for the 8x8 work-groups at the first enqueue. A
user pays it once per variant and machine; the caches keep it. The before column
builds the kernels of e9aeb32 (`git worktree add /tmp/before-e9aeb32 e9aeb32`), with
the same host code: there the rare surface paths were still inlined into every copy
of the ray loop (docs/design-kernels.md, "Kernel builds and the host–kernel contract").
"""


def child(name: str, kernels: str | None) -> None:
    """Render the variant's 8x8 frame twice; print the two wall times."""
    import numpy as np

    from exabricks.device import opencl
    from exabricks import schema
    from exabricks.picture.camera import default_camera
    from exabricks.scene import IsoSurface, Scene, Settings, VolumeLayer
    from exabricks.builders.bricks import build_bricks
    from exabricks.builders.bvh import build_bvh
    from exabricks.builders.regions import build_regions
    from exabricks.engine.renderer import Renderer
    from exabricks.picture.transfer_function import TransferFunction

    if kernels:
        opencl.kernel_dir = lambda: Path(kernels)
    _, renderer_kw, scene_kw = VARIANTS[name]
    g = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    ramp = np.linspace(0, 1, len(g), dtype=np.float32)
    cells = schema.Cells(fields=("a", "b"), origin_world=np.zeros(3), spacing_world=np.ones(3),
                         lower_lattice=g.astype(np.int32), level=np.zeros(len(g), np.int8),
                         values=np.stack([ramp, ramp[::-1]]))
    bricks = build_bricks(cells)
    regions = build_regions(bricks)
    tf = TransferFunction.from_colormap("viridis", (0.0, 1.0), opacity=(0.0, 0.3))
    iso = ()
    if scene_kw.get("iso"):
        color = {"color_field": "b", "colormap": tf} if scene_kw.get("color_field") else {}
        iso = (IsoSurface("a", 0.5, opacity=0.6, **color),)
    scene = Scene(camera=default_camera(*schema.world_bounds(bricks)),
                  volumes=(VolumeLayer("a", tf),), isosurfaces=iso,
                  settings=Settings(width=8, height=8, lod=scene_kw.get("lod", 0.0),
                                    reconstruction=scene_kw.get("reconstruction", "basis")))
    lookup = renderer_kw.get("lookup")
    renderer = Renderer(bricks, regions, build_bvh(regions), fields=scene.fields(),
                        packets=renderer_kw.get("packets"))
    if lookup:
        renderer = renderer.with_lookup(lookup)
    walls = []
    for _ in range(2):
        start = time.perf_counter()
        renderer.render_scene(scene)
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
    names = benchdoc.chosen(args.only, list(VARIANTS))
    rows = []
    for name in names:
        after = statistics.median(build_seconds(name, None) for _ in range(args.runs))
        row = f"| `{name}` | {VARIANTS[name][0]} | "
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
        f"| variant | frame | {before_head}build s |",
        "|---|---|" + "---:|" * (3 if args.before else 1),
        *rows,
        NOTES,
    ])
    benchdoc.publish(SECTION, body, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
