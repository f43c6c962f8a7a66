"""Derivatives of IK solutions by the implicit function theorem, not through the iterations."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin import kinematics, se3


def _twist(dT: jax.Array, T: jax.Array, position_only: bool) -> jax.Array:
    """World-frame velocity ``[dp; vee(dR R^T)]`` (or ``dp``) of a pose tangent ``dT`` at ``T``."""
    dp = dT[..., :3, 3]
    if position_only:
        return dp
    w = se3.vee(dT[..., :3, :3] @ jnp.swapaxes(T[..., :3, :3], -1, -2))
    return jnp.concatenate([dp, w], axis=-1)


@jax.custom_jvp
def implicit_q(chain, target: jax.Array, q: jax.Array) -> jax.Array:
    """``q`` unchanged; its derivative is that of the solution of ``fk(chain, q) = target``.

    Args:
        chain: the chain model (its parameters are differentiable).
        target: ``(..., 4, 4)`` poses or ``(..., 3)`` positions.
        q: ``(..., dof)`` solutions (their own tangent is ignored).

    Returns:
        ``q``. Its tangent is ``dq = J^+ (v_target - v_chain)``: ``J`` the world Jacobian at
        ``q`` (position rows only for position targets), ``J^+`` its pseudo-inverse (the
        minimum-norm joint motion for redundant arms, least squares for under-actuated ones),
        ``v_target`` the world-frame velocity of the target and ``v_chain`` that of the end
        effector when the chain's parameters move at fixed ``q``.
    """
    del chain, target
    return q


@implicit_q.defjvp
def _implicit_q_jvp(primals, tangents):
    chain, target, q = primals
    chain_dot, target_dot, _ = tangents
    position_only = target.shape[-1] == 3
    T, dT_chain = jax.jvp(lambda c: kinematics.fk(c, q), (chain,), (chain_dot,))
    v_chain = _twist(dT_chain, T, position_only)
    v_target = target_dot if position_only else _twist(target_dot, target, False)
    J = kinematics.jacobian(chain, q, "world", method="analytic")
    if position_only:
        J = J[..., :3, :]
    dq = jnp.einsum("...ij,...j->...i", jnp.linalg.pinv(J), v_target - v_chain)
    return q, dq.astype(q.dtype)
