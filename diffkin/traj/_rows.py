"""Collision-aware IK's clearance term, evaluated at many configurations of many curves.

One :class:`diffkin.ik._problem.Problem` holding only the clearance term
(:class:`diffkin.ik._terms.avoid.AvoidTerm`), its world tiled so that each configuration sees its own
problem's obstacles: its rows (with their motion Jacobians) for the descent, its distances for the
certificate. Configurations ``q`` ``(C, Q, dof)``: ``Q`` of each of ``C`` curves, ``k`` curves per
problem (consecutive), the world shared or flat per problem ``(B, ...)`` (``C = B k``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin.ik import Avoid
from diffkin.ik.interface import AvoidTerm, Kinematics, Problem, Spec

#: ``1 / SHARE`` of the pairs measured exactly at a time (:func:`diffkin.collision.interface.near_motions`):
#: along a curve far fewer pairs are near than among IK's seeds, and a step costs its whole size
SHARE = 512


def _with_margins(avoid: Avoid, margin: jax.Array) -> Avoid:
    """``avoid`` with a margin per configuration ``margin`` ``(P,)``, rebuilt as JAX rebuilds pytrees: the
    user's ``Avoid(...)`` takes a scalar, the clearance term's arithmetic broadcasts one per state."""
    leaves, treedef = jax.tree_util.tree_flatten_with_path(avoid)
    margin_path = (jax.tree_util.GetAttrKey("margin"),)
    return jax.tree_util.tree_unflatten(treedef, [margin if path == margin_path else x for path, x in leaves])


def problem(
    model, avoid: Avoid, locked: tuple[bool, ...], base, k: int, Q: int, margin=None
) -> tuple[Problem, AvoidTerm, Avoid]:
    """The problem of ``C Q`` configurations, its term and its data (``avoid`` tiled; ``margin`` ``(C Q,)``
    one per configuration in place of ``avoid.margin`` where given)."""
    reps = k * Q
    avoid = avoid.tiled(lambda v: jnp.repeat(v, reps, axis=0))
    if margin is not None:
        avoid = _with_margins(avoid, margin)
    term = dataclasses.replace(AvoidTerm.of(avoid), share=SHARE)
    spec = Spec((), (term,), tuple(locked), (), False, True)
    root = rg.IDENTITY if base is None else rg.from_matrix(jnp.repeat(base, reps, axis=0))
    return spec.problem(model, spec.bind([], (avoid,)), root=root), term, avoid


def rows(model, avoid: Avoid, locked, base, k: int, q: jax.Array, margin=None) -> tuple[jax.Array, jax.Array]:
    """``r (m, C, Q)`` the clearance rows and ``dr/dq`` ``(m, dof, C, Q)`` at ``q`` ``(C, Q, dof)``; ``margin``
    ``(C Q,)``: one per configuration in place of ``avoid.margin`` (``-inf``: no rows there, and no
    distance of that configuration measured exactly)."""
    C, Q, dof = q.shape
    prob, _, _ = problem(model, avoid, locked, base, k, Q, margin)
    ev = prob.evaluate(q.reshape(C * Q, dof).T)
    m = ev.r.shape[0]
    return ev.r.reshape(m, C, Q), -ev.J.reshape(m, dof, C, Q)


def distances(model, avoid: Avoid, locked, base, k: int, q: jax.Array, reach=jnp.inf):
    """The distances at ``q`` ``(C, Q, dof)``: the self pairs' ``(pairs, C, Q)`` in ``avoid.geom.pairs``
    order (``None`` without ``self_collision``) and the shapes' to the world ``(S, W, C, Q)`` (``None``
    without obstacles); lower bounds of the exact ones (:mod:`diffkin.collision`), exact below ``reach``
    (metres, a scalar or one per configuration ``(C Q,)``; above it a cheap lower bound, at least ``reach``,
    may stand for a pair's distance)."""
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
