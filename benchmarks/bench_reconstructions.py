"""Benchmark the reconstructions (basis, nearest, vertex) and level of detail (`--lod`)
on the four shared datasets, and render the pictures of docs/reconstructions.md.

    .venv/bin/python -m benchmarks.bench_reconstructions [--runs 3] [--size 512]
        [--lod-sizes 256,1024] [--lod-pixels 0,1,2,4,8,16] [--lod-shading none]
        [--only gerris,amrex,athena,enzo] [--no-images] [--write-docs]

Each dataset goes through the `exabricks` stage commands once (ingest, brick,
regions, bvh; cached under bench-data/gallery/<dataset>/ as by
benchmarks/gallery.py, not timed): the same bricks, regions and BVH that
tests/conftest.py `built_scene` builds in memory. Every frame is a Scene made by
`exabricks.scene.scene_from_options` from `exabricks render` flags (the CLI's own
parser, as in benchmarks/bench_modes.py), so each figure and picture is exactly
what the printed command draws: with no camera or transfer-function flags that
is the default camera on the data bounds and the default transfer function over
the field's range (what `built_scene` uses; checked).

(a) Reconstructions, --size x --size: for each of basis, nearest and vertex a
    fresh `Renderer` (timed: construction, the vertex values for "vertex" --
    made on the device, `DeviceDataset.vertex_args`, which the first vertex frame
    would otherwise make -- and the first frame, headlight, which also fetches
    the program variant), then --runs timed frames with `--shading none` and
    with headlight, the six cases alternating round by round so that a change of
    the machine's load hits them alike. Reported: kernel ms per frame (median,
    min-max), samples, samples/s, and how far nearest and vertex frames are from
    the basis frame (RMSE, SSIM: exabricks.stages.compare).
(b) Level of detail, basis reconstruction, `--shading` --lod-shading: for each
    image size of --lod-sizes, one frame of every --lod PIXELS (0 = off) per round,
    --runs rounds, on the basis Renderer of (a) (its non-LOD program is warm;
    the first LOD frame, which also makes the bricks' mip levels and fetches
    the LOD program, is timed apart as the warm-up). Reported: kernel ms
    (median), speed-up over PIXELS 0, samples and samples per level, and the
    error of the frame against the PIXELS 0 frame of the same size (RMSE,
    SSIM). docs/images/lod-curve.png plots speed-up against error, one line per
    dataset; docs/images/lod-<dataset>.png shows PIXELS 0, 4 and 16.
Pictures (unless --no-images): SHOTS below, each with every reconstruction --
    docs/images/reconstruction-<dataset>[-<shot>]-<recon>.png (the volume with the
    gallery's camera and transfer function, a slice and iso-surfaces close up) and
    4 x |vertex - basis| as ...-diff.png -- written as `exabricks render` writes
    them, with the command in the PNG metadata (exabricks:command).

--write-docs replaces the "## reconstructions and level of detail" section of
docs/benchmarks.md with tables built from the rows measured in this run.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import benchdoc
from benchmarks import gallery

from exabricks import schema
from exabricks.picture.camera import default_camera
from exabricks.scene import FLAGS, RECONSTRUCTIONS, scene_from_options, scene_to_dict
from exabricks.stages.compare import compare_images
from exabricks.engine.renderer import Renderer
from exabricks.picture.transfer_function import default_transfer_function

ROOT = Path(__file__).resolve().parents[1]


SECTION = "reconstructions and level of detail"
DATASETS = ("gerris", "amrex", "athena", "enzo")
SHADINGS = ("none", "headlight")
LOD_PIXELS = (0, 1, 2, 4, 8, 16)
LOD_SIZES = (256, 1024)
LOD_SHOWN = (0, 4, 16)  # the columns of docs/images/lod-<dataset>.png
LOD_PICTURES = ("gerris", "amrex")  # the datasets of docs/images/lod-<dataset>.png
IMAGES = ROOT / "docs" / "images"
NAMES = {"gerris": "Gerris plume", "amrex": "AMReX advection", "athena": "Athena++ blast",
         "enzo": "Enzo moving7"}

# Pictures of docs/reconstructions.md: (dataset, shot, flags); each is rendered with
# every reconstruction to docs/images/reconstruction-<dataset>[-<shot>]-<recon>.png.
# Enzo moving7 nests its levels as cubes around the clump at (0.75, 0.75, 0.75):
# level 3 (cells 1/256) inside |x - 0.75| < 0.031, level 4 (1/128) out to 0.078.
# Density ~ r^-2: 30 at r ~ 0.03, so the iso-surface Density = 30 meets the
# level 3/4 boundary where the cube's faces touch it.
SHOTS = (
    # The volume of each dataset with the camera and transfer function of docs/gallery.md
    # (benchmarks/gallery.py, copied here so that docs/reconstructions.md's commands stay put)
    # (the default view of the benchmark shows the Athena++ blast as an opaque cube and
    # the Enzo clump as a few faint pixels): docs/images/reconstruction-<dataset>-<recon>.png.
    ("gerris", None, "--position 129 63 148 --look-at 64 33 64 --up 0 1 0 --fovy 30 --field T "
               "--colormap inferno --range 0 0.6 --opacity 0,0.05,0.15,0.3 --size 400 400"),
    ("amrex", None, "--position 2.1 1.65 2.3 --look-at 0.68 0.6 0.5 --up 0 1 0 --fovy 24 "
              "--field phi --colormap viridis --range 1 1.97 --opacity 0,0,0.3,0.6,0.9 "
              "--size 400 400"),
    ("athena", None, "--position 0.66 0.46 0.8 --look-at 0 0 0 --up 0 1 0 --fovy 30 --field rho "
               "--colormap viridis --range 1 2.7 --opacity 0,0.02,0.2,0.5 --size 400 400"),
    ("enzo", None, "--position 1.23 1.04 1.33 --look-at 0.75 0.75 0.75 --up 0 1 0 --fovy 30 "
             "--field Density --colormap viridis --range 1 30 --opacity 0,0.02,0.1,0.3,0.6 "
             "--unit-distance 0.01 --size 400 400"),
    ("enzo", "slice",
     "--position 0.775 0.775 0.95 --look-at 0.775 0.775 0.7505 --up 0 1 0 --fovy 20 "
     "--field Density --no-volume --slice 0.775 0.775 0.7505 0 0 1 --slice-colormap viridis "
     "--slice-range 3 100 --size 400 400"),
    ("enzo", "iso",
     "--position 0.87 0.82 0.93 --look-at 0.75 0.75 0.75 --up 0 1 0 --fovy 30 "
     "--field Density --no-volume --iso 30 --iso-color 1,0.6,0.3 --size 400 400"),
    ("gerris", "iso",
     "--position 97 58 106 --look-at 64 44 64 --up 0 1 0 --fovy 30 "
     "--field T --no-volume --iso 0.3 --iso-color 1,0.6,0.3 --size 400 400"),
)


def rel(path: Path) -> str:
    return gallery.rel(path)


class Data:
    """One dataset's stage files (bench-data/gallery/<key>/), loaded."""

    def __init__(self, key: str):
        self.key = key
        dataset = benchdoc.datasets()[key]
        self.field = dataset.field
        gallery.ensure(dataset)
        d = gallery.WORK / key
        self.paths = [d / "bricks.npz", d / "regions.npz", d / "bvh.npz"]
        self.bricks = schema.load(self.paths[0], "bricks")
        self.regions = schema.load(self.paths[1], "regions")
        self.bvh = schema.load(self.paths[2], "bvh")

    def scene(self, flags: list[str]):
        """The Scene that `exabricks render BRICKS REGIONS BVH -o x.png FLAGS` draws."""
        from exabricks.cli.render import render as render_command

        ctx = render_command.make_context("render", [*map(str, self.paths), "-o", "/dev/null.png",
                                                     *map(str, flags)])
        p = ctx.params
        return scene_from_options(self.bricks, scene_path=p["scene_path"],
                                  camera_path=p["camera_path"], flags={k: p[k] for k in FLAGS})

    def command(self, flags: list[str], image: str = "out.png") -> str:
        d = rel(gallery.WORK / self.key)
        return shlex.join(["exabricks", "render", f"{d}/bricks.npz", f"{d}/regions.npz",
                           f"{d}/bvh.npz", *flags, "-o", image])

    def check_defaults(self, scene) -> None:
        """The default camera and transfer function are tests/conftest.py built_scene's."""
        values = self.bricks.values[self.bricks.field_index(self.field)]
        lo, hi = schema.world_bounds(self.bricks)
        cam = default_camera(np.asarray(lo), np.asarray(hi))
        tf = default_transfer_function((float(values.min()), float(values.max())))
        c = scene.camera
        assert np.allclose(c.position, cam.position) and np.allclose(c.look_at, cam.look_at) \
            and c.fovy == cam.fovy, (c, cam)
        got, want = scene.volumes[0].transfer_function.merged_knots(), tf.merged_knots()
        assert all(np.allclose(a, b) for a, b in zip(got, want)), "transfer function differs"

    def finest_pixels(self, scene, height: int) -> float:
        """Pixels covered by a finest cell at the distance of the data's centre."""
        lo, hi = (np.asarray(x) for x in schema.world_bounds(self.bricks))
        t = float(np.linalg.norm(0.5 * (lo + hi) - np.asarray(scene.camera.position)))
        width = 2.0 ** int(self.bricks.level.min()) * float(np.min(self.bricks.spacing_world))
        return width / (t * 2.0 * math.tan(math.radians(scene.camera.fovy) / 2.0) / height)


