"""benchmarks/bench_preintegration.py: its quadratures against closed forms and dense
float64 integrals, so that its comparison of the midpoint rule with pre-integration
measures the quadratures and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.bench_preintegration import (SUB_STEPS, IntegralTables, midpoint,
                                             preintegrated_1d, preintegrated_2d,
                                             transfer_functions)

UNIT = 0.5


@pytest.fixture(scope="module")
def tfs():
    return transfer_functions((-1.0, 3.0))


def dense_integral(values_at, length, tf, n=200_000):
    """Premultiplied RGBA of one ray of `length` whose value at t is values_at(t), by the
    midpoint rule on n steps (the reference: second order, error ~ 1 / n^2)."""
    h = length / n
    v = values_at((np.arange(n) + 0.5) * h)
    return midpoint(v[None, :], np.array([h]), tf, UNIT)[0]


def test_the_integral_tables_equal_dense_integrals(tfs):
    for tf in tfs.values():
        tables = IntegralTables(tf, UNIT)
        for v in (-1.0, -0.2, 0.77, 1.9, 2.999):
            x = np.linspace(-1.0, v, 400_001)
            mid = 0.5 * (x[1:] + x[:-1])
            rgba = tf.evaluate(mid)
            sigma = tables.sigma(rgba[:, 3])
            dx = x[1] - x[0]
            want = [np.sum(sigma) * dx, *[np.sum(sigma * rgba[:, c]) * dx for c in range(3)]]
            np.testing.assert_allclose(tables(np.array(v)), want, rtol=1e-6, atol=1e-9)


def test_outside_the_span_the_integrals_grow_at_the_end_slopes(tfs):
    tf = tfs["bench"]
    tables = IntegralTables(tf, UNIT)
    ends = tf.evaluate(np.array([-1.0, 3.0]))
    sigma = tables.sigma(ends[:, 3])
    np.testing.assert_allclose(tables(np.array(3.5)) - tables(np.array(3.0)),
                               0.5 * sigma[1] * np.array([1.0, *ends[1, :3]]), rtol=1e-12)
    np.testing.assert_allclose(tables(np.array(-1.5)), -0.5 * sigma[0] * np.array([1.0, *ends[0, :3]]),
                               atol=1e-15)


def test_a_constant_value_gives_every_quadrature_the_closed_form(tfs):
    tf = tfs["bench"]
    tables = IntegralTables(tf, UNIT)
    n, h, value = 7, 0.3, 1.7
    rgba = tf.evaluate(np.array(value))
    alpha = 1.0 - (1.0 - rgba[3]) ** (n * h / UNIT)
    want = np.array([*(rgba[:3] * alpha), alpha])
    steps, hs = np.array([n]), np.array([h])
    np.testing.assert_allclose(midpoint(np.full((1, n), value), hs, tf, UNIT)[0], want, rtol=1e-12)
    ends = np.full((1, n + 1), value)
    np.testing.assert_allclose(preintegrated_1d(ends, steps, hs, tables)[0], want, rtol=1e-12)
    np.testing.assert_allclose(preintegrated_2d(ends, steps, hs, tf, UNIT)[0], want, rtol=1e-12)


def test_one_step_of_a_linear_value_has_the_exact_opacity(tfs):
    """1D pre-integration is exact in opacity for a value linear along the step (Engel
    et al. 2001), whatever the step's length; the 2D integral is the midpoint rule
    inside the step."""
    for name in ("bench", "ramp", "peaks"):
        tf = tfs[name]
        for f, b, h in ((-0.5, 2.5, 0.2), (0.9, 1.1, 1.0), (2.0, 0.5, 0.05)):
            want = dense_integral(lambda t, f=f, b=b, h=h: f + (b - f) * t / h, h, tf)
            ends, steps, hs = np.array([[f, b]]), np.array([1]), np.array([h])
            got = preintegrated_1d(ends, steps, hs, IntegralTables(tf, UNIT))[0]
            np.testing.assert_allclose(got[3], want[3], rtol=1e-6, atol=1e-12)
            # The 2D integral is the midpoint rule on SUB_STEPS sub-steps of the line.
            u = (np.arange(SUB_STEPS) + 0.5) / SUB_STEPS
            sub = midpoint((f + (b - f) * u)[None, :], np.array([h / SUB_STEPS]), tf, UNIT)
            np.testing.assert_allclose(preintegrated_2d(ends, steps, hs, tf, UNIT), sub,
                                       rtol=1e-12)


def test_the_quadratures_converge_to_the_integral_at_second_order(tfs):
    """A smooth value along a ray: the midpoint rule and 1D pre-integration both
    converge to the dense integral, their error falling about 4x per doubling."""
    tf = tfs["ramp"]
    tables = IntegralTables(tf, UNIT)
    length = 3.0
    value = lambda t: 1.0 + 1.5 * np.sin(2.0 * t)
    want = dense_integral(value, length, tf)
    for method in ("midpoint", "pre-integrated"):
        errs = []
        for n in (16, 32, 64):
            h = length / n
            if method == "midpoint":
                got = midpoint(value((np.arange(n) + 0.5) * h)[None, :], np.array([h]), tf, UNIT)
            else:
                got = preintegrated_1d(value(np.arange(n + 1) * h)[None, :], np.array([n]),
                                       np.array([h]), tables)
            errs.append(np.abs(got[0] - want).max())
        assert errs[0] / errs[1] > 3.0 and errs[1] / errs[2] > 3.0, (method, errs)


def test_a_ray_in_a_padded_batch_integrates_only_its_own_steps(tfs):
    """Rays of different step counts share one NaN-padded array: a short ray's image
    equals its image alone (the padding past its last end is no step)."""
    tf = tfs["bench"]
    tables = IntegralTables(tf, UNIT)
    rng = np.random.default_rng(3)
    short, long_ = rng.uniform(-1, 3, 5), rng.uniform(-1, 3, 12)
    batch = np.full((2, 12), np.nan)
    batch[0, :5], batch[1] = short, long_
    steps, h = np.array([4, 11]), np.array([0.3, 0.2])
    alone = preintegrated_1d(short[None, :], steps[:1], h[:1], tables)
    np.testing.assert_allclose(preintegrated_1d(batch, steps, h, tables)[0], alone[0], rtol=1e-13)
    alone = preintegrated_2d(short[None, :], steps[:1], h[:1], tf, UNIT)
    np.testing.assert_allclose(preintegrated_2d(batch, steps, h, tf, UNIT)[0], alone[0], rtol=1e-13)
