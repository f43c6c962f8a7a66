"""Derivatives of IK solutions by the implicit function theorem, from the problem's own terms.

At a solution ``x`` the residual ``r(x, theta)`` of the terms is (to the tolerance) zero or least
squares, ``theta`` being what the solution depends on: the model's numbers, the targets and a
given root pose. Moving ``theta`` by ``dtheta`` moves the solution by ``dx = J^+ dr``, ``J =
d(-r)/dx`` the terms' Jacobian at ``x`` and ``dr`` the change of the residual at fixed ``x``
(forward mode through the same terms the solver iterates on), ``J^+`` the pseudo-inverse: the
minimum-norm motion for a redundant robot, least squares for an over-constrained one. It is the
derivative of a successful, non-singular solution off the joint limits. A constraint's value that
the search measured at the solution has the derivative of measuring it there (:func:`measured`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin import se3
from diffkin.ik._problem import Kinematics, Problem


def _problem(spec, model, targets: tuple, base) -> Problem:
    """The problem of the targets alone (``n`` each; not the constraints: the derivative is the targets'),
    for its residual (no limits are needed)."""
    targets_only = spec._replace(constraints=())
    bound = targets_only.bind(targets, ())
    return targets_only.problem(model, bound, rg.IDENTITY if base is None else rg.from_matrix(base))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def implicit(spec, model, targets: tuple, base, x: jax.Array) -> jax.Array:
    """``x`` unchanged; its derivative is that of the solution of the problem's terms.

    Args:
        spec: static: the terms (:class:`~diffkin.ik._problem.Spec`), locked joints, whether the root is solved.
        model: the model (its numbers are differentiable).
        targets: per term, ``(n, 4, 4)`` poses or ``(n, 3)`` positions.
        base: ``(n, 4, 4)`` the given root pose (differentiable when the root is not solved), or ``None``.
        x: ``(n_state, n)`` solutions: joints, then (root solved) the root pose rows.

    Returns:
        ``x``, with the tangent ``dx = J^+ dr`` (see the module docstring); a solved root moves as
        ``T exp([dv; dw])``.
    """
    del spec, model, targets, base
    return x


@implicit.defjvp
def _implicit_jvp(spec, primals, tangents):
    model, targets, base, x = primals
    model_dot, targets_dot, base_dot, _ = tangents

    def residual(model, targets, base):
        r = _problem(spec, model, targets, base).residual(x, jacobian=False).r
        return jnp.stack([jnp.broadcast_to(jnp.asarray(e, x.dtype), x.shape[1:]) for e in r])

    _, dr = jax.jvp(residual, (model, targets, base), (model_dot, targets_dot, base_dot))
    J = jnp.moveaxis(_problem(spec, model, targets, base).evaluate(x).J, -1, 0)  # (n, m, columns)
    dx = jnp.einsum("nij,jn->in", jnp.linalg.pinv(J), dr).astype(x.dtype)  # (columns, n)
    if not spec.solve_base:
        return x, dx
    dof = x.shape[0] - 12
    R = jnp.moveaxis(x[dof + 3 :], 0, -1).reshape(-1, 3, 3)
    v, w = dx[dof : dof + 3].T, dx[dof + 3 :].T
    dp = jnp.einsum("nij,nj->in", R, v)
    dR = (R @ se3.skew(w)).reshape(-1, 9).T
    return x, jnp.concatenate([dx[:dof], dp, dR])


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def measured(spec, model, data: tuple, base, x: jax.Array, value: jax.Array) -> jax.Array:
    """``value`` unchanged: the constraint's value at ``x`` as the search measured it (where nothing is
    differentiated); its derivative is that of measuring it at ``x``, ``d value / dx dx`` (only traced
    where differentiated).

    Args:
        spec: static: its one constraint (:class:`~diffkin.ik._problem.Spec`), whether the root is solved.
        model: the model the search solved (detached: its numbers have no derivative here).
        data: per constraint, what it binds (detached).
        base: ``(n, 4, 4)`` the root pose when not solved, or ``None``.
        x: ``(n_state, n)`` the returned states.
        value: ``(n,)`` the constraint's value at ``x`` (``clearance``).
    """
    del spec, model, data, base, x
    return value


@measured.defjvp
def _measured_jvp(spec, primals, tangents):
    model, data, base, x, value = primals
    constraints = spec._replace(targets=())
    root = rg.IDENTITY if base is None else rg.from_matrix(base)
    problem = constraints.problem(model, constraints.bind((), data), root)
    ((constraint, bound),) = zip(constraints.constraints, problem.bound, strict=True)
    _, dvalue = jax.jvp(lambda x: constraint.clearance(Kinematics(problem, x), bound), (x,), (tangents[3],))
    return value, dvalue
