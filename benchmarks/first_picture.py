"""The first picture: what `exabricks render SOURCE -o x.png` gives with no
options on every shared dataset, measured (docs/scene.md, "Defaults").

    .venv/bin/python -m benchmarks.first_picture [--out DIR] [--size N]

Each dataset is rendered with no option but the field (the one a user would
name: Gerris T, Athena++ rho, Enzo Density; AMReX's only field by default),
and the PNG is measured by `picture_metrics`:

- opaque: the share of pixels with alpha 255 (a PNG is composited over the
  background unless --transparent);
- coverage: the share of pixels brighter than COVERED (luminance in [0, 1]):
  neither an empty frame (0) nor an opaque block filling it (1);
- contrast: the spread (standard deviation over mean) of the luminance of
  covered pixels: an opaque cube of one colour has little;
- framing: the share of the frame's width and height (the larger) that the
  bounding box of the covered pixels spans;
- isolated dark pixels: covered pixels darker than half the median of their
  8 neighbours, per thousand covered pixels (speckle);
- luminance: the standard deviation and the 99th percentile of the luminance
  of covered pixels (issue 63 asks at least 0.08 and 0.6);
- detail: the fine detail (mean absolute difference of the luminance from its
  3 x 3 mean over covered pixels) over that of the same command with
  `--shading none --spp 16` (noise and shading's edges; at most 2);
- core: the share of covered pixels darker than the brightest pixel within
  two pixels of the projection of the field's largest value (1: the densest
  structure is the brightest; issue 63 asks that it show where it is).

With --core DIR it also draws generated data: workflows/make_dense_core.py's
plotfile (written into DIR once) of a dense core spanning 6 decades and
smaller than a pixel.

It prints a Markdown table (the one in docs/scene.md) and leaves the pictures
in --out. With --yt DIR it also writes yt's `create_scene` default picture of
each dataset and field to DIR/defaults-yt-<dataset>.png (512 x 512; the Gerris
cells through exabricks.readers.yt_grids, as benchmarks/peers/yt.py loads them), the
comparison of docs/gallery.md, "The first picture".
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.benchdoc import exabricks_command
from workflows import make_dense_core

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
# Luminance above which a pixel counts as covered.
COVERED = 0.03

# name -> (source under ../shared/data, field flag)
DATASETS = {
    "amrex": ("amrex-advection3d/plt00020", ()),
    "athena": ("athena-blast3d/Blast.out2.00001.athdf", ("--field", "rho")),
    "gerris": ("gerris-plume/plume7-1.cells", ("--field", "T")),
    "enzo": ("enzo-moving7/moving7_0010", ("--field", "Density")),
}


def luminance(rgb8: np.ndarray) -> np.ndarray:
    """(H, W) float64 in [0, 1]: Rec. 709 luminance of 8-bit RGB."""
    return (np.asarray(rgb8[..., :3], np.float64) / 255.0) @ np.array([0.2126, 0.7152, 0.0722])


def picture_metrics(rgba8: np.ndarray) -> dict:
    """The measures of the module docstring of an (H, W, 4) uint8 picture."""
    lum = luminance(rgba8)
    covered = lum > COVERED
    h, w = lum.shape
    out = {"opaque": float((rgba8[..., 3] == 255).mean()), "coverage": float(covered.mean())}
    if not covered.any():
        return {**out, "contrast": 0.0, "framing": 0.0, "isolated_dark": 0.0}
    seen = lum[covered]
    rows, cols = np.nonzero(covered)
    out["contrast"] = float(seen.std() / seen.mean())
    out["framing"] = float(max((rows.max() - rows.min() + 1) / h, (cols.max() - cols.min() + 1) / w))
    padded = np.pad(lum, 1, mode="edge")
    neighbours = np.stack([padded[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
                           for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx])
    dark = covered & (lum < 0.5 * np.median(neighbours, axis=0))
    out["isolated_dark"] = float(1000.0 * dark.sum() / covered.sum())
    return out


def fine_detail(rgba8: np.ndarray) -> float:
    """The mean absolute difference of the luminance from its 3 x 3 mean over the
    covered pixels."""
    lum = luminance(rgba8)
    covered = lum > COVERED
    if not covered.any():
        return 0.0
    h, w = lum.shape
    padded = np.pad(lum, 1, mode="edge")
    mean = sum(padded[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx] for dy in (-1, 0, 1)
               for dx in (-1, 0, 1)) / 9.0
    return float(np.abs(lum - mean)[covered].mean())


def largest_value_at(source: Path, field: str) -> np.ndarray:
    """World position (3,) of the centre of the cell holding the largest value
    of `field` in `source`."""
    import exabricks as eb

    bricks = eb.open(str(source), fields=[field]).bricks
    values = np.asarray(bricks.values[bricks.field_index(field)])
    at = int(np.nanargmax(values))
    brick = int(np.searchsorted(bricks.offset, at, side="right")) - 1
    nx, ny, _ = (int(d) for d in bricks.dims[brick])
    i = at - int(bricks.offset[brick])
    cell = np.array([i % nx, (i // nx) % ny, i // (nx * ny)], np.float64)
    width = float(1 << int(bricks.level[brick]))
    lattice = np.asarray(bricks.lower_lattice[brick], np.float64) + (cell + 0.5) * width
    return np.asarray(bricks.origin_world, np.float64) + lattice * np.asarray(bricks.spacing_world)


def core_rank(rgba8: np.ndarray, png: Path, world: np.ndarray) -> float:
    """The share of covered pixels darker than the brightest pixel within two
    pixels of `world` projected by the camera recorded in `png`."""
    import json

    from PIL import Image

    from exabricks.picture.camera import Camera

    camera = Camera.from_dict(json.loads(Image.open(png).info["exabricks:camera"]))
    h, w = rgba8.shape[:2]
    origin, forward, du, dv = camera.frame(w, h)
    d = world - origin
    depth = d @ forward
    x = ((d @ du) / (du @ du) / depth + 1.0) * 0.5 * w
    y = (1.0 - (d @ dv) / (dv @ dv) / depth) * 0.5 * h
    lum = luminance(rgba8)
    covered = lum > COVERED
    if depth <= 0 or not covered.any():
        return 0.0
    c, r = int(x), int(y)
    near = lum[max(0, r - 2):max(0, r + 3), max(0, c - 2):max(0, c + 3)]
    return float((lum[covered] < near.max()).mean()) if near.size else 0.0


def render_default(name: str, output: Path, *, data: Path = SHARED, extra=()) -> np.ndarray:
    """Render dataset `name` with no option but its field into `output` (.png);
    its RGBA pixels (H, W, 4) uint8."""
    from PIL import Image

    source, field = DATASETS[name]
    subprocess.run([*exabricks_command(), "render", str(data / source), *field, *extra,
                    "-o", str(output)], check=True)
    return np.asarray(Image.open(output).convert("RGBA"))


def measured(name: str, out: Path, data: Path = SHARED) -> dict:
    """Every measure of the module docstring of dataset `name`'s default picture,
    left in `out`/NAME.png (and NAME-flat.png, unshaded at 16 spp)."""
    source, field = DATASETS[name]
    png = out / f"{name}.png"
    rgba8 = render_default(name, png, data=data)
    flat = render_default(name, out / f"{name}-flat.png", data=data,
                          extra=("--shading", "none", "--spp", "16"))
    m = picture_metrics(rgba8)
    lum = luminance(rgba8)
    seen = lum[lum > COVERED]
    m["std"] = float(seen.std()) if seen.size else 0.0
    m["p99"] = float(np.quantile(seen, 0.99)) if seen.size else 0.0
    m["detail"] = fine_detail(rgba8) / max(fine_detail(flat), 1e-9)
    name_of_field = field[1] if field else "phi"
    m["core"] = core_rank(rgba8, png, largest_value_at(data / source, name_of_field))
    return m


def yt_default(name: str, output: Path, *, data: Path = SHARED) -> float:
    """yt's `create_scene(ds, field)` of dataset `name`, saved as `output` at
    512 x 512 with yt's defaults otherwise; its seconds."""
    import time

    import yt

    yt.set_log_level(40)
    source, field = DATASETS[name]
    path = data / source
    if name == "gerris":
        from exabricks import readers, schema
        from exabricks.readers import yt_grids

        cells = readers.read(str(path), fields=[field[1]])
        grids, top = yt_grids.to_amr_grids(cells, source=str(path))
        lo, hi = (np.asarray(b) for b in schema.world_bounds(cells))
        root = np.rint((hi - lo) / cells.spacing_world / (1 << top)).astype(int)
        ds = yt.load_amr_grids(grids, root, bbox=np.column_stack([lo, hi]), length_unit=1.0)
        name_in_yt = ("stream", field[1])
    else:
        ds = yt.load(str(path))
        wanted = field[1] if field else "phi"
        name_in_yt = next(f for f in ds.field_list if f[1] == wanted)
    t = time.perf_counter()
    scene = yt.create_scene(ds, name_in_yt)
    scene.camera.resolution = (512, 512)
    scene.save(str(output))
    return time.perf_counter() - t


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="folder for the pictures")
    parser.add_argument("--yt", type=Path, default=None, metavar="DIR",
                        help="also write yt's create_scene default of each dataset here")
    parser.add_argument("--core", type=Path, default=None, metavar="DIR",
                        help="also draw the generated dense core (its plotfile written here)")
    args = parser.parse_args(argv)
    data = {name: SHARED for name in DATASETS}
    if args.core is not None:
        args.core.mkdir(parents=True, exist_ok=True)
        if not (args.core / "dense-core").exists():
            make_dense_core.write(args.core / "dense-core")
        DATASETS["core"] = ("dense-core", ("--field", "density"))
        data["core"] = args.core
    if args.yt is not None:
        args.yt.mkdir(parents=True, exist_ok=True)
        for name in DATASETS:
            seconds = yt_default(name, args.yt / f"defaults-yt-{name}.png")
            print(f"yt {name}: {seconds:.1f} s", file=sys.stderr)
    out = args.out or Path(tempfile.mkdtemp(prefix="first-picture-"))
    out.mkdir(parents=True, exist_ok=True)
    print("| dataset | command | opaque | coverage | framing | contrast | luminance σ | "
          "luminance p99 | detail | core | isolated dark (‰) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, (source, field) in DATASETS.items():
        m = measured(name, out, data[name])
        command = " ".join(["exabricks render", Path(source).name, *field, "-o x.png"])
        print(f"| {name} | `{command}` | {m['opaque']:.2f} | {m['coverage']:.2f} | "
              f"{m['framing']:.2f} | {m['contrast']:.2f} | {m['std']:.3f} | {m['p99']:.2f} | "
              f"{m['detail']:.2f} | {m['core']:.3f} | {m['isolated_dark']:.2f} |")
    print(f"pictures in {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