def write_png(path: Path, rgba, scene, command: str) -> None:
    from exabricks.film.image_io import write_image

    write_image(path, rgba, metadata={"camera": scene.camera.to_dict(),
                                      "scene": scene_to_dict(scene), "command": command})


def flags_of(data: Data, size: int, recon: str = "basis", shading: str = "headlight",
             lod: float = 0) -> list[str]:
    f = ["--field", data.field, "--size", str(size), str(size)]
    f += ["--reconstruction", recon] if recon != "basis" else []
    f += ["--shading", shading] if shading != "headlight" else []
    f += ["--lod", f"{lod:g}"] if lod else []
    return f


def device_line(renderer: Renderer) -> str:
    d = renderer.dataset.device
    return f"{d.name.strip()} ({d.platform.version.strip()}, {d.max_compute_units} compute units)"


# ---------------------------------------------------------------------------
# (a) reconstructions


def bench_reconstructions(data: Data, runs: int, size: int) -> tuple[dict, dict]:
    """{recon: row dict} and {recon: Renderer} (the basis one is reused by (b))."""
    scenes = {(r, s): data.scene(flags_of(data, size, r, s)) for r in RECONSTRUCTIONS
              for s in SHADINGS}
    data.check_defaults(scenes["basis", "headlight"])
    renderers, rows = {}, {}
    for recon in RECONSTRUCTIONS:
        t = time.perf_counter()
        ren = Renderer(data.bricks, data.regions, data.bvh, field=data.field)
        construct = time.perf_counter() - t
        vertex = None
        if recon == "vertex":
            t = time.perf_counter()
            ren.dataset.vertex_args()
            vertex = time.perf_counter() - t
        t = time.perf_counter()
        first = ren.render_scene(scenes[recon, "headlight"])
        first_s = time.perf_counter() - t
        renderers[recon] = ren
        rows[recon] = dict(construct=construct, vertex=vertex, first=first_s,
                           first_ms=first.stats["ms"], ms={s: [] for s in SHADINGS},
                           samples={}, frame={})
        print(f"  {data.key} {recon}: Renderer() {construct:.2f} s"
              + (f", vertex values {vertex:.2f} s" if vertex is not None else "")
              + f", first frame {first_s:.2f} s", flush=True)
    for _ in range(runs):
        for recon in RECONSTRUCTIONS:
            for shading in SHADINGS:
                res = renderers[recon].render_scene(scenes[recon, shading])
                row = rows[recon]
                row["ms"][shading].append(res.stats["ms"])
                row["samples"][shading] = res.stats["samples"]
                row["frame"][shading] = res.rgba
    for recon in RECONSTRUCTIONS:
        row = rows[recon]
        row["error"] = {s: compare_images(row["frame"][s], rows["basis"]["frame"][s])
                        for s in SHADINGS}
        print(f"  {data.key} {recon}: "
              + ", ".join(f"{s} {benchdoc.fmt_spread(row['ms'][s], 'ms', 0)} "
                          f"{row['samples'][s]:,} samples" for s in SHADINGS), flush=True)
    for row in rows.values():
        row.pop("frame")
    return rows, renderers


