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


def propose(optimizer: optax.GradientTransformation, problem, q, ev: Eval, state):
    """One optimizer update on ``|r|^2 / 2`` with the exact gradient ``-J^T r``, projected: ``(q_try, state)``."""
    updates, state = jax.vmap(optimizer.update, in_axes=-1, out_axes=-1)(gradient(ev), state, q)
    return problem.retract(q, updates), state


def judge(cost, cost_try, state):
    """Every step is taken (first-order methods may go uphill), none stalls: ``(accepted, state, stalled)``."""
    return jnp.ones(cost.shape, bool), state, jnp.zeros(cost.shape, bool)
