"""Collision-aware IK's clearance term, evaluated at many configurations of many curves.

One :class:`diffkin.ik._problem.Problem` holding only the clearance term
(:class:`diffkin.ik._terms.avoid.AvoidTerm`), its world tiled so that each configuration sees its own
problem's obstacles: its rows (with their motion Jacobians) for the descent, its distances for the
certificate. Configurations ``q`` ``(C, Q, dof)``: ``Q`` of each of ``C`` curves, ``k`` curves per
problem (consecutive), the world shared or flat per problem ``(B, ...)`` (``C = B k``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin.ik import Avoid
from diffkin.ik.interface import AvoidTerm, Kinematics, Problem, Spec


def problem(model, avoid: Avoid, locked: tuple[bool, ...], base, k: int, Q: int) -> tuple[Problem, AvoidTerm, Avoid]:
    """The problem of ``C Q`` configurations, its term and its data (``avoid`` tiled)."""
    reps = k * Q
    avoid = avoid.tiled(lambda v: jnp.repeat(v, reps, axis=0))
    term = AvoidTerm.of(avoid)
    spec = Spec((), (term,), tuple(locked), (), False, True)
    root = rg.IDENTITY if base is None else rg.from_matrix(jnp.repeat(base, reps, axis=0))
    return spec.problem(model, spec.bind([], (avoid,)), root=root), term, avoid


def rows(model, avoid: Avoid, locked, base, k: int, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``r (m, C, Q)`` the clearance rows and ``dr/dq`` ``(m, dof, C, Q)`` at ``q`` ``(C, Q, dof)``."""
    C, Q, dof = q.shape
    prob, _, _ = problem(model, avoid, locked, base, k, Q)
    ev = prob.evaluate(q.reshape(C * Q, dof).T)
    m = ev.r.shape[0]
    return ev.r.reshape(m, C, Q), -ev.J.reshape(m, dof, C, Q)


def distances(model, avoid: Avoid, locked, base, k: int, q: jax.Array, reach=jnp.inf):
    """The distances at ``q`` ``(C, Q, dof)``: the self pairs' ``(pairs, C, Q)`` in ``avoid.geom.pairs``
    order (``None`` without ``self_collision``) and the shapes' to the world ``(S, W, C, Q)`` (``None``
    without obstacles); lower bounds of the exact ones (:mod:`diffkin.collision`), exact below ``reach``
    (metres; above it a cheap lower bound, at least ``reach``, may stand for a pair's distance)."""
    C, Q, dof = q.shape
    prob, term, data = problem(model, avoid, locked, base, k, Q)
    kin = Kinematics(prob, q.reshape(C * Q, dof).T)
    blocks, d_self, d_world, _, _ = term.measure(kin, data, reach)
    self_d = None
    if blocks:
        order = jnp.concatenate([jnp.asarray(rows) for rows, *_ in blocks])
        stacked = jnp.concatenate([jnp.broadcast_to(d, (d.shape[0], C * Q)) for d in d_self])
        self_d = jnp.zeros_like(stacked).at[order].set(stacked).reshape(-1, C, Q)
    world_d = None if d_world is None else d_world.reshape(d_world.shape[:2] + (C, Q))
    return self_d, world_d


def smallest(d_self, d_world, shape: tuple[int, int], dtype) -> jax.Array:
    """``shape`` ``(C, Q)``: per configuration, the smallest of the self pairs' distances ``(pairs, C, Q)``
    and the world's ``(S, W, C, Q)`` (as :func:`distances` gives them, either ``None``); ``inf`` without
    either, ``-inf`` where a distance is NaN."""
    parts = []
    if d_self is not None:
        parts.append(jnp.min(d_self, axis=0))
    if d_world is not None:
        parts.append(jnp.min(d_world, axis=(0, 1)))
    if not parts:
        return jnp.full(shape, jnp.inf, dtype)
    d = jnp.min(jnp.stack(parts), axis=0)
    return jnp.where(jnp.isnan(d), -jnp.inf, d)
