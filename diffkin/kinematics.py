"""Forward kinematics, Jacobians and manipulability for every chain model."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin import se3
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain

Chain = DHChain | PoEChain
_FRAMES = ("world", "space", "body")
_METHODS = ("autodiff", "analytic")


def _joint_values(chain: Chain, q) -> jax.Array:
    """``q`` as a float array of shape ``(..., dof)``; raises on a bad chain or shape."""
    if not isinstance(chain, (DHChain, PoEChain)):
        raise TypeError(f"chain: expected a DHChain or PoEChain, got {type(chain).__name__}")
    q = jnp.asarray(q)
    if not jnp.issubdtype(q.dtype, jnp.floating):
        q = q.astype(jnp.result_type(float))
    if q.ndim == 0 or q.shape[-1] != chain.dof:
        raise ValueError(f"q: expected shape (..., {chain.dof}) for a {chain.dof}-joint chain, got {q.shape}")
    return q


def _frames(chain: Chain, q) -> tuple[rg.Frames, tuple[int, ...], jnp.dtype]:
    """Check ``q`` against ``chain`` and run the model's forward pass."""
    q = _joint_values(chain, q)
    frames = chain._frames([q[..., i] for i in range(chain.dof)])
    arrays = [e for e in rg.leaves(frames.ee) if not isinstance(e, float)]
    shape = jnp.broadcast_shapes(q.shape[:-1], *(jnp.shape(e) for e in arrays))
    return frames, shape, jnp.result_type(q, *arrays)


def fk(chain: Chain, q: jax.Array) -> jax.Array:
    """End-effector pose of ``chain`` at ``q``.

    Args:
        chain: a :class:`DHChain` (DH product) or :class:`PoEChain` (product of exponentials).
        q: ``(..., dof)`` joint values, radians (revolute) or metres (prismatic).

    Returns:
        ``(..., 4, 4)`` pose ``T_base_ee`` of the end effector in the base frame, tool included.
    """
    frames, shape, dtype = _frames(chain, q)
    return rg.to_matrix(frames.ee, shape, dtype)


def link_poses(chain: Chain, q: jax.Array) -> jax.Array:
    """Poses of the base and of every moving link.

    Args:
        chain: any chain model.
        q: ``(..., dof)`` joint values.

    Returns:
        ``(..., dof + 1, 4, 4)``: the base frame (DH frame 0, or the identity for a
        :class:`PoEChain`), then the frame of each moving link (DH frame ``i``, or the URDF
        child link of joint ``i``), all in the base frame.
    """
    frames, shape, dtype = _frames(chain, q)
    return jnp.stack([rg.to_matrix(T, shape, dtype) for T in frames.links], axis=-3)


def _world_from_space(screws, p_ee):
    """Columns ``[v + w x p; w]``: the velocity of the point ``p_ee`` and the angular velocity."""
    return [(rg.vadd(v, rg.cross(w, p_ee)), w) for v, w in screws]


def _analytic(chain: Chain, q, frame: str) -> jax.Array:
    frames, shape, dtype = _frames(chain, q)
    columns = frames.screws
    if frame != "space":
        columns = _world_from_space(columns, frames.ee.p)
    if frame == "body":
        Rt = tuple(rg.column(frames.ee.R, j) for j in range(3))
        columns = [(rg.rotate(Rt, v), rg.rotate(Rt, w)) for v, w in columns]
    v = rg.vectors_to_array([c[0] for c in columns], shape, dtype)
    w = rg.vectors_to_array([c[1] for c in columns], shape, dtype)
    return jnp.concatenate([v, w], axis=-2)


