"""Transfer-function tables (docs/design-rendering.md, "Transfer-function tables"): the table
is the knots' piecewise-linear function exactly where the knots lie on a lattice
(every built-in preset and colormap, over any range), within its measured bound
elsewhere; the kernels read it as this module's float32 mirror does; a frame
drawn from tables equals the exact lookup's frame of the same function, on
real data, by packets and one sample at a time, on every OpenCL device."""

from __future__ import annotations

import numpy as np
import pytest

from exabricks.device import kernel_abi, opencl
from exabricks.engine import variants
from exabricks.engine.renderer import Renderer
from exabricks.scene.model import Lighting, Scene, Settings, VolumeLayer
from exabricks.picture.transfer_function import (
    IRREGULAR_TABLE_INTERVALS, MAX_TABLE_INTERVALS, TABLE_TOLERANCE, TransferFunction, default_transfer_function,
    lookup_table, preset_path
)

from helpers import AMREX, GERRIS, built_scene, device_param


def device_lookup(rows: np.ndarray, v: np.ndarray) -> np.ndarray:
    """eb_table_lookup (kernels/transfer_function.cl) in float32, as the device runs it."""
    x0, scale, k = rows[0, 0], rows[0, 1], rows[0, 2]
    v = np.asarray(v, np.float32)
    with np.errstate(invalid="ignore"):
        x = np.fmin(np.fmax((v - x0) * scale, np.float32(0)), k)  # fmax drops a NaN
    i = np.minimum(x.astype(np.int32), np.int32(k) - 1)
    f = (x - i.astype(np.float32))[:, None]
    return (np.float32(1) - f) * rows[1 + i] + f * rows[2 + i]


