"""`exabricks probe SOURCE|BRICKS REGIONS BVH --points P.npy -o V.npy`: the reconstructed field at points."""

from __future__ import annotations

import click
import numpy as np

from ..util.errors import ExabricksError
from ..util.jsonfile import open_regular
from ..util.output import check_output, write_output
from ..scene import RECONSTRUCTIONS
from .options import dataset_arguments, dataset_from, device_option, field_option, output_option


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
@click.option("--points", "points_path", required=True, type=click.Path(exists=True, dir_okay=False),
              help="World points, a .npy array of shape (N, 3).")
@field_option
@click.option("--reconstruction", type=click.Choice(RECONSTRUCTIONS), default="basis",
              show_default=True,
              help="basis: the paper's continuous blend of cells; nearest: the value of the "
                   "containing leaf cell; vertex: trilinear in stitched vertex values.")
@output_option
@device_option
@dataset_arguments
def probe(inputs, points_path, field, reconstruction, output, device, **options):
    """Reconstructed FIELD at world points (float32 .npy, NaN where no cell has
    support) of a SOURCE (anything `ingest` reads, or a cells file; built and
    cached) or of the three structure files BRICKS REGIONS BVH."""
    from ..stages.probe import probe as probe_points

    check_output(output, [*inputs, points_path])
    points = _load_points(points_path)
    dataset = dataset_from(inputs, options)
    inputs = [*dataset.inputs, points_path]
    check_output(output, inputs)
    bricks, regions, bvh = dataset.structures()
    values = probe_points(bricks, regions, bvh, points, field=field, device=device,
                          reconstruction=reconstruction)
    def write(tmp):
        with open(tmp, "wb") as f:
            np.save(f, values)

    write_output(output, write, inputs=inputs)
