"""Benchmark every render mode (docs/scene.md) on the Gerris plume and the AMReX plotfile.

    .venv/bin/python -m benchmarks.bench_modes [--runs 5] [--size 512] [--only gerris,amrex]
                                              [--mode volume,iso,...] [--list] [--write-docs]

Each dataset goes through the `exabricks` stage commands once (ingest, brick,
regions, bvh; cached under bench-data/gallery/<dataset>/ as by benchmarks/gallery.py,
not timed). Each mode is a list of `exabricks render` flags (MODES below, printed
by --list), parsed by the CLI's own option parser and turned into a Scene by
exabricks.scene.scene_from_options, exactly as `exabricks render` does; the
frame is then drawn in-process by exabricks.engine.renderer.Renderer(bricks,
regions, bvh, fields=scene.fields()).render_scene(scene): one Renderer per set
of fields (uploaded once), one warm-up frame per mode (it also builds the
program variant), then --runs rounds of one timed frame of every mode (so that
a change in the machine's load hits every mode alike). Every frame is size x
size with one sample per pixel (`--spp 1` overrides the scene file's), the
dataset's gallery camera and the render defaults otherwise.

Reported per mode: the kernel time of a frame (`RenderResult.stats["ms"]`:
enqueue to finish, no upload or read-back; median and min-max), its ratio to
the plain volume of the same dataset, and the reconstructed samples of the
volume integration. --write-docs replaces the "## render modes" section of
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks import gallery

from exabricks import schema
from exabricks.scene import FLAGS, scene_from_options
from exabricks.engine.renderer import Renderer

ROOT = Path(__file__).resolve().parents[1]


SECTION = "render modes"
DATASETS = ("gerris", "amrex")

# Per dataset: the camera, the volume (field and transfer function), and the values
# the modes use (iso-values, a second field, clip box and plane, slices): the
# choices of docs/gallery.md (benchmarks/gallery.py), from `exabricks info`.
SETUP = {
    "gerris": dict(
        cam=gallery.G_CAM, field="T", tf=gallery.G_TF,
        iso="--iso 0.3", iso_fixed="--iso-color 1,0.85,0.6",
        shells="--iso 0.05 --iso 0.2 --iso 0.5 --iso-opacity 0.4 --iso-color-field T "
               "--iso-colormap plasma --iso-range 0 0.6",
        colored="--iso 0.1 --iso-color-field W --iso-colormap coolwarm --iso-range -0.06 0.06",
        box="--clip-box 0 0 0 64 128 64", plane="--clip-plane 64 33 64 -1 0.6 -1",
        slices="--slice 64 33 64 1 0 0 --slice 64 22 64 0 1 0 --slice-colormap YlGnBu "
               "--slice-range 0 0.5",
        oblique="--slice 64 33 64 1 0.7 -0.5 --slice-colormap YlGnBu --slice-range 0 0.5",
        ao_iso="--field U --iso -0.03 --iso 0.03 --iso-color 0.9,0.8,0.7",
        layers=f"--scene {gallery.EXAMPLES}/plume-layers.json",
        scene=f"--scene {gallery.EXAMPLES}/plume-scene.json"),
    "amrex": dict(
        cam=gallery.X_CAM, field="phi", tf=gallery.X_TF,
        iso="--iso 1.5", iso_fixed="--iso-color 1,0.6,0.3",
        shells="--iso 1.1 --iso 1.5 --iso 1.9 --iso-opacity 0.4 --iso-color-field phi "
               "--iso-colormap viridis --iso-range 1 1.97",
        colored="--iso 1.5 --iso-color-field phi --iso-colormap viridis --iso-range 1 1.97",
        box="--clip-box 0 0 0 1 1 0.5", plane="--clip-plane 0.5 0.5 0.5 0 0 -1",
        slices="--slice 0.5 0.5 0.5 0 0 1 --slice 0.68 0.5 0.5 1 0 0 --slice-colormap viridis "
               "--slice-range 1 1.97",
        oblique="--slice 0.5 0.5 0.5 1 1 0 --slice-colormap viridis --slice-range 1 1.97",
        ao_iso="--field phi --iso 1.5 --iso-color 1,0.6,0.3",
        layers=None, scene=None),
}

# mode: (what it draws, flags with {placeholders} from SETUP)
MODES = {
    "volume": ("volume, headlight (the default shading)", "{cam} {tf}"),
    "volume-unshaded": ("volume, `--shading none`", "{cam} {tf} --shading none"),
    "volume-central": ("volume, `--gradient central`", "{cam} {tf} --gradient central"),
    "background": ("volume over `--background` (composited on the host)",
                   "{cam} {tf} --background 0.05,0.05,0.08"),
    "iso": ("one opaque iso-surface, no volume", "{cam} --field {field} --no-volume {iso} {iso_fixed}"),
    "iso-central": ("the same, `--gradient central`",
                    "{cam} --field {field} --no-volume {iso} {iso_fixed} --gradient central"),
    "iso-volume": ("iso-surface inside the volume", "{cam} {tf} {iso} {iso_fixed}"),
    "shells": ("three translucent iso-surfaces coloured by a field, no volume",
               "{cam} --field {field} --no-volume {shells}"),
    "iso-colored": ("iso-surface coloured by a second field, no volume",
                    "{cam} --field {field} --no-volume {colored}"),
    "ao-off": ("two iso-surfaces, no volume", "{cam} --no-volume {ao_iso}"),
    "ao-on": ("the same with 16 ambient-occlusion rays per hit",
              "{cam} --no-volume {ao_iso} --ao-samples 16"),
    "ao-volume": ("iso-surface in the volume, 16 ambient-occlusion rays (through the volume)",
                  "{cam} {tf} {iso} {iso_fixed} --ao-samples 16"),
    "clip-box": ("volume and iso-surface in a clip box", "{cam} {tf} {iso} {iso_fixed} {box}"),
    "clip-plane": ("volume and iso-surface cut by a plane", "{cam} {tf} {iso} {iso_fixed} {plane}"),
    "slices": ("two axis-aligned slices with the volume", "{cam} {tf} {slices}"),
    "slice-oblique": ("one oblique slice with the volume", "{cam} {tf} {oblique}"),
    "layers": ("two volume layers of different fields (scene file)", "{layers}"),
    "scene": ("the gallery's scene file: volume, 2 iso-surfaces, slice, clip box and plane, "
              "specular, AO 8, background", "{scene}"),
}


def mode_flags(dataset: str, mode: str, size: int = 512) -> list[str] | None:
    """The `exabricks render` flags of `mode` on `dataset` (None: not run there)."""
    setup = SETUP[dataset]
    template = MODES[mode][1]
    if any(setup.get(k[1:-1], "") is None for k in ("{layers}", "{scene}") if k in template):
        return None
    return shlex.split(template.format(**setup)) + ["--size", str(size), str(size), "--spp", "1"]


def parse_scene(bricks, paths, flags: list[str]):
    """The Scene that `exabricks render PATHS -o x.png FLAGS` would draw."""
    from exabricks.cli.render import render as render_command

    ctx = render_command.make_context("render", [*map(str, paths), "-o", "/dev/null.png",
                                                 *map(str, flags)])
    p = ctx.params
    return scene_from_options(bricks, scene_path=p["scene_path"], camera_path=p["camera_path"],
                              flags={k: p[k] for k in FLAGS})


def bench_dataset(key: str, modes: list[str], runs: int, size: int) -> tuple[dict, str]:
    """{mode: (kernel ms per frame, samples, process CPU ms per frame)} (lists by
    round) and the device description.

    Every mode renders one warm-up frame first; then the timed frames go round
    the modes (one frame of each mode per round, --runs rounds), so that a change
    in the machine's load hits every mode alike."""
    d = gallery.WORK / key
    gallery.ensure(benchdoc.datasets()[key])
    paths = [d / "bricks.npz", d / "regions.npz", d / "bvh.npz"]
    b = schema.load(paths[0], "bricks")
    r = schema.load(paths[1], "regions")
    v = schema.load(paths[2], "bvh")
    renderers: dict[tuple, Renderer] = {}
    scenes = {}
    for mode in modes:
        flags = mode_flags(key, mode, size)
        if flags is None:
            continue
        scene = parse_scene(b, paths, flags)
        fields = scene.fields()
        if fields not in renderers:
            renderers[fields] = Renderer(b, r, v, fields=fields)
        scenes[mode] = (renderers[fields], scene)
        renderers[fields].render_scene(scene)  # warm-up (and the program variant's build)
    times = {mode: [] for mode in scenes}
    cpu = {mode: [] for mode in scenes}
    samples = {}
    for _ in range(runs):
        for mode, (ren, scene) in scenes.items():
            c0 = time.process_time()
            res = ren.render_scene(scene)
            cpu[mode].append(1e3 * (time.process_time() - c0))
            times[mode].append(res.stats["ms"])
            samples[mode] = res.stats["samples"]
    device = "?"
    for ren in renderers.values():
        s = ren.dataset
        device = (f"{s.device.name.strip()} ({s.device.platform.version.strip()}, "
                  f"{s.device.max_compute_units} compute units)")
    for mode in scenes:
        print(f"  {key:7s} {mode:16s} {benchdoc.fmt_spread(times[mode], 'ms', 0)}  "
              f"CPU {np.median(cpu[mode]):.0f} ms  {samples[mode]:,} samples", flush=True)
    return {mode: (times[mode], samples[mode], cpu[mode]) for mode in scenes}, device


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs_help="timed frames per mode after one warm-up "
                             "frame (default 5)")
    parser.add_argument("--mode", action="append", metavar="MODE",
                        help="only these modes (repeatable or comma-separated; default: all)")
    parser.add_argument("--size", type=int, default=512, help="image width and height")
    parser.add_argument("--list", action="store_true", help="print every mode's flags and stop")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    keys = benchdoc.chosen(args.only, DATASETS)
    modes = benchdoc.chosen(args.mode, list(MODES))
    if args.list:
        for key in keys:
            for mode in modes:
                flags = mode_flags(key, mode, args.size)
                if flags is not None:
                    print(f"{key} {mode}: {shlex.join(flags)}")
        return 0

    t0 = time.perf_counter()
    results, device = {}, "?"
    for key in keys:
        results[key], device = bench_dataset(key, modes, args.runs, args.size)

    names = {"gerris": "Gerris plume", "amrex": "AMReX advection"}
    head = "| mode | draws | " + " | ".join(
        f"{names[k]}: ms/frame | x volume | CPU ms/frame | samples/frame" for k in keys) + " |"
    rule = "|---|---|" + "---:|---:|---:|---:|" * len(keys)
    rows = []
    for mode in modes:
        if not any(mode in results[k] for k in keys):
            continue
        cells = [f"`{mode}`", MODES[mode][0]]
        for k in keys:
            if mode not in results[k]:
                cells += ["-", "-", "-", "-"]
                continue
            times, samples, cpu = results[k][mode]
            base = results[k].get("volume")
            # the ratio round by round (both frames of a round saw about the same load)
            ratio = (f"{np.median(np.divide(times, base[0])):.2f}" if base else "-")
            cells += [benchdoc.fmt_spread(times, "", 0), ratio, f"{np.median(cpu):.0f}",
                      f"{samples:,}"]
        rows.append("| " + " | ".join(cells) + " |")

    command = "`.venv/bin/python -m benchmarks.bench_modes" + (
        f" --only {','.join(keys)}" if args.only else "") + (
        f" --mode {','.join(modes)}" if args.mode else "") + f" --runs {args.runs}" + (
        f" --size {args.size}" if args.size != 512 else "") + " --write-docs`"
    section = (
        f"Command: {command} (`--list` prints the flags of every mode)\n\n"
        f"- machine: {benchdoc.machine()}, load average {benchdoc.load_average()} at the end "
        f"({time.perf_counter() - t0:.0f} s in all)\n- OpenCL device: {device}\n"
        f"- frames: {args.size}x{args.size}, 1 sample per pixel, one camera and volume "
        "transfer function per dataset (the gallery's first shot, benchmarks/gallery.py) and "
        "the iso-values, fields, clip and slice placements of `--list`; one warm-up frame "
        f"per mode, then {args.runs} rounds of one frame of every mode; median (min-max in "
        "brackets)\n\n"
        + head + "\n" + rule + "\n" + "\n".join(rows) + "\n\n"
        "ms/frame is the kernel time of one frame (`Renderer.render_scene(scene).stats"
        "[\"ms\"]`: enqueue to finish, no upload or read-back), the scene built by "
        "`exabricks.scene.scene_from_options` from the flags exactly as `exabricks render` "
        "builds it; x volume is the median over the rounds of its ratio to the `volume` frame "
        "of the same dataset and round; CPU ms/frame is the process CPU time of the "
        "`render_scene` call (all of the OpenCL runtime's threads; less sensitive to other "
        "jobs than the wall time). samples "
        "are the volume reconstructions the kernel counts (surface-only frames still step "
        "through the regions an iso-value lies in). The background is composited on the host "
        "after the kernel: `background` runs the same kernel as `volume`, and the difference between the two rows is the noise of the measurement. The AMReX plotfile has "
        "one field (phi), so its `iso-colored` and `shells` rows colour phi by phi, and it "
        "has no two-field layers or scene-file rows. These figures come from a machine "
        "shared with other jobs (2 cores): the spread shows how much they moved.\n")
    benchdoc.publish(SECTION, section, args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
