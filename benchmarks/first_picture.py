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
  8 neighbours, per thousand covered pixels (speckle).

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


def render_default(name: str, output: Path, *, data: Path = SHARED, extra=()) -> np.ndarray:
    """Render dataset `name` with no option but its field into `output` (.png);
    its RGBA pixels (H, W, 4) uint8."""
    from PIL import Image

    source, field = DATASETS[name]
    subprocess.run([*exabricks_command(), "render", str(data / source), *field, *extra,
                    "-o", str(output)], check=True)
    return np.asarray(Image.open(output).convert("RGBA"))


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
    args = parser.parse_args(argv)
    if args.yt is not None:
        args.yt.mkdir(parents=True, exist_ok=True)
        for name in DATASETS:
            seconds = yt_default(name, args.yt / f"defaults-yt-{name}.png")
            print(f"yt {name}: {seconds:.1f} s", file=sys.stderr)
    out = args.out or Path(tempfile.mkdtemp(prefix="first-picture-"))
    out.mkdir(parents=True, exist_ok=True)
    print("| dataset | command | opaque | coverage | contrast | framing | isolated dark (‰) |")
    print("|---|---|---|---|---|---|---|")
    for name, (source, field) in DATASETS.items():
        m = picture_metrics(render_default(name, out / f"{name}.png"))
        command = " ".join(["exabricks render", Path(source).name, *field, "-o x.png"])
        print(f"| {name} | `{command}` | {m['opaque']:.2f} | {m['coverage']:.2f} | "
              f"{m['contrast']:.2f} | {m['framing']:.2f} | {m['isolated_dark']:.2f} |")
    print(f"pictures in {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