# ---------------------------------------------------------------------------
# (b) level of detail


def bench_lod(data: Data, renderer: Renderer, runs: int, sizes, pixels, shading: str) -> dict:
    """{size: {"first": s, "finest_px": px, "rows": {P: row}, "frames": {P: rgba}}}."""
    out = {}
    for n, size in enumerate(sizes):
        scenes = {p: data.scene(flags_of(data, size, "basis", shading, p)) for p in pixels}
        entry = out[size] = {"finest_px": data.finest_pixels(scenes[pixels[0]], size),
                             "first": None, "rows": {}, "frames": {}}
        if n == 0 and any(p > 0 for p in pixels):
            # Warm-up: the first LOD frame also makes the bricks' mip levels (lod.py).
            t = time.perf_counter()
            renderer.render_scene(scenes[max(pixels)])
            entry["first"] = time.perf_counter() - t
        times = {p: [] for p in pixels}
        for i in range(runs):
            for p in pixels:
                res = renderer.render_scene(scenes[p])
                times[p].append(res.stats["ms"])
                if i == 0:
                    entry["frames"][p] = res.rgba
                    entry["rows"][p] = dict(samples=res.stats["samples"],
                                            per_level=res.stats.get("samples_per_level"))
        base = entry["frames"][pixels[0]]
        for p in pixels:
            row = entry["rows"][p]
            row["ms"] = times[p]
            row["error"] = compare_images(entry["frames"][p], base)
            row["speedup"] = float(np.median(times[pixels[0]]) / np.median(times[p]))
            row["sample_ratio"] = entry["rows"][pixels[0]]["samples"] / max(row["samples"], 1)
            print(f"  {data.key} {size}^2 lod {p:>2}: {benchdoc.fmt_spread(times[p], 'ms', 0)}, "
                  f"x{row['speedup']:.2f}, {row['samples']:,} samples {row['per_level']}, "
                  f"RMSE {row['error']['rmse']:.4f} SSIM {row['error']['ssim']:.4f}", flush=True)
    return out


