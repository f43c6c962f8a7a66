"""Closest-point geometry, written batched: vectors are ``(..., 3)`` arrays with broadcasting leading axes.

Everything here is finite with finite derivatives for every input, degenerate ones included
(coincident points, zero-length segments, parallel segments, points on a box face): divisions and
square roots go through :func:`safe_div` and :func:`norm`, whose unused branch never sees a zero.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def dot(u: jax.Array, v: jax.Array) -> jax.Array:
    """``(...,)`` dot product over the last axis."""
    return jnp.sum(u * v, axis=-1)


def norm(v: jax.Array) -> jax.Array:
    """``(...,)`` Euclidean norm over the last axis; its derivative at ``v = 0`` is zero (not NaN)."""
    sq = dot(v, v)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1)), 0)


def safe_div(num: jax.Array, den: jax.Array, default: float = 0.0) -> jax.Array:
    """``num / den`` where ``den > 0``, else ``default`` (derivatives finite)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1), default)


def point_segment(p: jax.Array, a: jax.Array, b: jax.Array) -> jax.Array:
    """``(...,)`` distance from the points ``p`` to the segments ``a``-``b`` (a point if ``a == b``)."""
    d = b - a
    t = jnp.clip(safe_div(dot(p - a, d), dot(d, d)), 0, 1)
    return norm(p - a - t[..., None] * d)


def segment_params(p1: jax.Array, q1: jax.Array, p2: jax.Array, q2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(...,)`` each: the parameters ``s`` (on ``p1``-``q1``) and ``t`` (on ``p2``-``q2``) of a closest pair.

    The clamped least-squares problem (Ericson, *Real-Time Collision Detection*, 5.1.9): ``s`` from
    the unconstrained optimum clamped to ``[0, 1]``, ``t`` as the optimum for that ``s``; if ``t``
    leaves ``[0, 1]`` it is clamped and ``s`` recomputed. Parallel segments (``a e - b^2 = 0``) take
    ``s = 0``; zero-length segments are points. Exact: every branch ends at a closest pair.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
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


def segment_segment(p1: jax.Array, q1: jax.Array, p2: jax.Array, q2: jax.Array) -> jax.Array:
    """``(...,)`` distance between the segments ``p1``-``q1`` and ``p2``-``q2`` (:func:`segment_params`)."""
    s, t = segment_params(p1, q1, p2, q2)
    return norm(p1 - p2 + s[..., None] * (q1 - p1) - t[..., None] * (q2 - p2))


def point_box(p: jax.Array, h: jax.Array) -> jax.Array:
    """``(...,)`` signed distance from the points ``p`` (in the box frame) to the boxes of half extents ``h``.

    Outside: the Euclidean distance; inside: minus the distance to the nearest face.
    """
    q = jnp.abs(p) - h
    return norm(jnp.maximum(q, 0)) + jnp.minimum(jnp.max(q, axis=-1), 0)
