"""The fused trigonometry of :mod:`diffkin._trig` against numpy, values and derivatives."""

import jax
import numpy as np
import pytest

from diffkin._trig import atan2, sincos


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_sincos_matches_numpy(dtype):
    rng = np.random.default_rng(15)
    x = np.concatenate(
        [
            rng.uniform(-4, 4, 100_000),
            rng.uniform(-1e4, 1e4, 100_000),
            np.pi / 4 * np.arange(-16, 17),
            [0.0, -0.0, 1e-30],
        ]
    ).astype(dtype)
    s, c = jax.jit(sincos)(x)
    assert s.dtype == c.dtype == dtype
    exact = x.astype(np.longdouble)
    tol = 1e-7 if dtype == np.float32 else 2e-16
    np.testing.assert_allclose(np.asarray(s, np.longdouble), np.sin(exact), rtol=0, atol=tol)
    np.testing.assert_allclose(np.asarray(c, np.longdouble), np.cos(exact), rtol=0, atol=tol)
    # Exact derivatives, to any order (custom JVP on the same function).
    t = np.array([0.3, -2.0, 7.5], dtype)
    ds = jax.vmap(jax.grad(lambda v: sincos(v)[0]))(t)
    d2c = jax.vmap(jax.grad(jax.grad(lambda v: sincos(v)[1])))(t)
    np.testing.assert_allclose(ds, np.cos(t), rtol=1e-6)
    np.testing.assert_allclose(d2c, -np.cos(t), rtol=1e-6)


def test_sincos_of_non_finite_is_nan():
    s, c = sincos(np.array([np.nan, np.inf, -np.inf], np.float32))
    assert np.all(np.isnan(s)) and np.all(np.isnan(c))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fast_atan2_matches_arctan2(dtype):
    rng = np.random.default_rng(14)
    angle, radius = rng.uniform(-np.pi, np.pi, 100_000), np.exp(rng.uniform(-30, 30, 100_000))
    y, x = (radius * np.sin(angle)).astype(dtype), (radius * np.cos(angle)).astype(dtype)
    axes = np.array([[0, 1], [0, -1], [1, 0], [-1, 0], [-0.0, 1], [-0.0, -1], [1, 1], [-1, -1], [1e-30, -1]], dtype)
    y, x = np.concatenate([y, axes[:, 0]]), np.concatenate([x, axes[:, 1]])
    out = np.asarray(jax.jit(atan2)(y, x))
    assert out.dtype == dtype
    tol = 3e-7 if dtype == np.float32 else 5e-16
    np.testing.assert_allclose(out, np.arctan2(y.astype(np.float64), x.astype(np.float64)), rtol=0, atol=tol)
    np.testing.assert_array_equal(np.signbit(out), np.signbit(np.arctan2(y, x)))
    assert float(jax.jit(atan2)(dtype(0), dtype(0))) == 0.0
    # The derivative is exact, and 0 at the origin.
    grad = jax.jit(jax.vmap(jax.grad(atan2, argnums=(0, 1))))
    dy, dx = grad(np.array([0.3, 0.0, -2.0], dtype), np.array([-0.7, 0.0, 0.5], dtype))
    r2 = np.array([0.58, 1.0, 4.25])
    np.testing.assert_allclose(dy, np.array([-0.7, 0.0, 0.5]) / r2 * [1, 0, 1], rtol=1e-6)
    np.testing.assert_allclose(dx, -np.array([0.3, 0.0, -2.0]) / r2, rtol=1e-6)


