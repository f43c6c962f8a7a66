"""Checks shared by the functions: host-side input conversion (raising), and traceable validity checks
(no raising: they give a boolean per problem)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp


def rigid_tol(dtype) -> float:
    """Tolerance of :func:`rigid_poses`: 1e-9 in float64, 1e-5 in float32."""
    return 1e-9 if jnp.finfo(dtype).bits >= 64 else 1e-5


def rigid_poses(T: jax.Array) -> jax.Array:
    """``(...,)`` whether each ``(..., 4, 4)`` pose is a rigid transform within :func:`rigid_tol`.

    ``|R^T R - I|``, ``|det R - 1|`` and the last row's distance from ``[0, 0, 0, 1]`` (max norms);
    false for non-finite poses.
    """
    tol = rigid_tol(T.dtype)
    R = [[T[..., i, j] for j in range(3)] for i in range(3)]  # entries: no batched 3x3 matmuls (slow on CPU)
    gram = [jnp.abs(sum(R[k][i] * R[k][j] for k in range(3)) - (1.0 if i == j else 0.0))
            for i in range(3) for j in range(i, 3)]
    row = [jnp.abs(T[..., 3, j] - (1.0 if j == 3 else 0.0)) for j in range(4)]
    det = (R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1])
           - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0])
           + R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0]))
    worst = functools.reduce(jnp.maximum, [*gram, *row, jnp.abs(det - 1.0)])
    return worst <= tol  # false for NaN


def real_array(value, name: str, what: str) -> jax.Array:
    """``value`` as a real floating array (integers cast to the default float); raises on the host.

    Raises:
        ValueError: numbers beyond the float range.
        TypeError: bool or complex values.
    """
    try:
        x = jnp.asarray(value)
    except OverflowError as err:
        raise ValueError(f"{name}: expected {what} within the float range, got {value!r:.80}") from err
    if x.dtype == bool or jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"{name}: expected real {what}, got dtype {x.dtype}")
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))
