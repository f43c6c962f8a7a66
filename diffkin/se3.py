"""Rotations and rigid transforms on ``(..., 3, 3)`` / ``(..., 4, 4)`` arrays.

Twists are ``[v; w]`` (linear first). All functions broadcast over leading batch dimensions
and have finite derivatives everywhere, including the identity and half-turns.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from diffkin import _rigid as rg


def skew(w: ArrayLike) -> jax.Array:
    """``(..., 3) -> (..., 3, 3)``: the matrix ``[w]`` with ``[w] x = w x x``."""
    w = jnp.asarray(w)
    z = jnp.zeros_like(w[..., 0])
    rows = [
        jnp.stack([z, -w[..., 2], w[..., 1]], -1),
        jnp.stack([w[..., 2], z, -w[..., 0]], -1),
        jnp.stack([-w[..., 1], w[..., 0], z], -1),
    ]
    return jnp.stack(rows, -2)


def vee(W: jax.Array) -> jax.Array:
    """``(..., 3, 3) -> (..., 3)``: the vector of the skew part of ``W``."""
    return 0.5 * jnp.stack(
        [W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]],
        -1,
    )


def adjoint(T: jax.Array) -> jax.Array:
    """``(..., 4, 4) -> (..., 6, 6)``: ``Ad_T`` acting on twists ``[v; w]``: ``[[R, [p] R], [0, R]]``."""
    R, p = T[..., :3, :3], T[..., :3, 3]
    top = jnp.concatenate([R, skew(p) @ R], -1)
    bottom = jnp.concatenate([jnp.zeros_like(R), R], -1)
    return jnp.concatenate([top, bottom], -2)


def _entries(R: ArrayLike) -> rg.Mat3:
    """The nine entries ``(..., )`` of ``(..., 3, 3)`` matrices."""
    R = jnp.asarray(R)
    return tuple(tuple(R[..., i, j] for j in range(3)) for i in range(3))


def rotation_angle(R: ArrayLike) -> jax.Array:
    """``(..., 3, 3) -> (...,)``: angle in ``[0, pi]`` of rotations, accurate near 0 and pi.

    The matrix form of :func:`diffkin._rigid.rotation_angle`.
    """
    return rg.rotation_angle(_entries(R))


def so3_log(R: ArrayLike) -> jax.Array:
    """``(..., 3, 3) -> (..., 3)``: rotation vector ``w`` with ``R = exp([w])``, ``|w| <= pi``.

    Finite for every rotation: near the identity the series of ``theta / sin(theta)`` is used;
    near a half-turn the axis comes from the symmetric part ``(R + R^T)/2 = I + (1 - cos) a a^T``.
    The matrix form of :func:`diffkin._rigid.so3_log`.
    """
    w, _ = rg.so3_log(_entries(R))
    return jnp.stack(w, -1)


def rotation_from_quaternion(quat: ArrayLike) -> jax.Array:
    """``(..., 4) -> (..., 3, 3)``: rotation of quaternions ``(w, x, y, z)``, normalised here (not zero)."""
    quat = jnp.asarray(quat)
    w, x, y, z = jnp.moveaxis(quat / jnp.linalg.norm(quat, axis=-1, keepdims=True), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return jnp.stack([jnp.stack(row, -1) for row in rows], -2)


def quaternion_from_rotation(R: ArrayLike) -> jax.Array:
    """``(..., 3, 3) -> (..., 4)``: unit quaternions ``(w, x, y, z)`` with ``w >= 0`` of rotations.

    Shepperd's method: of ``4 w^2 - 1 = tr R`` and ``4 x^2 - 1 = 2 R_00 - tr R`` (and y, z), the
    largest is taken as the pivot, so no division is by a small number.
    """
    R = jnp.asarray(R)
    tr = jnp.trace(R, axis1=-2, axis2=-1)
    d0, d1, d2 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    a = [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]]  # 4 w (x, y, z)
    b = [R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1]]  # 4 xy, 4 xz, 4 yz
    pivots = jnp.stack([tr, 2 * d0 - tr, 2 * d1 - tr, 2 * d2 - tr], -1)  # 4 w^2 - 1, 4 x^2 - 1, ...
    s = 2.0 * jnp.sqrt(1.0 + jnp.maximum(pivots, -1.0))  # 4 |w|, 4 |x|, ... (the pivot's is >= 2)
    s = jnp.where(s > 0, s, 1.0)
    candidates = [
        [s[..., 0] / 4, a[0] / s[..., 0], a[1] / s[..., 0], a[2] / s[..., 0]],
        [a[0] / s[..., 1], s[..., 1] / 4, b[0] / s[..., 1], b[1] / s[..., 1]],
        [a[1] / s[..., 2], b[0] / s[..., 2], s[..., 2] / 4, b[2] / s[..., 2]],
        [a[2] / s[..., 3], b[1] / s[..., 3], b[2] / s[..., 3], s[..., 3] / 4],
    ]
    pivot = jnp.argmax(pivots, axis=-1)
    quat = jnp.stack(candidates[3], -1)
    for i in (2, 1, 0):
        quat = jnp.where((pivot == i)[..., None], jnp.stack(candidates[i], -1), quat)
    quat = quat / jnp.linalg.norm(quat, axis=-1, keepdims=True)
    return jnp.where(quat[..., :1] < 0, -quat, quat)