def lod_picture(key: str, lod: dict, pixels, path: Path) -> None:
    """Rows: the --lod-sizes; columns: PIXELS of LOD_SHOWN (those measured), over a dark
    background, each panel shown at 512 pixels."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [p for p in LOD_SHOWN if p in pixels]
    sizes = list(lod)
    fig, axes = plt.subplots(len(sizes), len(shown), squeeze=False,
                             figsize=(5.12 * len(shown), 5.5 * len(sizes)), dpi=100)
    bg = np.array([0.06, 0.06, 0.08])
    for i, size in enumerate(sizes):
        for j, p in enumerate(shown):
            im = lod[size]["frames"][p]
            rgb = np.clip(im[..., :3] + (1.0 - im[..., 3:4]) * bg, 0, 1)
            row = lod[size]["rows"][p]
            ax = axes[i, j]
            ax.imshow(rgb, interpolation="nearest" if size < 512 else "antialiased")
            title = f"{size}x{size}, --lod {p}" + ("" if p == 0 else
                    f": x{row['speedup']:.2f} faster, SSIM {row['error']['ssim']:.3f}")
            ax.set_title(title, fontsize=13)
            ax.axis("off")
    fig.suptitle(f"{NAMES[key]}: level of detail", fontsize=15)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def lod_curve(results: dict, pixels, path: Path) -> None:
    """Speed-up against RMSE and against SSIM, one panel per image size, one line per dataset."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = sorted({s for lod in results.values() for s in lod})
    fig, axes = plt.subplots(2, len(sizes), squeeze=False, figsize=(6 * len(sizes), 9), dpi=100)
    for j, size in enumerate(sizes):
        for i, metric in enumerate(("rmse", "ssim")):
            ax = axes[i, j]
            for key, lod in results.items():
                rows = lod[size]["rows"]
                x = [rows[p]["error"][metric] for p in pixels]
                y = [rows[p]["speedup"] for p in pixels]
                line, = ax.plot(x, y, "o-", label=NAMES[key])
                for p, a, b in zip(pixels, x, y):
                    ax.annotate(str(p), (a, b), textcoords="offset points", xytext=(4, 3),
                                fontsize=8, color=line.get_color())
            ax.axhline(1.0, color="grey", lw=0.5)
            ax.set_xlabel("RMSE against --lod 0" if metric == "rmse" else "SSIM against --lod 0")
            if metric == "ssim":
                ax.invert_xaxis()
            ax.set_ylabel("speed-up over --lod 0 (kernel ms)")
            ax.set_title(f"{size}x{size}: speed-up vs {metric.upper()} (labels: --lod PIXELS)")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ---------------------------------------------------------------------------
