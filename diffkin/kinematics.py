"""Forward kinematics, Jacobians and manipulability for every chain model."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain

Chain = DHChain | PoEChain
_FRAMES = ("world", "space", "body")
_METHODS = ("autodiff", "analytic")


def _joint_values(chain: Chain, q) -> jax.Array:
    """``q`` as a float array of shape ``(..., dof)``; raises on a bad chain or shape."""
    if not isinstance(chain, (DHChain, PoEChain)):
        raise TypeError(f"chain: expected a DHChain or PoEChain, got {type(chain).__name__}")
    try:
        q = jnp.asarray(q)
    except OverflowError as err:
        raise ValueError(f"q: expected joint values within the float range, got {q!r:.80}") from err
    if q.dtype == bool or jnp.issubdtype(q.dtype, jnp.complexfloating):
        raise TypeError(f"q: expected real joint values (radians or metres), got dtype {q.dtype}")
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
    return _stack_columns(columns, shape, dtype)


def _autodiff(chain: Chain, q, frame: str) -> jax.Array:
    """Columns from forward-mode derivatives of the end-effector pose, one joint at a time."""
    q = _joint_values(chain, q)
    qs = [q[..., i] for i in range(chain.dof)]

    def pose(i, x):
        ee = chain._frames(qs[:i] + [x] + qs[i + 1:]).ee
        return tuple(jnp.asarray(e, q.dtype) for e in rg.leaves(ee))

    columns = []
    for i in range(chain.dof):
        T, dT = jax.jvp(lambda x, i=i: pose(i, x), (qs[i],), (jnp.ones_like(qs[i]),))
        R, p, dR, dp = _split(T), T[9:], _split(dT), dT[9:]
        if frame == "body":  # [R^T dp; vee(R^T dR)]
            Rt, dRt = [rg.column(R, j) for j in range(3)], [rg.column(dR, j) for j in range(3)]
            columns.append((rg.rotate(Rt, dp), _vee_of_product(Rt, dRt)))
        else:
            w = _vee_of_product(dR, R)  # vee(dR R^T)
            columns.append((dp if frame == "world" else rg.vadd(dp, rg.cross(p, w)), w))
    return _stack_columns(columns, q.shape[:-1], q.dtype)


def _stack_columns(columns, shape, dtype) -> jax.Array:
    """Twist columns ``(v, w)`` (entries) as one ``shape + (6, len(columns))`` array, in one stack."""
    rows = [column[part][i] for part in (0, 1) for i in range(3) for column in columns]
    return rg.stack(rows, shape, dtype).reshape(shape + (6, len(columns)))


def _split(entries) -> rg.Mat3:
    """The rotation of a pose's :func:`rg.leaves`."""
    return tuple(tuple(entries[3 * i: 3 * i + 3]) for i in range(3))  # type: ignore[return-value]


def _vee_of_product(A: rg.Mat3, B: rg.Mat3) -> rg.Vec3:
    """``vee`` of the skew part of ``A B^T`` (only its off-diagonal entries are formed)."""
    W = lambda a, b: rg.dot(A[a], B[b])  # noqa: E731
    return tuple(0.5 * (W(a, b) - W(b, a)) for a, b in ((2, 1), (0, 2), (1, 0)))  # type: ignore[return-value]


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