def _autodiff(chain: Chain, q, frame: str) -> jax.Array:
    q = _joint_values(chain, q)
    T, tangent = jax.linearize(lambda x: fk(chain, x), q)
    basis = jnp.eye(chain.dof, dtype=q.dtype)
    dT = jax.vmap(lambda e: tangent(jnp.broadcast_to(e, q.shape)))(basis)  # (dof, ..., 4, 4)
    dT = jnp.moveaxis(dT, 0, -1)  # (..., 4, 4, dof)
    R, p = T[..., :3, :3, None], T[..., :3, 3, None]
    dR, dp = dT[..., :3, :3, :], dT[..., :3, 3, :]
    Rt = jnp.swapaxes(T[..., :3, :3], -1, -2)[..., None]
    mm = lambda A, B: jnp.einsum("...ijk,...jlk->...ilk", A, B)  # noqa: E731 (matrix product per column)
    if frame == "body":
        w = _vee_columns(mm(Rt, dR))
        v = jnp.einsum("...ijk,...jk->...ik", Rt, dp)
    else:
        w = _vee_columns(mm(dR, jnp.swapaxes(R, -2, -3)))
        v = dp if frame == "world" else dp + jnp.cross(p, w, axis=-2)
    return jnp.concatenate([v, w], axis=-2)


def _vee_columns(W: jax.Array) -> jax.Array:
    """``(..., 3, 3, n) -> (..., 3, n)``: ``vee`` of each column's skew part."""
    return se3.vee(jnp.moveaxis(W, -1, -3)).swapaxes(-1, -2)


def jacobian(chain: Chain, q: jax.Array, frame: str = "world", *, method: str = "autodiff") -> jax.Array:
    """Geometric Jacobian of the end effector, rows ``[v; w]``.

    Args:
        chain: any chain model.
        q: ``(..., dof)`` joint values.
        frame: ``"world"``: linear velocity of the end-effector origin and angular velocity, both
            in base axes (pytorch-kinematics' ``jacobian``, Pinocchio's ``LOCAL_WORLD_ALIGNED``);
            ``"space"``: spatial twist Jacobian ``J_s`` (column ``i`` is the current screw axis of
            joint ``i`` in the base frame; Pinocchio's ``WORLD``); ``"body"``: body twist
            Jacobian ``J_b = Ad(T^-1) J_s`` in the end-effector frame (Pinocchio's ``LOCAL``).
        method: ``"autodiff"`` differentiates :func:`fk` with JAX (forward mode); ``"analytic"``
            uses the screw axes of the forward pass. Both agree to rounding.

    Returns:
        ``(..., 6, dof)`` Jacobian; column ``i`` is the twist per unit ``q_i``.
    """
    if frame not in _FRAMES:
        raise ValueError(f"frame: expected one of {_FRAMES}, got {frame!r}")
    if method not in _METHODS:
        raise ValueError(f"method: expected one of {_METHODS}, got {method!r}")
    return (_analytic if method == "analytic" else _autodiff)(chain, q, frame)


def manipulability(chain: Chain, q: jax.Array) -> jax.Array:
    """Yoshikawa's manipulability of the world Jacobian.

    ``sqrt(det(J J^T))`` for chains of 6 or more joints, ``sqrt(det(J^T J))`` for fewer (both
    the product of the singular values of ``J``). At a singular configuration the value is 0
    and its gradient is finite (0 there: a subgradient of the measure at its minimum).

    Args:
        chain: any chain model.
        q: ``(..., dof)`` joint values.

    Returns:
        ``(...,)`` manipulability (units of the Jacobian's entries).
    """
    J = jacobian(chain, q, "world", method="analytic")
    Jt = jnp.swapaxes(J, -1, -2)
    G = J @ Jt if chain.dof >= 6 else Jt @ J
    det = jnp.linalg.det(G)
    tiny = jnp.finfo(G.dtype).eps ** 2
    singular = jax.lax.stop_gradient(det) <= tiny
    eye = jnp.eye(G.shape[-1], dtype=G.dtype)
    det_safe = jnp.linalg.det(jnp.where(singular[..., None, None], eye, G))
    return jnp.where(singular, 0.0, jnp.sqrt(det_safe))
