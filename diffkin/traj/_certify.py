"""A certified lower bound of the clearance over a whole continuous motion.

Each segment of the curve (:mod:`diffkin.traj._spline`) is cut in halves ``DEPTH`` times: pieces of
``1, 2, 4, ..., 2^DEPTH`` per segment. On a piece of half-width ``w`` (in the curve's parameter), joint
``c`` stays within ``speed_c w`` of its value at the piece's middle (``speed_c``: a bound on ``|dq_c/du|``
over the piece, from the Bernstein coefficients of that quadratic on it), so every point of shape
``s`` stays within ``delta_s = sum_c R[c, s] speed_c w`` (:func:`diffkin.traj._reach.reach`) of where
it is at the middle. A distance measured at the middle
(a lower bound of the true one: :mod:`diffkin.collision`) minus the motion of its shapes (``delta_s``
against an obstacle, ``delta_a + delta_b`` between two of the robot's shapes) is then a lower bound
over the whole piece. A piece's bound is the larger of its own and the smaller of its two halves'
(the subdivision: a piece too coarse for its own bound is certified by its halves), and the motion's
is the smallest over its segments.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.traj import _rows, _spline

#: halvings of each segment (pieces of 1/2^DEPTH of a segment at the finest level)
DEPTH = 5


def pieces(depth: int = DEPTH) -> tuple[np.ndarray, np.ndarray]:
    """The pieces of one segment, coarsest first: their middles and half-widths ``(2^(depth+1) - 1,)``
    each (in the segment's parameter, ``[0, 1]``)."""
    mids, halves = [], []
    for level in range(depth + 1):
        n = 2**level
        mids.append((np.arange(n) + 0.5) / n)
        halves.append(np.full(n, 0.5 / n))
    return np.concatenate(mids), np.concatenate(halves)


def _piece_speed(start: jax.Array, mid: jax.Array, end: jax.Array) -> jax.Array:
    """A bound on ``|dq/du|`` over a piece, from ``dq/du`` at its start, middle and end: within a segment
    ``dq/du`` is a quadratic, whose Bernstein coefficients on the piece are ``start``, ``2 mid - (start +
    end) / 2`` and ``end``, and which lies in their convex hull."""
    inner = 2 * mid - (start + end) / 2
    return jnp.maximum(jnp.maximum(jnp.abs(start), jnp.abs(end)), jnp.abs(inner))


def _tree(bound: jax.Array, depth: int) -> jax.Array:
    """``(...,)`` per segment from the pieces' own bounds ``(..., 2^(depth+1) - 1)`` (coarsest first):
    each piece the larger of its own and the smaller of its halves', bottom up."""
    start = 2**depth - 1
    below = bound[..., start:]
    for level in range(depth - 1, -1, -1):
        n = 2**level
        own = bound[..., n - 1 : 2 * n - 1]
        halves = jnp.min(below.reshape(below.shape[:-1] + (n, 2)), axis=-1)
        below = jnp.maximum(own, halves)
    return below[..., 0]


def certified(
    model, avoid, reach: np.ndarray, P: jax.Array, base, locked: tuple[bool, ...], depth: int = DEPTH
) -> tuple[jax.Array, jax.Array]:
    """``(lower, sampled)`` each ``(B, K)`` metres: a certified lower bound of the clearance of ``avoid``
    over the curves ``P`` ``(B, K, N, dof)`` (``K`` curves per problem), and the smallest distance
    measured at the pieces' middles (exact for the pairs within the margin plus twice the largest
    motion of a piece plus 1 cm; a cheap lower bound, beyond that, for the others: at least the certified
    bound, at most the true smallest where it is within that reach).

    ``avoid``'s world is shared or one per problem, flat ``(B, n_kind)`` (:meth:`diffkin.ik.Avoid.flat`);
    ``base`` ``(B, 4, 4)`` or ``None``; ``reach`` ``(dof, S)`` (:func:`diffkin.traj._reach.reach`).
    """
    B, K, N, dof = P.shape
    mids, halves = pieces(depth)
    M = len(mids)
    segs = _spline.segments(N)
    u = jnp.asarray(np.arange(segs)[:, None] + mids[None, :], P.dtype)  # (segs, M)
    q = _spline.evaluate(P[:, :, None, None], u)  # (B, K, segs, M, dof)
    half = jnp.asarray(halves, P.dtype)
    ends = [_spline.evaluate(P[:, :, None, None], u + side * half, 1) for side in (-1, 1)]
    mid = _spline.evaluate(P[:, :, None, None], u, 1)
    moved = _piece_speed(ends[0], mid, ends[1]) * half[:, None]  # (B, K, segs, M, dof)
    delta = jnp.moveaxis(moved @ jnp.asarray(reach, P.dtype), -1, 0).reshape(-1, B * K, segs * M)  # (S, C, Q)
    # pairs farther than any piece's motion can bring within the margin need no exact distance: a
    # lower bound at least that far stands for them (the bound of a piece stays above the margin)
    reach = avoid.margin + 2 * jnp.max(delta) + 0.01
    d_self, d_world = _rows.distances(model, avoid, locked, base, K, q.reshape(B * K, segs * M, dof), reach)
    parts, sampled = [], []
    if d_self is not None:
        pairs = avoid.geom.pairs
        parts.append(jnp.min(d_self - delta[pairs[:, 0]] - delta[pairs[:, 1]], axis=0))
        sampled.append(jnp.min(d_self, axis=0))
    if d_world is not None:
        parts.append(jnp.min(d_world - delta[:, None], axis=(0, 1)))
        sampled.append(jnp.min(d_world, axis=(0, 1)))
    if not parts:
        inf = jnp.full((B, K), jnp.inf, P.dtype)
        return inf, inf
    own = jnp.min(jnp.stack(parts), axis=0).reshape(B, K, segs, M)
    lower = jnp.min(_tree(own, depth), axis=-1)
    return lower, jnp.min(jnp.stack(sampled), axis=(0, 2)).reshape(B, K)
