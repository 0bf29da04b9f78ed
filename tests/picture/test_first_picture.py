"""The first picture (issue 63): the automatic transfer function's colours
spread by opacity-weighted histogram equalisation and its layers placed the
same way, the automatic scale that stays linear on a Gaussian blob, and the
default picture of a dense core smaller than a pixel, which shows bright
where the core is."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from PIL import Image

import exabricks as eb
from exabricks.picture import auto_transfer
from exabricks.picture.auto_transfer import (COLOUR_KNOTS, COLOUR_TRIM, LAYERS, _ambient_shape,
                                             automatic_transfer_function, equalised_colours, layered)
from exabricks.picture.camera import Camera
from exabricks.readers import read
from workflows import make_dense_core, make_series

from helpers import ENZO, build


@functools.lru_cache(maxsize=1)
def _enzo():
    return build(read(str(ENZO), fields=["Density"])).bricks


def _opacity_weight(bricks, field):
    scale, threshold, axis, histogram, _, shape = _ambient_shape(bricks, field, None, None)
    edges = np.linspace(*axis, len(histogram) + 1)
    centres = 0.5 * (edges[1:] + edges[:-1])
    return histogram * np.interp(centres, shape[:, 0], shape[:, 1]), edges, histogram, shape, axis


def test_each_colour_covers_as_much_of_what_is_seen():
    """Between two knots of the equalised colour map lies the same share of the
    opacity-weighted volume, on Enzo's log axis where the top 2.5 decades (the
    core) hold almost none of it."""
    weight, edges, histogram, shape, axis = _opacity_weight(_enzo(), "Density")
    colours = equalised_colours("viridis", histogram, shape, axis)
    knots = colours.rgb_points[:, 0]
    assert len(knots) == COLOUR_KNOTS
    cumulative = np.concatenate([[0.0], np.cumsum(weight) / weight.sum()])
    shares = np.diff(np.interp(knots, edges, cumulative))
    np.testing.assert_allclose(shares, (1 - 2 * COLOUR_TRIM) / (COLOUR_KNOTS - 1), rtol=1e-6)
    # the colours run from the colour map's first to its last
    np.testing.assert_allclose(colours.rgb_points[[0, -1], 1:],
                               [[0.267004, 0.004874, 0.329415], [0.993248, 0.906157, 0.143936]],
                               atol=1e-6)


def test_the_layers_are_bands_at_even_shares_of_the_opacity():
    weight, edges, histogram, shape, axis = _opacity_weight(_enzo(), "Density")
    bands = layered(shape, histogram, axis)
    xs = np.linspace(*axis, 20001)
    ratio = np.interp(xs, bands[:, 0], bands[:, 1]) / np.maximum(
        np.interp(xs, shape[:, 0], shape[:, 1]), 1e-300)
    on = np.interp(xs, shape[:, 0], shape[:, 1]) > 0
    peaks = np.sum((ratio[1:-1] > ratio[:-2]) & (ratio[1:-1] >= ratio[2:]) & on[1:-1]
                   & (ratio[1:-1] > 0.99))
    assert peaks == LAYERS
    assert ratio[on].min() == pytest.approx(auto_transfer.LAYER_FLOOR, abs=0.02)


def test_a_gaussian_blob_stays_on_a_linear_axis(tmp_path):
    """Its tails reach 1e-38, but 5.8 % of its volume lies above 1 % of its
    range: on a log axis most colours would go to the tails."""
    step = make_series.write_step(tmp_path, 0, 8, 16, 2)
    bricks = eb.open(step, cache=tmp_path / "cache").bricks
    tf = automatic_transfer_function(bricks, "phi")
    assert tf.scale == "linear"
    assert automatic_transfer_function(_enzo(), "Density").scale == "log"


@pytest.mark.slow
def test_the_default_picture_of_a_dense_core_shows_it(tmp_path):
    """The default render of the generated core (6 decades, smaller than a
    pixel): an opaque picture, near white at its brightest, whose brightest
    pixels are at the core's projection (issue 63's "Done when")."""
    source = make_dense_core.write(tmp_path / "core")
    image = eb.render(eb.open(source, cache=tmp_path / "cache"), field="density", size=(160, 160))
    image.save(tmp_path / "core.png")
    rgba8 = np.asarray(Image.open(tmp_path / "core.png").convert("RGBA"))
    lum = (rgba8[..., :3] / 255.0) @ np.array([0.2126, 0.7152, 0.0722])
    seen = lum[lum > 0.03]
    assert (rgba8[..., 3] == 255).all() and 0.03 < (lum > 0.03).mean() < 0.95
    assert seen.std() >= 0.08 and np.quantile(seen, 0.99) >= 0.6
    camera = Camera.from_dict(image.metadata["camera"])
    origin, fwd, du, dv = camera.frame(160, 160)
    d = make_dense_core.CORE - origin
    col = ((d @ du) / (du @ du) / (d @ fwd) + 1) * 80
    row = (1 - (d @ dv) / (dv @ dv) / (d @ fwd)) * 80
    near = lum[int(row) - 2:int(row) + 3, int(col) - 2:int(col) + 3]
    assert near.max() >= np.quantile(seen, 0.995)
    assert image.scene.volumes[0].transfer_function.scale == "log"


def _steepness_reference(bricks, field, axis, bins):
    """steepness_histogram by its definition in float64 NumPy (linear scale)."""
    a, b = axis
    out = np.zeros(bins + 1)
    values = np.asarray(bricks.values[bricks.field_index(field)], np.float64)
    for k in range(bricks.n_bricks):
        nx, ny, nz = (int(d) for d in bricks.dims[k])
        first = int(bricks.offset[k])
        cube = values[first:first + nx * ny * nz].reshape(nz, ny, nx)
        width = float(1 << int(bricks.level[k]))
        for axis_index in (2, 1, 0):  # x, y, z neighbours
            lo = np.take(cube, range(cube.shape[axis_index] - 1), axis=axis_index).ravel()
            hi = np.take(cube, range(1, cube.shape[axis_index]), axis=axis_index).ravel()
            s1, s2 = np.minimum(lo, hi), np.maximum(lo, hi)
            keep = np.isfinite(s1) & np.isfinite(s2) & (s2 > s1)
            s1, s2 = s1[keep], s2[keep]
            k1 = np.where(s1 > a, np.minimum(((s1 - a) * bins / (b - a)).astype(int), bins - 1), 0)
            k2 = np.where(s2 > a, np.minimum(((s2 - a) * bins / (b - a)).astype(int), bins - 1), 0)
            np.add.at(out, k1, width * (s2 - s1))
            np.add.at(out, k2 + 1, -width * (s2 - s1))
    return np.cumsum(out[:-1])


def test_the_steepness_histogram_against_its_definition():
    from exabricks.picture.field_statistics import field_range, steepness_histogram

    from helpers import GERRIS

    bricks = build(read(str(GERRIS), fields=["T"])).bricks
    axis = field_range(bricks, "T")
    np.testing.assert_allclose(steepness_histogram(bricks, "T", "linear", 1.0, axis, 64),
                               _steepness_reference(bricks, "T", axis, 64), rtol=1e-9, atol=1e-9)


def test_the_suggested_iso_value_is_crossed_not_held():
    """Not a level that many cells hold exactly (Enzo's top-hat at Density 1,
    Athena++'s ambient rho 1), nor the top of a ridge, nor the ambient band's
    noise: inside what the automatic function shows, with surfaces of their own."""
    from exabricks.picture.auto_transfer import suggested_iso_value

    bricks = _enzo()
    iso = suggested_iso_value(bricks, "Density")
    values = np.asarray(bricks.values[0])
    assert 0.3 < iso < 0.95 and not np.any(values == np.float32(iso))
    # cells on both sides of it: a surface, not the field's extreme
    assert (values < iso).sum() > 1000 and (values > iso).sum() > 1000



def test_an_outlying_cell_does_not_take_the_axis():
    """One cell of Gerris T set to 1000 (the field's range 0 to 0.88): the
    automatic axis is its volume percentiles (auto_transfer.TAIL at either end),
    so the plume keeps its colours and opacity, and the outlier takes the
    colour and opacity of the axis's end."""
    from helpers import GERRIS

    bricks = build(read(str(GERRIS), fields=["T"])).bricks
    values = np.array(bricks.values, copy=True)
    values[0, int(np.argmax(values[0]))] = 1000.0
    spiked = bricks.replace(values=values)
    plain, tf = (automatic_transfer_function(b, "T") for b in (bricks, spiked))
    assert tf.rgb_points[-1, 0] < 1.0 and tf.evaluate(0.8)[3] > 0.1
    for v in (0.1, 0.3, 0.5, 0.8):
        np.testing.assert_allclose(tf.evaluate(v), plain.evaluate(v), atol=0.02)
    np.testing.assert_array_equal(tf.evaluate(1000.0), tf.evaluate(tf.alpha_points[-1, 0]))