def exact(xs: np.ndarray, rgba: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The knots' function (eb_transfer_function) in float64: clamped outside, NaN as
    the first knot."""
    v = np.where(np.isnan(v), xs[0], v).astype(np.float64)
    return np.stack([np.interp(v, xs.astype(np.float64), rgba[:, c].astype(np.float64))
                     for c in range(4)], axis=1)


def probe_values(xs: np.ndarray, rng, n: int = 100_000) -> np.ndarray:
    """Every knot and its float32 neighbours, values outside and random values inside."""
    xs = np.asarray(xs, np.float32)
    span = float(xs[-1] - xs[0])
    return np.concatenate([
        xs, np.nextafter(xs, np.float32(np.inf)), np.nextafter(xs, np.float32(-np.inf)),
        np.float32([xs[0] - span, xs[-1] + span, np.inf, -np.inf]),
        rng.uniform(xs[0], xs[-1], n).astype(np.float32)])


def colormap_ramp(lo, hi):
    return TransferFunction.from_colormap("magma", (lo, hi), opacity=[0.0, 0.2, 0.05, 1.0])


LATTICE_PRESETS = {
    "default": lambda lo, hi: default_transfer_function((lo, hi)),
    "inferno-shells": lambda lo, hi: TransferFunction.from_paraview(
        preset_path("inferno-shells")).rescaled((lo, hi)),
    "colormap": colormap_ramp,
}


@pytest.mark.parametrize("preset", list(LATTICE_PRESETS))
@pytest.mark.parametrize("value_range", [(0.0, 1.0), (-3.7, 12.9), (1e3, 1e3 + 7.0)])
def test_presets_on_a_lattice_are_exact(preset, value_range, rng):
    xs, rgba = LATTICE_PRESETS[preset](*value_range).merged_knots(np.float64)
    table = lookup_table(xs, rgba)
    assert table.error_rgb <= 1e-6 and table.error_alpha <= 1e-6
    assert len(table.rows) - 2 <= 4096  # the lattice itself: a table that stays in cache
    v = probe_values(xs, rng)
    np.testing.assert_allclose(device_lookup(table.rows, v), exact(xs, rgba, v), rtol=0,
                               atol=2e-6)


def random_function(rng, n: int, rough: bool = False) -> TransferFunction:
    """Knots at random places on [-2, 5]: a smooth function sampled there, or (rough)
    random values, whose steep pieces take the largest table."""
    x = np.sort(rng.uniform(-2.0, 5.0, n))
    rgb = rng.random((n, 3)) if rough else 0.5 + 0.5 * np.sin(np.outer(x, [1.0, 2.0, 3.0]))
    alpha = rng.random(n) * 0.5 if rough else 0.25 + 0.25 * np.sin(3.0 * x)
    return TransferFunction(np.column_stack([x, rgb]), np.column_stack([x, alpha]))


@pytest.mark.parametrize("knots, rough", [(5, False), (300, False), (40, True), (300, True)])
def test_irregular_knots_stay_within_the_measured_bound(knots, rough, rng):
    """Knots on no lattice: the table differs from the function only near the knots,
    by at most its measured error; a smooth function's table is used, a rough one
    may be too far from its knots even at the largest size."""
    xs, rgba = random_function(rng, knots, rough).merged_knots(np.float64)
    table = lookup_table(xs, rgba)
    error = max(table.error_rgb, table.error_alpha)
    size = len(table.rows) - 2
    assert size in (IRREGULAR_TABLE_INTERVALS, MAX_TABLE_INTERVALS) and error > 0
    if not rough:
        assert size == IRREGULAR_TABLE_INTERVALS and error <= TABLE_TOLERANCE
    v = probe_values(xs, rng, 400_000)
    off = np.abs(device_lookup(table.rows, v) - exact(xs, rgba, v))
    # float32: the value and the table's position are a few roundings off
    steepest = (np.abs(np.diff(rgba, axis=0)) / np.diff(xs)[:, None]).max(axis=0)
    rounding = 2e-6 + steepest * 4 * np.spacing(np.float32(np.abs(xs).max()))
    assert off[:, :3].max() <= table.error_rgb + rounding[:3].max()
    assert off[:, 3].max() <= table.error_alpha + rounding[3]
    # The bound is attained (to the float32 nodes) at a knot: it is no loose estimate.
    assert max(off[:, :3].max(), off[:, 3].max()) >= 0.5 * error


def sawtooth() -> TransferFunction:
    """Opacity that swings 0 -> 1 -> 0 many times within one table interval."""
    x = np.concatenate([np.linspace(0.0, 1e-5, 41)[:-1], [1.0]])
    return TransferFunction(np.array([[0.0, 0, 0, 0], [1.0, 1, 1, 1]]),
                            np.column_stack([x, np.arange(len(x)) % 2]))


def test_a_table_beyond_the_tolerance_falls_back_to_the_knots():
    xs, rgba = sawtooth().merged_knots(np.float64)
    table = lookup_table(xs, rgba)
    assert len(table.rows) - 2 == MAX_TABLE_INTERVALS and table.error_alpha > TABLE_TOLERANCE


LOOKUP_SOURCE = """#include "transfer_function.cl"
__kernel void lookup(__global const float4 *table, __global const float *v, __global float4 *out)
{
    int i = get_global_id(0);
    out[i] = eb_table_lookup(table, v[i]);
}
"""


@device_param
def test_the_device_reads_the_table_as_its_mirror(device, rng):
    import pyopencl as cl

    context, queue = opencl.context_for(opencl.choose_device(device))
    program = cl.Program(context, kernel_abi.header() + LOOKUP_SOURCE).build(
        options=opencl.build_options(variants.variant().defines))
    for tf in (default_transfer_function((-3.0, 7.5)), random_function(rng, 40)):
        xs, rgba = tf.merged_knots(np.float64)
        rows = lookup_table(xs, rgba).rows
        v = np.concatenate([probe_values(xs, rng, 20_000), np.float32([np.nan])])
        out = np.empty((len(v), 4), np.float32)
        out_buf = opencl.empty_buffer(queue, out.nbytes)
        opencl.kernel(program, "lookup")(queue, (len(v),), None, opencl.to_device(queue, rows),
                       opencl.to_device(queue, v), out_buf)
        opencl.read_back(queue, out_buf, out)
        np.testing.assert_allclose(out, device_lookup(rows, v), rtol=0, atol=1e-6)
        np.testing.assert_array_equal(out[-1], rows[1])  # NaN: the first node


def as_knots(rows: np.ndarray) -> TransferFunction:
    """The table's own function, as knots at its nodes."""
    x0, scale, k = (float(c) for c in rows[0, :3])
    x = x0 + np.arange(int(k) + 1) / scale
    nodes = rows[1:].astype(np.float64)
    return TransferFunction(np.column_stack([x, nodes[:, :3]]), np.column_stack([x, nodes[:, 3]]))


def frame(renderer, camera, tf, lookup, shading):
    scene = Scene(camera=camera, volumes=(VolumeLayer(renderer.field, tf),),
                  lighting=Lighting(shading=shading),
                  settings=Settings(width=96, height=96, jitter=False, max_opacity=1.0,
                                    tf_lookup=lookup))
    return renderer.render_scene(scene)


@device_param
@pytest.mark.parametrize("path, field", [(AMREX, "phi"), (GERRIS, "T")], ids=["amrex", "gerris"])
def test_table_frames_equal_exact_frames_on_real_data(path, field, device, rng, monkeypatch):
    """The default preset (on a lattice) gives the exact lookup's frame; a function on
    no lattice gives the frame of its table's own knots, looked up exactly. Both by
    sample packets (on a CPU) and one sample at a time, shaded and not."""
    bricks, regions, bvh, _, camera, tf = built_scene(path, field)
    lo, hi = tf.rgb_points[0, 0], tf.rgb_points[-1, 0]
    odd = random_function(rng, 30)
    odd = TransferFunction(odd.rgb_points * [[(hi - lo) / 7, 1, 1, 1]] + [[lo + 2 * (hi - lo) / 7, 0, 0, 0]],
                           odd.alpha_points * [[(hi - lo) / 7, 1]] + [[lo + 2 * (hi - lo) / 7, 0]])
    table = lookup_table(*odd.merged_knots(np.float64))
    monkeypatch.setattr("exabricks.picture.transfer_function.MAX_KNOTS", len(table.rows))
    nodes = as_knots(table.rows)  # more knots than a preset may hold
    base = Renderer(bricks, regions, bvh, field=field, device=device)
    saw = sawtooth()
    saw = TransferFunction(saw.rgb_points * [[hi - lo, 1, 1, 1]] + [[lo, 0, 0, 0]],
                           saw.alpha_points * [[hi - lo, 1]] + [[lo, 0]])
    assert frame(base, camera, saw, "table", "none").stats["transfer_function_tables"] == [
        {"lookup": "exact"}]  # a table too far from its knots is not used
    for renderer in [base, base.with_packets(False)] if base.packets else [base]:
        for shading in ("none", "headlight"):
            got = frame(renderer, camera, tf, "table", shading)
            assert got.stats["transfer_function_tables"][0]["lookup"] == "table"
            want = frame(renderer, camera, tf, "exact", shading)
            assert want.stats["transfer_function_tables"] == [{"lookup": "exact"}]
            assert got.rgba[..., 3].mean() > 0.01
            np.testing.assert_allclose(got.rgba, want.rgba, rtol=0, atol=2e-5)
            got = frame(renderer, camera, odd, "table", shading)
            assert got.stats["transfer_function_tables"][0]["error_alpha"] > 0
            assert got.rgba[..., 3].mean() > 0.01
            want = frame(renderer, camera, nodes, "exact", shading)
            np.testing.assert_allclose(got.rgba, want.rgba, rtol=0, atol=2e-5)


def test_knots_the_kernels_cannot_tell_apart_are_merged():
    """A log axis down to float32's underflow (the synthetic series' phi reaches
    6e-38) laid knots 1e-40 apart, which the kernels' flushed arithmetic divided
    by: NaN pixels. The float32 knots keep a normal distance between them."""
    xs = np.array([5.93e-38, 8.2892e-38, 8.3001e-38, 1.1586e-37, 1e-30, 1.0])
    tf = TransferFunction(np.column_stack([xs, np.linspace(0, 1, 6), np.zeros(6), np.ones(6)]),
                          np.column_stack([xs, np.linspace(0, 1, 6)]))
    x32, rgba = tf.merged_knots(np.float32)
    assert (np.diff(x32) >= np.finfo(np.float32).tiny).all() and x32[-1] == 1.0 and x32[0] == np.float32(xs[0])
    assert len(x32) == 5 and np.isfinite(rgba).all()
    x64, _ = tf.merged_knots(np.float64)
    assert len(x64) == 6  # the exact function keeps them all