# Pictures of docs/reconstructions.md


def render_shots(datas: dict) -> list[str]:
    """Render SHOTS with every reconstruction; the commands, one per image."""
    commands, renderers = [], {}
    for key, shot, text in SHOTS:
        if key not in datas:
            continue
        data = datas[key]
        frames = {}
        name = f"{key}-{shot}" if shot else key
        for recon in RECONSTRUCTIONS:
            flags = shlex.split(text) + (["--reconstruction", recon] if recon != "basis" else [])
            scene = data.scene(flags)
            if (key, scene.fields()) not in renderers:
                renderers[key, scene.fields()] = Renderer(data.bricks, data.regions, data.bvh,
                                                          fields=scene.fields())
            t = time.perf_counter()
            res = renderers[key, scene.fields()].render_scene(scene)
            path = IMAGES / f"reconstruction-{name}-{recon}.png"
            command = data.command(flags, rel(path))
            write_png(path, res.rgba, scene, command)
            frames[recon] = res.rgba
            commands.append(command)
            print(f"  {rel(path)}: {time.perf_counter() - t:.1f} s", flush=True)
        for recon in ("nearest", "vertex"):
            e = compare_images(frames[recon], frames["basis"])
            print(f"    {name} {recon} vs basis: RMSE {e['rmse']:.4f} SSIM {e['ssim']:.4f}")
        # Where vertex and basis differ: |vertex - basis| (largest channel), x4.
        d = np.abs(frames["vertex"] - frames["basis"])[..., :3].max(axis=-1)
        grey = np.clip(4.0 * d, 0.0, 1.0)
        diff = np.stack([grey, grey, grey, np.ones_like(grey)], -1).astype(np.float32)
        from exabricks.film.image_io import write_image
        write_image(IMAGES / f"reconstruction-{name}-diff.png", diff,
                    metadata={"what": "4 x |vertex - basis|, largest RGB channel"})
        print(f"    {name}: max |vertex - basis| = {float(d.max()):.3f}", flush=True)
    return commands


# ---------------------------------------------------------------------------
# The section of docs/benchmarks.md


def fmt_err(e: dict) -> str:
    if e["rmse"] == 0.0:
        return "0 / 1"
    return f"{e['rmse']:.4f} / {e['ssim']:.4f}"


def fmt_levels(per_level) -> str:
    if not per_level:
        return "-"
    total = sum(per_level.values())
    share = lambda c: "<1 %" if 100 * c / total < 0.5 else f"{100 * c / total:.0f} %"
    return ", ".join(f"L{l}: {share(c)}" for l, c in
                     sorted(per_level.items(), key=lambda kv: int(kv[0])))


