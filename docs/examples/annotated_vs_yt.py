"""The AMReX advection plotfile annotated by exabricks and by yt's
`Scene.save_annotated`, side by side (docs/annotate.md, "Against yt").

Runs from any folder (REPO is the checkout; the yt extra needed):

    python REPO/docs/examples/annotated_vs_yt.py [PLOTFILE] [-o OUT.png]

PLOTFILE defaults to the checkout's tests/data/amrex-advection3d/plt00020, OUT to
docs/images/annotated/amrex-exabricks-vs-yt.png. Both render the
field phi from the same perspective camera (the gallery's AMReX view) with the
same colour map over the same range; each transfer function is its own tool's
natural form (exabricks: viridis with piecewise-linear opacity knots; yt: viridis
through `map_to_colormap` with alpha of the same shape on yt's own scale), so the
pictures compare the annotations, not the two integrators. yt gets the time through `text_annotate`,
as a yt user adds it; exabricks reads it from the plotfile's header through
`facts_from_meta`.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

import exabricks as eb
from exabricks.film.annotate import annotate
from exabricks.film.layout import facts_from_meta
from exabricks.stages.ingest import ingest

ROOT = Path(__file__).resolve().parents[2]
PLOTFILE = ROOT / "tests" / "data" / "amrex-advection3d" / "plt00020"
OUT = ROOT / "docs" / "images" / "annotated" / "amrex-exabricks-vs-yt.png"

SIZE = 512
CAMERA = {"position": (2.1, 1.65, 2.3), "look_at": (0.68, 0.6, 0.5), "up": (0.0, 1.0, 0.0),
          "fovy": 24.0}
RANGE = (1.0, 1.97)
OPACITY = (0.0, 0.0, 0.3, 0.6, 0.9)
# yt's alpha is on its own scale (and save_annotated normalises the picture to its
# brightest pixels): 2 to 20 give much the same picture here.
YT_SCALE = 4.0
TITLE = "AMReX advection, phi"
# The composite is at most this wide (docs pictures stay small).
MAX_WIDTH = 1024


def exabricks_picture(plotfile: Path) -> np.ndarray:
    """uint8 (H, W, 4): the exabricks render annotated with the plotfile's facts."""
    renderer = eb.Renderer(eb.open(plotfile, cache=False))
    scene = renderer.scene(**CAMERA, field="phi", colormap="viridis", range=RANGE,
                           opacity=OPACITY, size=(SIZE, SIZE),
                           background=(0.0, 0.0, 0.0))
    image = renderer.render(scene)
    return annotate(image.rgba, scene, facts=facts_from_meta(ingest(plotfile).meta), title=TITLE)


def yt_picture(plotfile: Path, folder: Path) -> np.ndarray:
    """uint8 (H, W, 4): yt's volume render of the same view through save_annotated."""
    import yt

    yt.set_log_level("error")
    ds = yt.load(str(plotfile))
    sc = yt.create_scene(ds, field=("boxlib", "phi"), lens_type="perspective")
    source = sc[0]
    source.set_log(False)
    source.tfh.set_bounds(RANGE)
    tf = yt.ColorTransferFunction(RANGE)
    # viridis over the range, alpha shaped like exabricks' opacity knots (yt's own scale).
    knots = np.linspace(0.0, 1.0, len(OPACITY))
    tf.map_to_colormap(*RANGE, colormap="viridis", scale=YT_SCALE,
                       scale_func=lambda t, lo, hi: np.interp(t, knots, OPACITY))
    source.set_transfer_function(tf)
    cam = sc.camera
    cam.resolution = (SIZE, SIZE)
    position = np.array(CAMERA["position"])
    focus = np.array(CAMERA["look_at"])
    distance = float(np.linalg.norm(position - focus))
    # yt's perspective lens spans `width` at the focus: the same vertical angle.
    width = 2.0 * distance * math.tan(math.radians(CAMERA["fovy"]) / 2.0)
    # (The lens puts its image plane at distance width[2].)
    cam.width = ds.arr([width, width, distance], "code_length")
    cam.focus = ds.arr(focus, "code_length")
    cam.set_position(ds.arr(position, "code_length"), north_vector=CAMERA["up"])
    path = folder / "yt.png"
    sc.save_annotated(str(path), sigma_clip=None, label_fontsize=10, text_annotate=[
        [(0.03, 0.95), f"{TITLE}, t = {float(ds.current_time.d):.4g}", {"color": "white"}]])
    return np.asarray(Image.open(path).convert("RGBA"))


def side_by_side(left: np.ndarray, right: np.ndarray) -> Image.Image:
    """The two pictures on one black canvas, tops aligned, a grey line between them,
    scaled to MAX_WIDTH."""
    gap = 24
    height = max(left.shape[0], right.shape[0])
    canvas = np.zeros((height, left.shape[1] + gap + right.shape[1], 4), np.uint8)
    canvas[..., 3] = 255
    canvas[:, left.shape[1] + gap // 2 - 1:left.shape[1] + gap // 2 + 1, :3] = 96
    canvas[:left.shape[0], :left.shape[1]] = left
    canvas[:right.shape[0], left.shape[1] + gap:] = right
    picture = Image.fromarray(canvas, "RGBA").convert("RGB")
    if picture.width > MAX_WIDTH:
        picture = picture.resize((MAX_WIDTH, round(picture.height * MAX_WIDTH / picture.width)),
                                 Image.LANCZOS)
    return picture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plotfile", nargs="?", type=Path, default=PLOTFILE)
    parser.add_argument("-o", "--output", type=Path, default=OUT)
    args = parser.parse_args()
    ours = exabricks_picture(args.plotfile)
    with tempfile.TemporaryDirectory() as folder:
        theirs = yt_picture(args.plotfile, Path(folder))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    side_by_side(ours, theirs).save(args.output, optimize=True)
    print(args.output)


if __name__ == "__main__":
    main()
