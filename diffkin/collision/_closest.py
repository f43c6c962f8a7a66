"""Closest-point geometry in structure of arrays: a vector is a tuple of three arrays (one per coordinate)
of broadcastable batch shapes.

The arithmetic is entry by entry, which XLA's CPU backend fuses into one loop over the batch (as the
rigid transforms of :mod:`diffkin._rigid`), vectorised along its innermost axis, instead of tiny
batched matrix products and reductions over axes of length 3. Everything here is finite with finite
derivatives for every input, degenerate ones included (coincident points, zero-length segments,
parallel segments, points on a box face): divisions and square roots go through :func:`safe_div` and
:func:`sqrt0`, whose unused branch never sees a zero.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

Vec = tuple[jax.Array, ...]  # three entries (x, y, z), each an array of the batch


def vec(x: jax.Array) -> Vec:
    """The coordinates of ``x (..., 3)``."""
    return (x[..., 0], x[..., 1], x[..., 2])


def rotation(pose: jax.Array) -> tuple[Vec, Vec, Vec]:
    """The columns of the rotation of ``pose (..., 4, 4)``: a frame's axes in the outer frame."""
    return tuple((pose[..., 0, j], pose[..., 1, j], pose[..., 2, j]) for j in range(3))  # type: ignore[return-value]


def dot(u: Vec, v: Vec) -> jax.Array:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def sub(u: Vec, v: Vec) -> Vec:
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def to_frame(axes: tuple[Vec, Vec, Vec], v: Vec) -> Vec:
    """``R^T v`` for the rotation of columns ``axes``."""
    return (dot(axes[0], v), dot(axes[1], v), dot(axes[2], v))


def sqrt0(sq: jax.Array) -> jax.Array:
    """``sqrt`` with a zero (not NaN) derivative at 0."""
    ok = sq > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1)), 0)


def norm(v: Vec) -> jax.Array:
    """The Euclidean norm; its derivative at ``v = 0`` is zero (not NaN)."""
    return sqrt0(dot(v, v))


def safe_div(num: jax.Array, den: jax.Array, default: float = 0.0) -> jax.Array:
    """``num / den`` where ``den > 0``, else ``default`` (derivatives finite)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), default)


def lerp(p: Vec, q: Vec, t: jax.Array) -> Vec:
    """``p + t (q - p)``."""
    return (p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), p[2] + t * (q[2] - p[2]))


def point_segment(p: Vec, a: Vec, b: Vec) -> jax.Array:
    """The distance from the points ``p`` to the segments ``a``-``b`` (a point if ``a == b``)."""
    d = sub(b, a)
    t = jnp.clip(safe_div(dot(sub(p, a), d), dot(d, d)), 0, 1)
    return norm(sub(p, lerp(a, b, t)))


def segment_params(p1: Vec, q1: Vec, p2: Vec, q2: Vec) -> tuple[jax.Array, jax.Array]:
    """The parameters ``s`` (on ``p1``-``q1``) and ``t`` (on ``p2``-``q2``) of a closest pair of the segments.

    The clamped least-squares problem (Ericson, *Real-Time Collision Detection*, 5.1.9): ``s`` from
    the unconstrained optimum clamped to ``[0, 1]``, ``t`` as the optimum for that ``s``; if ``t``
    leaves ``[0, 1]`` it is clamped and ``s`` recomputed. Parallel segments (``a e - b^2 = 0``) take
    ``s = 0``; zero-length segments are points. Exact: every branch ends at a closest pair.
    """
    d1, d2, r = sub(q1, p1), sub(q2, p2), sub(p1, p2)
    a, e, f = dot(d1, d1), dot(d2, d2), dot(d2, r)
    c, b = dot(d1, r), dot(d1, d2)
    denom = a * e - b * b
    s = jnp.clip(safe_div(b * f - c * e, denom), 0, 1)
    s = jnp.where(e > 0, s, jnp.clip(safe_div(-c, a), 0, 1))  # second segment a point
    t = safe_div(b * s + f, e)
    s_low = jnp.clip(safe_div(-c, a), 0, 1)  # t clamped to 0
    s_high = jnp.clip(safe_div(b - c, a), 0, 1)  # t clamped to 1
    s = jnp.where(t < 0, s_low, jnp.where(t > 1, s_high, s))
    return s, jnp.clip(t, 0, 1)


def segment_segment(p1: Vec, q1: Vec, p2: Vec, q2: Vec) -> jax.Array:
    """The distance between the segments ``p1``-``q1`` and ``p2``-``q2`` (:func:`segment_params`)."""
    s, t = segment_params(p1, q1, p2, q2)
    return norm(sub(lerp(p1, q1, s), lerp(p2, q2, t)))


def point_box(p: Vec, h: Vec) -> jax.Array:
    """The signed distance from the points ``p`` (in the box frame) to the boxes of half extents ``h``.

    Outside: the Euclidean distance; inside: minus the distance to the nearest face.
    """
    q = tuple(jnp.abs(p[i]) - h[i] for i in range(3))
    outside = norm(tuple(jnp.maximum(x, 0) for x in q))  # type: ignore[arg-type]
    return outside + jnp.minimum(jnp.maximum(jnp.maximum(q[0], q[1]), q[2]), 0)
