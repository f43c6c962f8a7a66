"""Derivatives of IK solutions by the implicit function theorem, not through the iterations."""

from __future__ import annotations

import functools

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


@functools.partial(jax.custom_jvp, nondiff_argnums=(1,))
def implicit_tree(robot, spec, targets: tuple, q: jax.Array, T_world_root, base: jax.Array):
    """``(q, T_world_root)`` unchanged; their derivative is that of the solution of a robot's targets.

    Args:
        robot: the robot (its parameters are differentiable).
        spec: static: the targets' frames, kinds, weights, locked joints, whether the base is solved.
        targets: per target, ``(n, 4, 4)`` poses or ``(n, 3)`` positions.
        q: ``(n, dof)`` solutions.
        T_world_root: ``(n, 4, 4)`` solved root poses, or ``None`` (the root fixed at ``base``).
        base: ``(n, 4, 4)`` the given root pose (differentiable when the root is not solved).

    Returns:
        ``(q, T_world_root)``. The tangent is ``dx = A^+ W (v_target - v_robot)``: ``A`` the
        targets' stacked world Jacobians (root body-twist columns first when the root is solved;
        locked joints have none) turned into the target frames and weighted (``W``), ``v_target``
        the targets' velocities and ``v_robot`` those of the frames when the robot's parameters
        (or the fixed root) move at fixed ``q``; a solved root moves as ``T exp([dx_root])``.
    """
    del robot, spec, targets, base
    return q, T_world_root


@implicit_tree.defjvp
def _implicit_tree_jvp(spec, primals, tangents):
    robot, targets, q, T_world_root, base = primals
    robot_dot, targets_dot, _, _, base_dot = tangents
    B = base if T_world_root is None else T_world_root
    B_dot = base_dot if T_world_root is None else jnp.zeros_like(base_dot)
    rows, rhs = [], []
    for f, pos_only, weights, T_t, T_t_dot in zip(
        spec.frames, spec.position_only, spec.weights, targets, targets_dot, strict=True
    ):
        name = robot.frame_names[f]
        T, dT = jax.jvp(lambda r, b, name=name: kinematics.fk(r, q, name, base=b), (robot, B), (robot_dot, B_dot))
        J = kinematics.jacobian(robot, q, name, frame="world", method="analytic", base=B, include_base=spec.solve_base)
        J = J * jnp.asarray([True] * (6 if spec.solve_base else 0) + [not lock for lock in spec.locked])
        v = (T_t_dot if pos_only else _twist(T_t_dot, T_t, False)) - _twist(dT, T, pos_only)
        if pos_only:
            J = J[..., :3, :]
        elif weights != (1.0,) * 6:  # into the target frame
            Rt = jnp.swapaxes(T_t[..., :3, :3], -1, -2)
            J = jnp.concatenate([Rt @ J[..., :3, :], Rt @ J[..., 3:, :]], axis=-2)
            v = jnp.concatenate(
                [jnp.einsum("...ij,...j->...i", Rt, v[..., :3]), jnp.einsum("...ij,...j->...i", Rt, v[..., 3:])],
                axis=-1,
            )
        keep = [a for a in range(J.shape[-2]) if weights[a] != 0.0]
        w = jnp.asarray([weights[a] for a in keep], J.dtype)
        rows.append(J[..., keep, :] * w[:, None])
        rhs.append(v[..., keep] * w)
    A, b = jnp.concatenate(rows, axis=-2), jnp.concatenate(rhs, axis=-1)
    dx = jnp.einsum("...ij,...j->...i", jnp.linalg.pinv(A), b).astype(q.dtype)
    if T_world_root is None:
        return (q, None), (dx, None)
    dq, v, w = dx[..., 6:], dx[..., :3], dx[..., 3:6]
    hat = jnp.zeros(v.shape[:-1] + (4, 4), v.dtype).at[..., :3, :3].set(se3.skew(w)).at[..., :3, 3].set(v)
    return (q, T_world_root), (dq, T_world_root @ hat)
