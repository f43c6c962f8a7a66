"""First-order iterations with an optax gradient transformation, one state per problem."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from diffkin.ik._problem import Eval, gradient


def default_optimizer() -> optax.GradientTransformation:
    """``optax.adam(1e-2)``: steps of about 0.01 rad per iteration."""
    return optax.adam(1e-2)


def init(optimizer: optax.GradientTransformation, q: jax.Array):
    """Optimizer state of every problem, problem axis last (vmapped: no statistic is shared)."""
    return jax.vmap(optimizer.init, in_axes=-1, out_axes=-1)(q)


def step(optimizer: optax.GradientTransformation, problem, q, ev: Eval, state):
    """One optimizer update on ``|r|^2 / 2`` with the exact gradient ``-J^T r``, then projected.

    Returns ``(q_new, ev_new, state_new, accepted, stalled)``: every step is taken (first-order
    methods may go uphill), none stalls.
    """
    updates, state = jax.vmap(optimizer.update, in_axes=-1, out_axes=-1)(gradient(ev), state, q)
    q_new = problem.retract(q, updates)
    ev_new = problem.evaluate(q_new)
    accept = jnp.ones(ev.cost.shape, bool)
    return q_new, ev_new, state, accept, jnp.zeros(ev.cost.shape, bool)
