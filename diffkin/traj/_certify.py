"""A certified lower bound of the clearance over a whole continuous motion.

Each segment of the curve (:mod:`diffkin.traj._spline`) is cut into ``PIECES`` equal pieces. On a
piece of half-width ``w`` (in the curve's parameter), joint ``c`` stays within ``speed_c w`` of its
value at the piece's middle (``speed_c``: a bound on ``|dq_c/du|`` over the piece, from the Bernstein
coefficients of that quadratic on it), so every point of shape ``s`` stays within ``delta_s = sum_c
R[c, s] speed_c w`` (:func:`diffkin.traj._reach.reach`) of where it is at the middle. A distance
measured at the middle (a lower bound of the true one: :mod:`diffkin.collision`) minus the motion of
its shapes (``delta_s`` against an obstacle, ``delta_a + delta_b`` between two of the robot's shapes)
is then a lower bound over the whole piece, and the motion's is the smallest over its pieces.

Only the pairs that a piece's motion could bring within the margin need their exact distance: the
others get a cheap lower bound at least ``margin + 2 max_s delta_s + 1 cm``, the largest motion of the
piece's shapes (:func:`diffkin.collision._near`),
which keeps their pieces above the margin. Pieces of one size (rather than a tree of halvings, whose
coarse pieces move far and so need almost every pair exactly) keep that reach short; then, where a curve's
bound falls below the margin, the quarter of each curve's pieces whose bound is lowest (where a curve passes
close to an obstacle) are cut finer, which tightens the bound where it decides, at a fixed cost (a curve certified
by its pieces is not: that cost would change nothing but how far above the margin its bound is).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.traj import _rows, _spline

#: pieces per segment
PIECES = 32
#: the sub-pieces a refined piece is cut into; ``1 / SUB`` of a curve's pieces are refined (the lowest)
SUB = 4


def _piece_speed(start: jax.Array, mid: jax.Array, end: jax.Array) -> jax.Array:
    """A bound on ``|dq/du|`` over a piece, from ``dq/du`` at its start, middle and end: within a segment
    ``dq/du`` is a quadratic, whose Bernstein coefficients on the piece are ``start``, ``2 mid - (start +
    end) / 2`` and ``end``, and which lies in their convex hull."""
    inner = 2 * mid - (start + end) / 2
    return jnp.maximum(jnp.maximum(jnp.abs(start), jnp.abs(end)), jnp.abs(inner))


def motion(reach: np.ndarray, P: jax.Array, u: jax.Array, half: float) -> tuple[jax.Array, jax.Array]:
    """``(q, delta)``: the curves ``P`` ``(..., N, dof)`` at the pieces' middles ``u`` ``(..., Q)`` (pieces of
    half-width ``half``, each within one segment), ``(..., Q, dof)``, and how far each shape moves from
    there within its piece, ``(..., Q, S)`` metres."""
    Pb = P[..., None, :, :]
    q = _spline.evaluate(Pb, u)
    speed = _piece_speed(*(_spline.evaluate(Pb, u + side * half, 1) for side in (-1, 0, 1)))
    return q, (speed * half) @ jnp.asarray(reach, P.dtype)


def _bounds(model, avoid, reach, P, u, half, base, locked) -> tuple[jax.Array, jax.Array]:
    """``(lower, sampled)`` each ``(B, K, Q)``: per piece of middle ``u`` ``(B, K, Q)`` and half-width ``half``,
    a lower bound of the clearance over it and the smallest distance at its middle."""
    B, K, N, dof = P.shape
    q, delta = motion(reach, P, u, half)  # (B, K, Q, dof), (B, K, Q, S)
    Q = q.shape[2]
    delta = jnp.moveaxis(delta, -1, 0).reshape(-1, B * K, Q)  # (S, C, Q)
    # pairs farther than their piece's motion can bring within the margin need no exact distance: a
    # lower bound at least that far stands for them (the bound of the piece stays above the margin)
    near = (avoid.margin + 2 * jnp.max(delta, axis=0) + 0.01).reshape(B * K * Q)
    d_self, d_world = _rows.distances(model, avoid, locked, base, K, q.reshape(B * K, Q, dof), near)
    lower = _rows.smallest(
        None if d_self is None else d_self - delta[avoid.geom.pairs[:, 0]] - delta[avoid.geom.pairs[:, 1]],
        None if d_world is None else d_world - delta[:, None],
        (B * K, Q),
        P.dtype,
    )
    sampled = _rows.smallest(d_self, d_world, (B * K, Q), P.dtype)
    return lower.reshape(B, K, Q), sampled.reshape(B, K, Q)


def certified(
    model, avoid, reach: np.ndarray, P: jax.Array, base, locked: tuple[bool, ...], pieces: int = PIECES
) -> tuple[jax.Array, jax.Array]:
    """``(lower, sampled)`` each ``(B, K)`` metres: a certified lower bound of the clearance of ``avoid``
    over the curves ``P`` ``(B, K, N, dof)`` (``K`` curves per problem), and the smallest distance
    measured at the pieces' middles (exact for the pairs within the margin plus twice the largest
    motion of a piece plus 1 cm; a cheap lower bound, beyond that, for the others: at least the certified
    bound, at most the true smallest where it is within that reach).

    Each segment is cut into ``pieces`` pieces (a multiple of :data:`SUB`). Where a curve's bound falls below
    ``avoid.margin`` (any curve of the batch: one test), the quarter of each curve's pieces (``1 / SUB``) of
    lowest bound are then cut into :data:`SUB` sub-pieces each, as many as the pieces, and a refined piece's
    bound is the larger of its own and its sub-pieces' smallest (both hold); a batch whose curves all clear the
    margin keeps the pieces' bound (the curves are certified already, and the finer pieces cost about as much
    again). Both passes are one measurement in a loop of at most two steps: one compiled copy of the distances.

    ``avoid``'s world is shared or one per problem, flat ``(B, n_kind)`` (:meth:`diffkin.ik.Avoid.flat`);
    ``base`` ``(B, 4, 4)`` or ``None``; ``reach`` ``(dof, S)`` (:func:`diffkin.traj._reach.reach`).
    """
    assert pieces % SUB == 0, pieces
    B, K, N, dof = P.shape
    Q = _spline.segments(N) * pieces
    refined = Q // SUB
    half = 0.5 / pieces
    mids = jnp.broadcast_to(jnp.asarray((np.arange(Q) + 0.5) / pieces, P.dtype), (B, K, Q))
    offsets = jnp.asarray((2 * np.arange(SUB) + 1 - SUB) / SUB * half, P.dtype)  # sub-pieces' middles

    def finer(lower):  # the middles of the sub-pieces (B, K, Q) of the pieces of lowest bound (B, K, refined)
        chosen = jax.lax.top_k(-lower, refined)[1]
        return (jnp.take_along_axis(mids, chosen, axis=-1)[..., None] + offsets).reshape(B, K, Q), chosen

    def measure(state):  # the pieces' bound, then (a second step) a refined piece's: its own or its sub-pieces'
        n, lower, sampled = state
        first = n == 0
        u, chosen = jax.lax.cond(first, lambda _: (mids, jnp.zeros((B, K, refined), jnp.int32)), finer, lower)
        bound, at_middle = _bounds(model, avoid, reach, P, u, jnp.where(first, half, half / SUB), base, locked)
        fine = jnp.maximum(
            jnp.take_along_axis(lower, chosen, axis=-1), jnp.min(bound.reshape(B, K, refined, SUB), axis=-1)
        )
        lower = jnp.where(first, bound, jnp.put_along_axis(lower, chosen, fine, axis=-1, inplace=False))
        return n + 1, lower, jnp.minimum(sampled, jnp.min(at_middle, axis=-1))

    def more(state):
        n, lower, _ = state
        return (n == 0) | ((n == 1) & jnp.any(jnp.min(lower, axis=-1) < avoid.margin))

    start = (jnp.int32(0), jnp.zeros((B, K, Q), P.dtype), jnp.full((B, K), jnp.inf, P.dtype))
    _, lower, sampled = jax.lax.while_loop(more, measure, start)
    return jnp.min(lower, axis=-1), sampled
