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


def propose(problem, q, ev: Eval, mu):
    """The LM trial point from ``q`` (where the residual is ``ev``): ``(q_try, mu)``.

    The step solves ``(J J^T + lam I) y = r, dq = J^T y`` (or the ``dof x dof`` form) and is
    projected onto the limits.
    """
    return problem.retract(q, damped_step(ev.J, ev.r, mu * ev.cost + _LAM_MIN)), mu


def judge(cost, cost_try, mu):
    """``(accepted, mu_new, stalled)``: a trial is accepted only if it lowers ``|r|^2``; a rejected
    one raises the damping (the next trial is a shorter step from the same point)."""
    accept = cost_try < cost
    mu = jnp.where(accept, jnp.maximum(mu * _MU_DOWN, _MU_MIN), mu * _MU_UP)
    return accept, mu, mu >= _MU_MAX
