"""The kernels of a git revision against the working tree's, on bench_peers' frames.

    .venv/bin/python -m benchmarks.ab_kernels [--base HEAD | --base-dir DIR]
        [--base-options=...] [--options=...] [--datasets gerris,shell256]
        [--rates 2] [--rounds 5] [--size 1024] [--shading none]

A kernel change is measured here before it is kept (docs/design.md quotes these
ratios): both versions render the same frames (bench_peers' camera, transfer
function, opacity unit, seed and early termination) with the same uploaded scene,
alternating frame by frame in one process, so that the load of this machine hits
both alike (bench_peers.interleaved); after one warm-up frame each, the median kernel time of --rounds frames
(min-max) and base / this is printed, with the sample counts and the largest
difference between the two images. The base kernels are `git show REV:kernels/...`
in a temporary directory, or the kernels/ folder --base-dir names (a copy of an
older tree, where git is not at hand); each version's programs are kept apart by
swapping exabricks.opencl's program and kernel caches (keyed by context and defines,
not by directory), its kernel directory and its build options. --options (and
--base-options) add OpenCL build options to this (the base) version, so that one
kernel tree can be measured against itself with and without them: a define
(`--options=-DEB_QUEUE_SIZE=16`, the walk's heap) or a driver's option
(`--options=-cl-nv-maxrregcount=64` on NVIDIA's; the `=` keeps argparse from
reading the value as a flag).
"""
from __future__ import annotations

import argparse
import contextlib
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from benchmarks import bench_peers
from benchmarks import benchdoc

ROOT = Path(__file__).resolve().parents[1]


def base_kernels(rev: str, into: Path) -> Path:
    """The kernels/ files of git revision `rev`, written under `into`."""
    names = subprocess.run(["git", "-C", str(ROOT), "ls-tree", "--name-only", rev, "kernels/"],
                           check=True, capture_output=True, text=True).stdout.split()
    for name in names:
        data = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{name}"], check=True,
                              capture_output=True).stdout
        (into / Path(name).name).write_bytes(data)
    return into


def use(version: dict) -> None:
    """Make exabricks.opencl build and cache programs from `version`'s kernel directory,
    with its build options."""
    from exabricks import opencl
    opencl._PROGRAMS = version["programs"]
    opencl._KERNELS = version["kernels"]
    opencl.kernel_dir = lambda: version["dir"]
    opencl.BUILD_OPTIONS = version["options"]


@contextlib.contextmanager
def versions_of(*dirs: Path, options=((), ())):
    """{"base": ..., "this": ...} versions of the kernel directories `dirs`, each with
    program and kernel caches of its own and exabricks.opencl.BUILD_OPTIONS plus its
    entry of `options`; exabricks.opencl's own come back afterwards."""
    from exabricks import opencl
    saved = opencl._PROGRAMS, opencl._KERNELS, opencl.kernel_dir, opencl.BUILD_OPTIONS
    try:
        yield {v: {"dir": d, "programs": {}, "kernels": {},
                   "options": (*opencl.BUILD_OPTIONS, *extra)}
               for v, d, extra in zip(("base", "this"), dirs, options)}
    finally:
        opencl._PROGRAMS, opencl._KERNELS, opencl.kernel_dir, opencl.BUILD_OPTIONS = saved


def compare(name: str, versions: dict, rates, rounds: int, size: int, shading: str) -> list[str]:
    from exabricks.render.renderer import Renderer

    if name == "shell256":
        benchdoc.ensure_shell(256)
    path, field, _ = bench_peers.DATASETS[name]
    cells, bricks, regions, bvh, _, _ = bench_peers.build_scene(path, field)
    camera, tf, bounds, _ = bench_peers.view_of(cells, bench_peers.ALPHA_SCALE)
    unit = bench_peers.opacity_unit(bounds)
    renderer = Renderer(bricks, regions, bvh)

    def frame(version, rate):
        def render():
            use(version)
            result = renderer.render(camera=camera, transfer_function=tf, width=size,
                                     height=size, sampling_rate=rate, seed=bench_peers.SEED,
                                     jitter=True, max_opacity=bench_peers.MAX_OPACITY,
                                     unit_distance=unit, shading=shading)
            return result.stats["ms"] / 1e3, result.stats["samples"], result.rgba
        return render

    lines = []
    for rate in rates:
        measured, images = bench_peers.interleaved(
            {v: frame(version, rate) for v, version in versions.items()}, rounds)
        ms = {v: [1e3 * t for t in measured[v]["kernel_s"]] for v in versions}
        base, this = (statistics.median(ms[v]) for v in versions)
        diff = float(np.abs(images["base"] - images["this"]).max())
        lines.append(f"{name} rate {rate:g} {shading}: base {base:.0f} ms "
                     f"({min(ms['base']):.0f}-{max(ms['base']):.0f}), this {this:.0f} ms "
                     f"({min(ms['this']):.0f}-{max(ms['this']):.0f}), base / this "
                     f"{base / this:.3f}; samples {measured['base']['samples']:,} / "
                     f"{measured['this']['samples']:,}; max abs diff {diff:.2e}")
        print(lines[-1], flush=True)
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--base", default="HEAD", help="git revision of the base kernels")
    p.add_argument("--base-dir", type=Path, help="the base kernels from this folder instead")
    p.add_argument("--base-options", default="", help="OpenCL build options added to the base")
    p.add_argument("--options", default="", help="OpenCL build options added to this version")
    p.add_argument("--datasets", default="gerris,shell256")
    p.add_argument("--rates", default="2", help="samples per finest cell, comma-separated")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--shading", default="none", choices=("none", "headlight"))
    args = p.parse_args(argv)
    from exabricks import opencl

    rates = [float(r) for r in args.rates.split(",")]
    options = (tuple(shlex.split(args.base_options)), tuple(shlex.split(args.options)))
    with tempfile.TemporaryDirectory(prefix="ab-kernels-") as tmp:
        base = args.base_dir or base_kernels(args.base, Path(tmp))
        if not (Path(base) / opencl.ENTRY_SOURCE).is_file():
            p.error(f"{base}: no {opencl.ENTRY_SOURCE} there")
        with versions_of(Path(base), opencl.kernel_dir(), options=options) as versions:
            for name in benchdoc.chosen([args.datasets], list(bench_peers.DATASETS)):
                compare(name, versions, rates, args.rounds, args.size, args.shading)
    return 0


if __name__ == "__main__":
    sys.exit(main())