def _log_uniform(rng, dtype, n, lo_exp=None):
    """``n`` signed values of ``dtype`` with log-uniform magnitudes over the whole finite range."""
    info = np.finfo(dtype)
    lo = np.log10(info.smallest_subnormal) if lo_exp is None else lo_exp
    mag = 10.0 ** rng.uniform(lo, np.log10(info.max), n)
    return (mag * rng.choice([-1.0, 1.0], n)).astype(dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_sincos_over_the_whole_finite_range(dtype):
    """The sine and cosine of the float value itself, as numpy gives them, up to the largest float."""
    rng = np.random.default_rng(18)
    info = np.finfo(dtype)
    x = np.concatenate(
        [
            _log_uniform(rng, dtype, 50_000),
            np.array(
                [
                    1e6,
                    -1e6,
                    1e10,
                    1e20,
                    1e30,
                    -1e30,
                    info.max,
                    -info.max,
                    2.0**13 * 1.5703125,
                    2.0**30 * 1.5703125,
                    12868.0,
                    12869.0,
                    1.7e9,
                    1.6e9,
                ],
                dtype,
            ),
        ]
    )
    x = x[np.isfinite(x)]
    s, c = jax.jit(sincos)(x)
    assert np.all(np.isfinite(s)) and np.all(np.isfinite(c))
    exact = x.astype(np.longdouble)
    tol = 1e-7 if dtype == np.float32 else 2e-16
    np.testing.assert_allclose(np.asarray(s, np.longdouble), np.sin(exact), rtol=0, atol=tol)
    np.testing.assert_allclose(np.asarray(c, np.longdouble), np.cos(exact), rtol=0, atol=tol)
    # Subnormals and signed zeros: sin x = x bit for bit (XLA's CPU arithmetic flushes subnormals).
    tiny = np.array(
        [
            info.smallest_subnormal,
            -info.smallest_subnormal,
            3 * info.smallest_subnormal,
            info.tiny / 2,
            -info.tiny / 3,
            0.0,
            -0.0,
            1e-30,
        ],
        dtype,
    )
    s, c = jax.jit(sincos)(tiny)
    np.testing.assert_array_equal(np.asarray(s), np.sin(tiny))
    np.testing.assert_array_equal(np.signbit(np.asarray(s)), np.signbit(tiny))
    np.testing.assert_array_equal(np.asarray(c), np.ones_like(tiny))
    # Exact derivatives at large angles too, also batched (the fallback branch under vmap).
    t = np.array([3e4, -1e10, 1e30 if dtype == np.float32 else 1e300], dtype)
    ds = jax.jit(jax.vmap(jax.grad(lambda v: sincos(v)[0])))(t)
    dc = jax.vmap(jax.grad(lambda v: sincos(v)[1]))(t)
    np.testing.assert_allclose(ds, np.cos(t), rtol=0, atol=tol)
    np.testing.assert_allclose(dc, -np.sin(t), rtol=0, atol=tol)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_atan2_special_and_subnormal_inputs_as_numpy(dtype):
    info = np.finfo(dtype)
    inf, d = np.inf, info.smallest_subnormal
    y = np.array(
        [
            inf,
            inf,
            -inf,
            -inf,
            inf,
            -inf,
            1,
            -1,
            0,
            -0.0,
            1,
            inf,
            d,
            -d,
            d,
            d,
            -d,
            3 * d,
            d,
            d,
            1,
            info.tiny / 4,
            info.max,
            -info.max,
        ],
        dtype,
    )
    x = np.array(
        [
            inf,
            -inf,
            inf,
            -inf,
            1,
            -1,
            inf,
            -inf,
            inf,
            -inf,
            0,
            0,
            1,
            -1,
            d,
            -d,
            -d,
            2 * d,
            2.0,
            1e20,
            d,
            info.max,
            info.tiny,
            -d,
        ],
        dtype,
    )
    out = np.asarray(jax.jit(atan2)(y, x))
    ref = np.arctan2(y, x)
    np.testing.assert_allclose(out, ref, rtol=3e-7 if dtype == np.float32 else 5e-16, atol=0)
    np.testing.assert_array_equal(np.signbit(out), np.signbit(ref))
    # NaN in, NaN out.
    assert np.all(
        np.isnan(np.asarray(atan2(np.array([np.nan, 1.0, np.nan], dtype), np.array([1.0, np.nan, np.nan], dtype))))
    )
    # Random magnitudes over the whole range (subnormal included): within tolerance, and a
    # subnormal result within one unit of its last place (not flushed to 0).
    rng = np.random.default_rng(19)
    y, x = _log_uniform(rng, dtype, 100_000), _log_uniform(rng, dtype, 100_000)
    out = np.asarray(jax.jit(atan2)(y, x))
    ref = np.arctan2(y, x)
    sub = np.abs(ref) < info.tiny
    tol = 3e-7 if dtype == np.float32 else 5e-16
    np.testing.assert_allclose(out[~sub], ref[~sub], rtol=tol, atol=0)
    assert np.abs(out[sub].astype(np.float64) - ref[sub]).max() <= d
