"""The motion: a uniform cubic B-spline in joint space, its exact values and its exact derivative bounds.

Control points ``P (..., N, dof)``: three copies of the start, the free points, three copies of the
goal. With the parameter ``u`` in ``[0, N - 3]`` (one unit per segment, segment ``i`` drawn by
``P[i : i + 4]``), the curve starts at the start and ends at the goal with zero velocity and
acceleration. Its derivatives are B-splines of the control polygon's differences (uniform knots):

- ``dq/du`` lies in the convex hull of the three ``P[k + 1] - P[k]`` of its segment;
- ``d2q/du2`` is piecewise linear, its values at the knots ``P[k + 2] - 2 P[k + 1] + P[k]``;
- ``d3q/du3`` is constant per segment: ``P[k + 3] - 3 P[k + 2] + 3 P[k + 1] - P[k]``;
- the curve itself lies in the convex hull of its segment's four control points.

So every bound below holds over the whole continuous curve, not only where it is sampled. A segment
lasts ``h`` seconds (``t = h u``), so velocity, acceleration and jerk are these divided by ``h``,
``h^2``, ``h^3``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: copies of the start and of the goal among the control points
ENDS = 3


def control_points(q_start: jax.Array, free: jax.Array, q_goal: jax.Array) -> jax.Array:
    """``(..., n + 6, dof)``: the start three times, ``free`` ``(..., n, dof)``, the goal three times."""
    ends = lambda q: jnp.broadcast_to(q[..., None, :], q.shape[:-1] + (ENDS, q.shape[-1]))  # noqa: E731
    return jnp.concatenate([ends(q_start), free, ends(q_goal)], axis=-2)


def segments(n_control: int) -> int:
    """The number of segments of a curve of ``n_control`` control points."""
    return n_control - 3


def basis(u: jax.Array, n_control: int, derivative: int = 0) -> jax.Array:
    """``u.shape + (n_control,)``: the weights of the control points in the curve (or its
    ``derivative``-th derivative with respect to ``u``) at ``u`` (clamped to ``[0, N - 3]``)."""
    last = segments(n_control)
    u = jnp.clip(u, 0.0, last)
    i = jnp.clip(jnp.floor(u), 0, last - 1)
    s = u - i
    if derivative == 0:
        b = [(1 - s) ** 3 / 6, (3 * s**3 - 6 * s**2 + 4) / 6, (-3 * s**3 + 3 * s**2 + 3 * s + 1) / 6, s**3 / 6]
    elif derivative == 1:
        b = [-((1 - s) ** 2) / 2, (3 * s**2 - 4 * s) / 2, (-3 * s**2 + 2 * s + 1) / 2, s**2 / 2]
    elif derivative == 2:
        b = [1 - s, 3 * s - 2, 1 - 3 * s, s]
    elif derivative == 3:
        one = jnp.ones_like(s)
        b = [-one, 3 * one, -3 * one, one]
    else:
        raise ValueError(f"derivative: expected 0, 1, 2 or 3, got {derivative}")
    k = jnp.arange(n_control)
    i = i.astype(jnp.int32)[..., None]
    return jnp.sum(jnp.stack([jnp.where(k == i + j, bj[..., None], 0.0) for j, bj in enumerate(b)]), axis=0)


def evaluate(P: jax.Array, u: jax.Array, derivative: int = 0) -> jax.Array:
    """The curve of control points ``P`` ``(..., N, dof)`` at ``u`` (broadcasting with ``(...)``, or with
    more leading axes): ``(..., dof)``, the ``derivative``-th derivative with respect to ``u``."""
    w = basis(u, P.shape[-2], derivative).astype(P.dtype)
    return jnp.sum(w[..., None] * P, axis=-2)


def differences(P: jax.Array, order: int) -> jax.Array:
    """``(..., N - order, dof)``: the control polygon's ``order``-th differences (see the module docstring)."""
    for _ in range(order):
        P = P[..., 1:, :] - P[..., :-1, :]
    return P


def derivative_bounds(P: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per joint, the largest ``|dq/du|``, ``|d2q/du2|``, ``|d3q/du3|`` over the whole curve, each
    ``(..., dof)`` (exact for the last two, a convex-hull bound for the first)."""
    return tuple(jnp.max(jnp.abs(differences(P, k)), axis=-2) for k in (1, 2, 3))  # type: ignore[return-value]


def segment_speed(P: jax.Array) -> jax.Array:
    """``(..., N - 3, dof)``: per segment and joint, a bound on ``|dq/du|`` over that segment."""
    d = jnp.abs(differences(P, 1))  # (..., N - 1, dof)
    return jnp.maximum(jnp.maximum(d[..., :-2, :], d[..., 1:-1, :]), d[..., 2:, :])


def knots(P: jax.Array) -> jax.Array:
    """``(..., N - 2, dof)``: the curve at the segments' ends ``u = 0, 1, ..., N - 3``."""
    return (P[..., :-2, :] + 4 * P[..., 1:-1, :] + P[..., 2:, :]) / 6


def segment_time(P: jax.Array, velocity, acceleration, jerk=None) -> jax.Array:
    """``(...,)`` seconds per segment: the shortest with ``|dq/dt| <= velocity``, ``|d2q/dt2| <=
    acceleration`` and (given) ``|d3q/dt3| <= jerk`` (each ``(dof,)``) by :func:`derivative_bounds`,
    lengthened by a relative ``1e-4`` so that the bounds hold after rounding; at least ``1e-3``."""
    v, a, j = derivative_bounds(P)
    h = jnp.maximum(jnp.max(v / velocity, axis=-1), jnp.sqrt(jnp.max(a / acceleration, axis=-1)))
    if jerk is not None:
        h = jnp.maximum(h, jnp.cbrt(jnp.max(j / jerk, axis=-1)))
    return jnp.maximum(h * (1 + 1e-4), 1e-3)
