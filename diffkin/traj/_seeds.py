"""The curves a problem's descent starts from: the straight line, then lines through via points.

Without obstacles the via points are random (near the middle of the start and the goal). With them, each
problem draws :data:`CANDIDATES` via points (three quarters anywhere within the joint limits, a quarter
near the middle), measures the clearance along the curves whose control points lie on ``start -> via ->
goal`` (:data:`SAMPLES` points per segment: the curve cuts the corner at the via point) and keeps the
best: the largest clearance (counted up to ``cap``, the clearance the descent aims for), then the
shortest. A via point that clears the obstacles gives the descent a curve around them that it only has
to smooth; a passage the straight line misses is found this way.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.traj import _rows, _spline

#: via points drawn and screened per problem
CANDIDATES = 32
#: clearance samples per segment of a candidate's curve
SAMPLES = 2
#: metres of clearance one radian of joint-space path length is worth among candidates
PER_RADIAN = 1e-3


def lines(q_start: jax.Array, q_goal: jax.Array, via: jax.Array, free: int) -> jax.Array:
    """``(B, V, free, dof)``: the free control points of ``start -> via -> goal`` (``via`` ``(B, V, dof)``),
    evenly spread, the first half on the first leg."""
    s = jnp.asarray((np.arange(free) + 1) / (free + 1), q_start.dtype)[:, None]  # (free, 1)
    a, b, v = q_start[:, None, None], q_goal[:, None, None], via[:, :, None]
    return jnp.where(s < 0.5, a + (s / 0.5) * (v - a), v + ((s - 0.5) / 0.5) * (b - v))


def _uniform(keys, count: int, lo, hi, dtype) -> jax.Array:
    """``(B, count, dof)``: uniform in ``[lo, hi]`` ``(dof,)``, each problem from its own key of ``keys`` ``(B,)``."""
    return jax.vmap(lambda key: jax.random.uniform(key, (count, lo.shape[-1]), dtype, lo, hi))(keys)


def _near_middle(keys, q_start, q_goal, lower, upper, count: int) -> jax.Array:
    span = jnp.where(jnp.isfinite(upper - lower), upper - lower, 2 * np.pi)
    noise = _uniform(keys, count, -jnp.ones_like(lower), jnp.ones_like(lower), q_start.dtype)
    mid = (q_start + q_goal) / 2
    return jnp.clip(mid[:, None] + 0.25 * span * noise, lower, upper)


def _anywhere(keys, lower, upper, count: int, dtype) -> jax.Array:
    lo = jnp.where(jnp.isfinite(lower), lower, -np.pi)
    hi = jnp.where(jnp.isfinite(upper), upper, np.pi)
    return _uniform(keys, count, lo, hi, dtype)


def seeds(curves, count: int, free: int, keys, first=True) -> tuple[jax.Array, jax.Array]:
    """``(X, ends_clear)``: ``X`` ``(B, count, free, dof)`` the straight line, then ``count - 1`` lines through via
    points, for the problems of ``curves`` (:class:`diffkin.traj._descent.Curves` of one curve per problem),
    each problem's drawn from its own PRNG key of ``keys`` ``(B,)``; where ``first`` (a bool, traced or not) is
    false, ``count`` lines through via points (a later round: the straight line was descended before).
    ``ends_clear`` ``(B,)``: whether the start and the goal clear ``curves.avoid`` by its margin (measured with
    the candidates; exact below it; true without ``avoid``)."""
    q_start, q_goal, lower, upper = curves.q_start, curves.q_goal, curves.lower, curves.upper
    line = lines(q_start, q_goal, (q_start + q_goal)[:, None] / 2, free)
    if curves.avoid is None:
        chosen = lines(q_start, q_goal, _near_middle(keys, q_start, q_goal, lower, upper, count), free)
        ends_clear = jnp.ones(q_start.shape[:1], bool)
    else:
        k_any, k_mid = jax.vmap(jax.random.split, out_axes=1)(keys)
        drawn = max(CANDIDATES, count)
        quarter = drawn // 4
        via = jnp.concatenate(
            [
                _anywhere(k_any, lower, upper, drawn - quarter, q_start.dtype),
                _near_middle(k_mid, q_start, q_goal, lower, upper, quarter),
            ],
            axis=1,
        )  # (B, M, dof)
        if any(curves.locked):
            via = jnp.where(jnp.asarray(curves.locked), curves.locked_q[:, None], via)
        X = lines(q_start, q_goal, via, free)  # (B, M, free, dof)
        length = jnp.linalg.norm(via - q_start[:, None], axis=-1) + jnp.linalg.norm(q_goal[:, None] - via, axis=-1)
        smallest, ends = clearance(curves, X)
        score = jnp.minimum(smallest, curves.cap()) - PER_RADIAN * length
        ends_clear = jnp.all(ends >= curves.avoid.margin, axis=1)
        _, best = jax.lax.top_k(score, count)  # (B, count)
        chosen = jnp.take_along_axis(X, best[:, :, None, None], axis=1)
    return jnp.where(first, jnp.concatenate([line, chosen[:, : count - 1]], axis=1), chosen), ends_clear


def clearance(curves, X: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(smallest (B, V), ends (B, 2))``: the smallest distance (counted up to ``curves.cap()``) along the curves
    of free control points ``X`` ``(B, V, n, dof)`` of ``curves``' problems, at :data:`SAMPLES` points per
    segment and the end, and at their start and goal (which all share)."""
    B, V, n, dof = X.shape
    ends = lambda q: jnp.broadcast_to(q[:, None], (B, V, dof))  # noqa: E731
    P = _spline.control_points(ends(curves.q_start), X, ends(curves.q_goal))  # (B, V, N, dof)
    segs = _spline.segments(n + 2 * _spline.ENDS)
    u = jnp.asarray(np.arange(segs * SAMPLES + 1) / SAMPLES, X.dtype)
    q = _spline.evaluate(P[:, :, None], u).reshape(B * V, -1, dof)  # (B V, Q, dof)
    d_self, d_world = _rows.distances(curves.model, curves.avoid, curves.locked, curves.base, V, q, curves.cap())
    d = _rows.smallest(d_self, d_world, (B * V, q.shape[1]), X.dtype)  # (B V, Q)
    return jnp.min(d, axis=-1).reshape(B, V), d.reshape(B, V, -1)[:, 0, jnp.array([0, -1])]
