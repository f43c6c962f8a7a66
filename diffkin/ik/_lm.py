"""Levenberg-Marquardt iterations with adaptive damping and projected steps."""

from __future__ import annotations

import jax.numpy as jnp

from diffkin.ik._linalg import damped_step
from diffkin.ik._problem import Eval

_MU_INIT = 1e-2  # damping lam = mu |r|^2 + lam_min (error-proportional, as in Sugihara 2011)
_MU_MIN = 1e-6
_MU_MAX = 1e6  # a seed whose damping reaches this made no progress in many tries: stalled
_MU_UP, _MU_DOWN = 8.0, 0.25
_LAM_MIN = 1e-10  # m^2: keeps J J^T positive definite at singularities


def init(q: jnp.ndarray) -> jnp.ndarray:
    """Per-problem damping factor ``mu`` ``(P,)`` for ``q`` ``(dof, P)``."""
    return jnp.full(q.shape[1:], _MU_INIT, q.dtype)


def step(problem, q, ev: Eval, mu):
    """One LM trial: ``(q_new, ev_new, mu_new, accepted, stalled)``, one forward pass.

    The step solves ``(J J^T + lam I) y = r, dq = J^T y`` (or the ``dof x dof`` form),
    is projected onto the limits, and is accepted only if it lowers ``|r|^2``; a rejected step
    keeps ``q`` and raises the damping.
    """
    lam = mu * ev.cost + _LAM_MIN
    q_try = problem.retract(q, damped_step(ev.J, ev.r, lam))
    ev_try = problem.evaluate(q_try)
    accept = ev_try.cost < ev.cost
    mu = jnp.where(accept, jnp.maximum(mu * _MU_DOWN, _MU_MIN), mu * _MU_UP)
    return q_try, ev_try, mu, accept, mu >= _MU_MAX
