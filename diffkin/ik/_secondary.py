"""Secondary objectives of a redundant robot, lowered in the null space of its targets.

Once a problem's targets are solved, :func:`refine` moves the joints along ``-(I - J^+ J) s``, ``s``
the Newton step of ``h`` (``J`` the targets' weighted Jacobian, so the targets do not move to
first order), then takes one
Gauss-Newton step back onto the targets, and keeps the move only if every target is still within
tolerance and ``h`` went down. The targets' accuracy is therefore what the solver reached, and
``h`` never rises.

Objectives (``h``, summed with their weights over the free joints):

- ``"rest"``: ``|q - q_rest|^2 / 2``, stay near a rest configuration.
- ``"limits"``: ``sum ((2 q - lower - upper) / (upper - lower))^2 / 2`` over limited joints:
  keep away from the joint limits (Liegeois' criterion: 0 mid-range, ``1/2`` per joint at a limit).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin.ik._linalg import damped_step
from diffkin.ik._search import succeeded

OBJECTIVES = ("rest", "limits")
_REFINE_ITERS = 20
_LAM = 1e-6  # m^2: damping of the null-space projection and of the step back onto the targets
_ALPHA0, _ALPHA_MIN = 1.0, 1e-3


def cost_and_step(objectives: tuple, q: jax.Array, rest, lower, upper, free) -> tuple[jax.Array, jax.Array]:
    """``(h, step)`` of the weighted objectives at ``q`` ``(dof, ...)``: ``(...)`` and ``(dof, ...)``.

    ``step`` is the Newton step ``grad h / diag(hess h)`` (each objective is a separable quadratic,
    so a full step reaches its minimum joint by joint, whatever the units and ranges of the joints).
    ``rest``: ``(dof, ...)`` rest configuration (for ``"rest"``); ``lower``/``upper``: ``(dof,)``
    limits; ``free``: ``(dof,)`` bool, the joints the solver moves.
    """
    expand = (slice(None),) + (None,) * (q.ndim - 1)
    h, grad, curvature = jnp.zeros(q.shape[1:], q.dtype), jnp.zeros_like(q), jnp.zeros_like(q)
    for name, weight in objectives:
        if name == "rest":
            d = jnp.where(free[expand], q - rest, 0.0)
            h, grad, curvature = h + weight * 0.5 * jnp.sum(d * d, axis=0), grad + weight * d, curvature + weight
        else:  # "limits"
            limited = (free & jnp.isfinite(lower) & jnp.isfinite(upper) & (upper > lower))[expand]
            span = jnp.where(limited, upper[expand] - lower[expand], 1.0)
            u = jnp.where(limited, (2 * q - jnp.where(limited, lower[expand] + upper[expand], 0.0)) / span, 0.0)
            h = h + weight * 0.5 * jnp.sum(u * u, axis=0)
            grad = grad + weight * 2 * u / span
            curvature = curvature + weight * jnp.where(limited, 4 / (span * span), 0.0)
    return h, jnp.where(free[expand] & (curvature > 0), grad / jnp.where(curvature > 0, curvature, 1.0), 0.0)


def refine(problem, x: jax.Array, ev, success: jax.Array, h_of, pos_tol, rot_tol):
    """Lower ``h`` at the solved states ``x`` ``(n, P)`` without losing their targets.

    Args:
        problem: the problems of ``x`` (``evaluate``, ``retract``).
        ev: the evaluation at ``x``; ``success``: ``(P,)`` which are solved (only those move).
        h_of: ``h_of(x) -> (h (P,), Newton step (dof, P))``.

    Returns:
        ``(x, ev)`` after at most 20 accepted or rejected moves per problem (the step length
        doubles after an accepted move and shrinks 4x after a rejected one).
    """
    dof = h_of(x)[1].shape[0]

    def body(state):
        i, x, ev, h, alpha = state
        g = h_of(x)[1]
        g = jnp.concatenate([g, jnp.zeros((ev.J.shape[1] - dof,) + g.shape[1:], g.dtype)])
        # (I - J^+ J) g with the damped pseudo-inverse J^+ = J^T (J J^T + lam I)^-1
        null_g = g - damped_step(ev.J, jnp.einsum("mnp,np->mp", ev.J, g), jnp.full(alpha.shape, _LAM, g.dtype))
        x1 = problem.retract(x, -alpha * null_g)
        ev1 = problem.evaluate(x1)
        x2 = problem.retract(x1, damped_step(ev1.J, ev1.r, jnp.full(alpha.shape, _LAM, g.dtype)))
        ev2 = problem.evaluate(x2)
        h2 = h_of(x2)[0]
        ok = success & (alpha > _ALPHA_MIN) & succeeded(ev2, pos_tol, rot_tol) & (h2 < h)
        pick = lambda a, b: jax.tree.map(lambda u, v: jnp.where(ok, u, v), a, b)  # noqa: E731
        alpha = jnp.where(ok, jnp.minimum(2 * alpha, 1.0), alpha / 4)
        return i + 1, pick(x2, x), pick(ev2, ev), jnp.where(ok, h2, h), alpha

    def cond(state):
        i, *_, alpha = state
        return (i < _REFINE_ITERS) & jnp.any(success & (alpha > _ALPHA_MIN))

    alpha = jnp.full(success.shape, _ALPHA0, x.dtype)
    _, x, ev, _, _ = jax.lax.while_loop(cond, body, (jnp.asarray(0), x, ev, h_of(x)[0], alpha))
    return x, ev
