"""`exabricks probe BRICKS REGIONS BVH --points P.npy -o V.npy`: the reconstructed field at points."""

from __future__ import annotations

import click
import numpy as np

from ..errors import ExabricksError
from ..jsonfile import open_regular
from ..output import check_output, write_output
from ..scene import RECONSTRUCTIONS
from .options import device_option, field_option, input_path, output_option


def _load_points(path) -> np.ndarray:
    with open_regular(path, "points") as f:
        if f.read(6) != b"\x93NUMPY":
            raise ExabricksError(f"{path}: not a .npy array file (it must start with numpy's "
                                 "\\x93NUMPY magic; save points with numpy.save)")
        f.seek(0)
        try:
            points = np.load(f, allow_pickle=False)
        except MemoryError:
            raise
        except Exception as e:  # numpy raises ValueError, OSError, EOFError...
            raise ExabricksError(f"{path}: not a readable .npy array ({e})") from None
    if not isinstance(points, np.ndarray) or points.ndim != 2 or points.shape[1] != 3 \
            or not (np.issubdtype(points.dtype, np.floating) or np.issubdtype(points.dtype, np.integer)):
        shape = getattr(points, "shape", None)
        raise ExabricksError(f"{path}: points must be a numeric (N, 3) array, got shape {shape} "
                             f"and dtype {getattr(points, 'dtype', type(points).__name__)}")
    return points


@click.command()
@input_path("bricks_path", metavar="BRICKS")
@input_path("regions_path", metavar="REGIONS")
@input_path("bvh_path", metavar="BVH")
@click.option("--points", "points_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="World points, a .npy array of shape (N, 3).")
@field_option
@click.option("--reconstruction", type=click.Choice(RECONSTRUCTIONS), default="basis",
              show_default=True,
              help="basis: the paper's continuous blend of cells; nearest: the value of the "
                   "containing leaf cell; vertex: trilinear in stitched vertex values.")
@output_option
@device_option
def probe(bricks_path, regions_path, bvh_path, points_path, field, reconstruction, output, device):
    """Reconstructed FIELD at world points (float32 .npy, NaN where no cell has support)."""
    from ..render.device_data import load_structures
    from ..stages.probe import probe as probe_points

    inputs = [bricks_path, regions_path, bvh_path, points_path]
    check_output(output, inputs)
    points = _load_points(points_path)
    bricks, regions, bvh = load_structures(bricks_path, regions_path, bvh_path)
    values = probe_points(bricks, regions, bvh, points, field=field, device=device,
                          reconstruction=reconstruction)
    def write(tmp):
        with open(tmp, "wb") as f:
            np.save(f, values)

    write_output(output, write, inputs=inputs)
