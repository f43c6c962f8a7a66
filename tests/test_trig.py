"""The fused trigonometry of :mod:`diffkin._trig` against numpy, values and derivatives."""

import jax
import numpy as np
import pytest

from diffkin._trig import atan2, sincos


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_sincos_matches_numpy(dtype):
    rng = np.random.default_rng(15)
    x = np.concatenate([rng.uniform(-4, 4, 100_000), rng.uniform(-1e4, 1e4, 100_000),
                        np.pi / 4 * np.arange(-16, 17), [0.0, -0.0, 1e-30]]).astype(dtype)
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