def section(args, rec: dict, lod: dict, finest: dict, device: str, seconds: float,
            keys) -> str:
    command = "`.venv/bin/python -m benchmarks.bench_reconstructions" + (
        f" --only {','.join(keys)}" if args.only else "") + f" --runs {args.runs}" + (
        f" --size {args.size}" if args.size != 512 else "") + (
        f" --lod-sizes {','.join(map(str, args.lod_sizes))}"
        if tuple(args.lod_sizes) != LOD_SIZES else "") + (
        f" --lod-pixels {','.join(f'{p:g}' for p in args.lod_pixels)}"
        if tuple(args.lod_pixels) != LOD_PIXELS else "") + (
        f" --lod-shading {args.lod_shading}" if args.lod_shading != "none" else "") + \
        " --write-docs`"
    out = [f"Command: {command}", "",
           f"- machine: {benchdoc.machine()}, load average {benchdoc.load_average()} at the "
           f"end ({seconds:.0f} s in all). **A machine shared with other jobs** (2 cores, "
           "other workers' builds and tests running at the same time): absolute times move "
           "by tens of per cent between runs; the cases alternate round by round, so ratios "
           "within one table are steadier than the times themselves, and the sample counts "
           "do not depend on the load at all.",
           f"- OpenCL device: {device}",
           "- data: the bricks, regions and BVH of `bench-data/gallery/<dataset>/` (the "
           "`exabricks` stage commands, as tests/conftest.py `built_scene` builds them); "
           "the default camera on the data bounds and the default transfer function over "
           "the field's range; sampling rate 2, jitter, seed 0, 1 sample per pixel.", ""]
    if rec:
        out += [f"### reconstructions ({args.size}x{args.size}, median of {args.runs} frames, "
                "min-max in brackets)", "",
                "| dataset | field | reconstruction | shading none: ms/frame | M samples/s "
                "| headlight: ms/frame | M samples/s | samples/frame (none) "
                "| vs basis, none: RMSE / SSIM | headlight: RMSE / SSIM |",
                "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
        for key, rows in rec.items():
            for recon, row in rows.items():
                cells = [NAMES[key], benchdoc.datasets()[key].field, recon]
                for s in SHADINGS:
                    med = float(np.median(row["ms"][s]))
                    cells += [benchdoc.fmt_spread(row["ms"][s], "", 0),
                              f"{row['samples'][s] / med / 1e3:.1f}"]
                cells += [f"{row['samples']['none']:,}"]
                cells += ["-" if recon == "basis" else fmt_err(row["error"][s]) for s in SHADINGS]
                out.append("| " + " | ".join(cells) + " |")
        out += ["", "Setup, the first time a reconstruction is used (seconds, wall clock; "
                "the program variants come from pyopencl's binary cache, already built):", "",
                "| dataset | reconstruction | `Renderer(...)` | vertex values | first frame "
                "(headlight) | setup in all | steady frame (headlight) |",
                "|---|---|---:|---:|---:|---:|---:|"]
        for key, rows in rec.items():
            for recon, row in rows.items():
                total = row["construct"] + (row["vertex"] or 0.0) + row["first"]
                out.append(
                    f"| {NAMES[key]} | {recon} | {row['construct']:.2f} | "
                    + (f"{row['vertex']:.2f}" if row["vertex"] is not None else "-")
                    + f" | {row['first']:.2f} | {total:.2f} | "
                    f"{np.median(row['ms']['headlight']) / 1e3:.2f} |")
        ratios = [np.median(r["ms"]["headlight"]) / np.median(r["ms"]["none"])
                  for rows in rec.values() for name, r in rows.items() if name == "nearest"]
        out += ["", RECON_NOTES.format(nearest_lo=min(ratios), nearest_hi=max(ratios)), ""]
    if lod:
        out += [f"### level of detail (basis, `--shading {args.lod_shading}`, median of "
                f"{args.runs} frames)", "",
                "| dataset | size | finest cell | --lod | ms/frame | speed-up | samples/frame "
                "| fewer samples | samples per level | RMSE | SSIM |",
                "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|"]
        for key, sizes in lod.items():
            for size, entry in sizes.items():
                for p, row in entry["rows"].items():
                    e = row["error"]
                    out.append(
                        f"| {NAMES[key]} | {size}² | {entry['finest_px']:.1f} px | {p:g} | "
                        f"{benchdoc.fmt_spread(row['ms'], '', 0)} | {row['speedup']:.2f} | "
                        f"{row['samples']:,} | {row['sample_ratio']:.2f}x | "
                        f"{fmt_levels(row['per_level'])} | {e['rmse']:.4f} | {e['ssim']:.4f} |")
        firsts = [f"{NAMES[k]} {e['first']:.2f} s" for k, s in lod.items()
                  for e in [next(iter(s.values()))] if e["first"] is not None]
        rows = [(k, size, p, r, e["rows"][0]["samples"]) for k, sizes in lod.items()
                for size, e in sizes.items() for p, r in e["rows"].items()]
        same = [r["speedup"] for _, _, p, r, base in rows
                if p and abs(r["samples"] - base) <= 0.01 * base] or [1.0]
        best = max(rows, key=lambda x: x[3]["sample_ratio"])
        firstp = "; ".join(
            f"{size}²: " + ", ".join(
                f"{NAMES[k].split()[0]} {next((f'{p:g}' for kk, ss, p, r, base in rows if kk == k and ss == size and p and r['samples'] <= 0.99 * base), 'none')}"
                for k in lod) for size in args.lod_sizes)
        enzo_root = ", ".join(f"{128 * e['finest_px']:.0f} px at {size}²"
                              for size, e in lod.get("enzo", {}).items()) or "-"
        out += ["", LOD_NOTES.format(
            firsts=", ".join(firsts), size=args.size, same_lo=min(same), same_hi=max(same),
            finest=", ".join(f"{NAMES[k]} {v:.1f} px" for k, v in finest.items()),
            firstp=firstp, best=f"{NAMES[best[0]]} at {best[1]}², P = {best[2]:g}",
            enzo_root=enzo_root, best_ratio=best[3]["sample_ratio"]),
                "", "![speed-up against error](images/lod-curve.png)"]
    return "\n".join(out) + "\n"


RECON_NOTES = """\
ms/frame is the kernel time of a frame (`RenderResult.stats["ms"]`: enqueue to finish, no
upload or read-back); samples are the reconstructions the kernel counts. RMSE / SSIM compare
the frame with the basis frame of the same shading (exabricks.stages.compare; premultiplied
RGBA). nearest is one cell lookup per sample, but shaded (headlight) it takes its normals from
central differences -- six more lookups per sample -- so its headlight frames cost
{nearest_lo:.1f}-{nearest_hi:.1f}x its unshaded ones here; vertex is one trilinear lookup in the
one brick that holds the point instead of the hat sums over every brick of the region's list,
and its analytic gradient comes with it. "vertex values" is the one-off device pass that makes
the stitched corner values (`DeviceDataset.vertex_args`, exabricks/engine/vertex.py), which the
first vertex frame would otherwise do; a `Renderer` keeps them for every later frame. The
programs of this table were already in pyopencl's cache; a variant built for the first time
(each reconstruction is a separate program, and so are frames with iso-surfaces or slices)
took PoCL 1.5-3 minutes on this busy machine when the pictures of docs/reconstructions.md
were first made (not measured by this script). What the default view shows: the default
transfer function (an opacity ramp over the whole range) makes the ambient gas of the
Athena++ blast nearly opaque, so its frames show the outside of an opaque cube (nearest and
vertex agree exactly there, the gas being uniform; basis differs along the silhouette, where
its field reaches half a cell beyond the data, and its rays end sooner, hence fewer samples);
the Enzo clump is transparent but for a few pixels at this ramp (Density 0.1 to 2.6e5), so the
Enzo rows measure the walk and the sampling of a nearly empty frame and its errors are 0.
docs/reconstructions.md shows the three reconstructions with the gallery's cameras and
transfer functions, and close-ups."""

LOD_NOTES = """\
`finest cell` is how many pixels a finest cell covers at the distance of the data's centre
(nearer regions: more); at the {size}x{size} of the first table it is {finest}. `--lod P` samples
a region at the coarsest level whose cells project to at most P pixels at the region's entry,
never finer than its data (docs/design-rendering.md, "Level of detail"), so a level is first coarsened
when P reaches twice its cells' projected size: the finest level at P ~ 2x the column's figure,
a coarser level only at 2x *its* (2^L times larger) projection. The first P that cuts the
samples by 1 % or more -- {firstp} -- so on the smaller images LOD acts from small P
on, on the larger ones only at the largest P, and at 512x512 small P change nothing. Most samples of these default views lie in regions of coarse data
(`samples per level` of the P = 1 rows): the Gerris plume's levels 2-4 around the plume, the
Enzo root grid (level 7, 128 finest cells wide: {enzo_root}), which no P here coarsens; so the
sample counts fall by at most {best_ratio:.2f}x ({best}).
`fewer samples` is samples(P = 0) / samples(P), the load-independent part of the speed-up;
the speed-up is the ratio of median kernel times. **A frame with P > 0 runs the LOD program
(level choice per region, mip addressing) even where it coarsens little**: the rows with
P > 0 whose samples changed by less than 1 % ran at {same_lo:.2f}-{same_hi:.2f}x the speed of
P = 0, so such a P can cost more than it saves. "samples per level" is
`stats["samples_per_level"]` (level 0 = the finest). RMSE and SSIM compare with the P = 0
frame of the same size. The first LOD frame of a dataset (the warm-up, not in the table) also
makes every brick's mip levels on the device: {firsts} (at the first size)."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=3, runs_help="timed frames per case after the "
                             "warm-up (default 3; figures are the median with min-max)")
    parser.add_argument("--size", type=int, default=512,
                        help="image width and height of the reconstruction frames (default 512)")
    parser.add_argument("--lod-sizes", type=lambda s: [int(x) for x in s.split(",")],
                        default=list(LOD_SIZES), help="image sizes of the LOD frames "
                        "(default 256,1024)")
    parser.add_argument("--lod-pixels", type=lambda s: [float(x) for x in s.split(",")],
                        default=list(LOD_PIXELS), help="--lod PIXELS values, the first is the "
                        "reference (default 0,1,2,4,8,16)")
    parser.add_argument("--lod-shading", choices=SHADINGS, default="none",
                        help="shading of the LOD frames (default none)")
    parser.add_argument("--no-images", action="store_true",
                        help="write no pictures under docs/images")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    args.lod_pixels = [int(p) if float(p).is_integer() else p for p in args.lod_pixels]
    if not args.lod_pixels or args.lod_pixels[0] != 0:
        parser.error("--lod-pixels must start with 0 (the reference frame)")
    keys = benchdoc.chosen(args.only, DATASETS)
    images = not args.no_images

    t0 = time.perf_counter()
    datas, rec, lod, finest, device = {}, {}, {}, {}, "?"
    for key in keys:
        print(f"{key}:", flush=True)
        data = datas[key] = Data(key)
        rec[key], renderers = bench_reconstructions(data, args.runs, args.size)
        finest[key] = data.finest_pixels(data.scene(flags_of(data, args.size)), args.size)
        device = device_line(renderers["basis"])
        lod[key] = bench_lod(data, renderers["basis"], args.runs, args.lod_sizes,
                             args.lod_pixels, args.lod_shading)
        if images and key in LOD_PICTURES:
            lod_picture(key, lod[key], args.lod_pixels, IMAGES / f"lod-{key}.png")
        for size in lod[key].values():
            size.pop("frames")
        del renderers
    if images:
        lod_curve(lod, args.lod_pixels, IMAGES / "lod-curve.png")
        print("pictures:", flush=True)
        for command in render_shots(datas):
            print("  " + command)
    seconds = time.perf_counter() - t0
    benchdoc.publish(SECTION, section(args, rec, lod, finest, device, seconds, keys), args.write_docs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
