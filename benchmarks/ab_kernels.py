"""Two versions of exabricks, host code and kernels, on the same frames in one process.

    .venv/bin/python -m benchmarks.ab_kernels [--base HEAD | --base-dir DIR]
        [--base-options=...] [--options=...] [--datasets gerris,amrex,athena,enzo]
        [--variants all] [--rounds 5] [--size 512] [--rate 2] [--timed volume]

A change to the renderer is measured here before it is kept. The base version is
the `exabricks` package and `kernels/` of git revision --base (extracted into a
temporary folder), or of the checkout at --base-dir, imported under the name
`exabricks_base` beside the working tree's `exabricks`. Each version reads and
builds the dataset with its own code and renders with its own Renderer, so a
new kernel signature or new host code is compared as a whole.

For every dataset and every variant (VARIANTS: one scene for each kernel
program a frame can reach), both versions render the same frame and the largest
absolute difference of the two images is printed (0: the arithmetic did not
change), and the same for probed values. The --timed variants' frames then
alternate for --rounds rounds after a warm-up frame each (benchmarks.peers.common.interleaved),
so that the load of this machine hits both alike, and the median kernel time
(min-max) of each and base / this are printed.

--options (and --base-options) add OpenCL build options to this (the base)
version: a define (`--options=-DEB_QUEUE_SIZE=16`) or a driver's option
(`--options=-cl-nv-maxrregcount=64`; the `=` keeps argparse from reading the
value as a flag), so that `--base-dir .` measures the tree against itself.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import shlex
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np
from benchmarks import benchdoc
from benchmarks.peers import common as peers

ROOT = Path(__file__).resolve().parents[1]
BASE_NAME = "exabricks_base"

# A second field per dataset, for the variants that need two (none: the variant is
# skipped there).
SECOND_FIELD = {"gerris": "U", "athena": "press", "enzo": "Density"}


def _volume(field, alpha=0.1):
    return {"field": field, "transfer_function": {"colormap": "viridis", "opacity": [0, alpha]}}


def _surfaces(field, second, lo, hi, value):
    mid = [(a + b) / 2 for a, b in zip(lo, hi)]
    return {"volumes": [_volume(field, 0.05)],
            "isosurfaces": [{"field": field, "value": value, "color": [1, 0.5, 0.2],
                             "opacity": 0.7}],
            "slices": [{"point": mid, "normal": [0, 0, 1], "field": field, "opacity": 0.6}],
            "clip": {"box": [*lo, *hi[:2], mid[2] + (hi[2] - mid[2]) / 2],
                     "planes": [[*mid, 1, 0.2, 0]]},
            "lighting": {"specular": 0.3, "ambient_occlusion": {"samples": 4}}}


# name: (scene file of (field, second field, world lower, upper, a mid value), Renderer
# keyword arguments, needs a second field)
# volume: one volume layer, unshaded; shaded-single: shaded, one sample at a time
# (no packets); surfaces: iso-surface, slice, clip box and plane, specular, AO;
# lod-central: level of detail with central-difference gradients; two-fields:
# two volume layers and an iso-surface coloured by the second field.
VARIANTS = {
    "volume": (lambda f, s, lo, hi, v: {"volumes": [_volume(f)], "lighting": {"shading": "none"}},
               {}, False),
    "shaded": (lambda f, s, lo, hi, v: {"volumes": [_volume(f)]}, {}, False),
    "shaded-single": (lambda f, s, lo, hi, v: {"volumes": [_volume(f)]},
                                     {"packets": False}, False),
    "nearest": (lambda f, s, lo, hi, v: {"volumes": [_volume(f)], "reconstruction": "nearest"},
                {}, False),
    "vertex": (lambda f, s, lo, hi, v: {"volumes": [_volume(f)], "reconstruction": "vertex"},
               {}, False),
    "surfaces": (_surfaces, {}, False),
    "lod-central": (
        lambda f, s, lo, hi, v: {"volumes": [_volume(f)], "lod": 1.0,
                                 "lighting": {"gradient": "central"}}, {}, False),
    "cell-location": (lambda f, s, lo, hi, v: {"volumes": [_volume(f)]},
                      {"lookup": "cell-location"}, False),
    "two-fields": (lambda f, s, lo, hi, v: {
        "volumes": [_volume(f), _volume(s, 0.05)],
        "isosurfaces": [{"field": f, "value": v, "color": {"field": s}}]}, {}, True),
}


def base_package(rev: str, into: Path) -> Path:
    """The exabricks/ and kernels/ folders of git revision `rev`, extracted under `into`."""
    archive = into / "base.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), rev,
                    "exabricks", "kernels"], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into


def import_version(root: Path, name: str):
    """The exabricks package of checkout `root` imported as `name` (its imports
    within the package are relative, so it runs beside the working tree's)."""
    if name == "exabricks":
        return importlib.import_module(name)
    package = root / "exabricks"
    spec = importlib.util.spec_from_file_location(
        name, package / "__init__.py", submodule_search_locations=[str(package)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


class Version:
    """One version's package and the dataset built with it."""

    def __init__(self, package: str, options):
        self.name = package
        self.opencl = self.module("device.opencl", "opencl")
        self.opencl.BUILD_OPTIONS = (*self.opencl.BUILD_OPTIONS, *options)

    def module(self, *names):
        """The first of `names` (the package's name for a module now, then its
        earlier names) that this version has."""
        for name in names:
            try:
                return importlib.import_module(f"{self.name}.{name}")
            except ModuleNotFoundError:
                continue
        raise ModuleNotFoundError(f"{self.name} has none of {names}")

    def build(self, path: Path, fields):
        cells = self.module("readers").read(path, fields=list(fields))
        bricks = self.module("builders.bricks", "stages.brick").build_bricks(cells)
        regions = self.module("builders.regions", "stages.regions").build_regions(bricks)
        bvh = self.module("builders.bvh", "stages.bvh").build_bvh(regions)
        self.structures = bricks, regions, bvh
        return cells

    def renderer(self, fields, **kw):
        # before the library's eb.render, and before 19d5715
        module = self.module("engine.renderer", "render.renderer", "stages.render")
        return module.Renderer(*self.structures, fields=fields, **kw)

    def scene(self, scene_file: Path, flags: dict):
        return self.module("scene").scene_from_options(
            self.structures[0], scene_path=scene_file, flags=flags)


@contextlib.contextmanager
def versions_of(base_root: Path, base_options=(), options=()):
    """{"base": Version, "this": Version}: the package of checkout `base_root` and the
    working tree's, with their build options extended; exabricks.device.opencl's options
    come back, and the base package leaves sys.modules, afterwards."""
    from exabricks.device import opencl

    saved = opencl.BUILD_OPTIONS
    import_version(base_root, BASE_NAME)
    try:
        yield {"base": Version(BASE_NAME, base_options), "this": Version("exabricks", options)}
    finally:
        opencl.BUILD_OPTIONS = saved
        for name in [m for m in sys.modules if m == BASE_NAME or m.startswith(BASE_NAME + ".")]:
            del sys.modules[name]


def compare(name: str, versions: dict, variants, timed, rounds: int, size: int,
            workdir: Path, rate: float = 2.0) -> list[str]:
    import json

    if name == "shell256":
        benchdoc.ensure_shell(256)
    path, field, _ = peers.DATASETS[name]
    second = SECOND_FIELD.get(name)
    fields = (field, second) if second else (field,)
    for v in versions.values():
        cells = v.build(path, fields)
    lo, hi = (np.asarray(b, np.float64) for b in versions["this"].module("schema").world_bounds(cells))
    values = cells.values[0][np.isfinite(cells.values[0])]
    mid_value = float(np.quantile(values, 0.7))
    unit = peers.opacity_unit((lo, hi))
    points = lo + (hi - lo) * np.random.default_rng(0).random((4096, 3))
    lines = []
    for variant in variants:
        make, options, needs_second = VARIANTS[variant]
        if needs_second and not second:
            continue
        doc = make(field, second, lo.tolist(), hi.tolist(), mid_value)
        doc.setdefault("unit_distance", unit)
        doc.setdefault("sampling_rate", rate)
        # The scalar settings and the lighting go as flags: an older base reads the
        # working tree's scene schema (importlib.resources finds the package named
        # exabricks), whose scalar nodes are made at run time since 2026-12-05.
        flags = {"size": (size, size), **{k: doc.pop(k) for k in
                                          ("reconstruction", "lod", "unit_distance", "sampling_rate")
                                          if k in doc}}
        lighting = doc.pop("lighting", {})
        ao = lighting.pop("ambient_occlusion", {})
        flags.update(lighting, **({"ao_samples": ao["samples"]} if ao else {}))
        scene_file = workdir / f"{name}-{len(lines)}.json"
        scene_file.write_text(json.dumps(doc))
        used = tuple(dict.fromkeys([field] + ([second] if needs_second else [])))
        renderers = {k: v.renderer(used, **options) for k, v in versions.items()}
        scenes = {k: v.scene(scene_file, flags) for k, v in versions.items()}

        def frame(k, renderers=renderers, scenes=scenes):
            def render():
                result = renderers[k].render_scene(scenes[k])
                return result.stats["ms"] / 1e3, result.stats["samples"], result.rgba
            return render

        if variant in timed:
            measured, images = peers.interleaved({k: frame(k) for k in versions}, rounds)
        else:
            images = {k: frame(k)()[2] for k in versions}
        diff = float(np.abs(images["base"] - images["this"]).max())
        # (a base from before the rename calls the dataset on the device `scene`, and
        # one older still has no probe_fields on it)
        on_device = {k: r.dataset if hasattr(r, "dataset") else r.scene for k, r in renderers.items()}
        probe = "n/a"
        if all(hasattr(d, "probe_fields") for d in on_device.values()):
            probed = {k: d.probe_fields(points) for k, d in on_device.items()}
            probe = f"{float(np.nanmax(np.abs(probed['base'] - probed['this']), initial=0.0)):.2e}"
        line = (f"{name} {variant}: mean alpha {float(images['this'][..., 3].mean()):.3f}, "
                f"max abs diff image {diff:.2e}, probe {probe}")
        if variant in timed:
            ms = {k: [1e3 * t for t in measured[k]["kernel_s"]] for k in versions}
            base, this = (statistics.median(ms[k]) for k in versions)
            line += (f"; base {base:.0f} ms ({min(ms['base']):.0f}-{max(ms['base']):.0f}), "
                     f"this {this:.0f} ms ({min(ms['this']):.0f}-{max(ms['this']):.0f}), "
                     f"base / this {base / this:.3f}")
        lines.append(line)
        print(line, flush=True)
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--base", default="HEAD", help="git revision of the base version")
    p.add_argument("--base-dir", type=Path, help="the base from this checkout instead")
    p.add_argument("--base-options", default="", help="OpenCL build options added to the base")
    p.add_argument("--options", default="", help="OpenCL build options added to this version")
    p.add_argument("--datasets", default="gerris,amrex,athena,enzo")
    p.add_argument("--variants", default="all", help=f"of: {', '.join(VARIANTS)}")
    p.add_argument("--timed", default="volume", help="variants whose frame times are compared")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--rate", type=float, default=2.0, help="samples per finest cell")
    args = p.parse_args(argv)
    variants = benchdoc.chosen([] if args.variants == "all" else [args.variants], list(VARIANTS))
    timed = benchdoc.chosen([args.timed], list(VARIANTS))
    with tempfile.TemporaryDirectory(prefix="ab-kernels-") as tmp:
        base_root = args.base_dir or base_package(args.base, Path(tmp))
        if not (Path(base_root) / "exabricks" / "__init__.py").is_file():
            p.error(f"{base_root}: no exabricks package there")
        with versions_of(Path(base_root), shlex.split(args.base_options),
                         shlex.split(args.options)) as versions:
            for name in benchdoc.chosen([args.datasets], list(peers.DATASETS)):
                compare(name, versions, variants, timed, args.rounds, args.size, Path(tmp),
                        args.rate)
    return 0


if __name__ == "__main__":
    sys.exit(main())
