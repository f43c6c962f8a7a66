"""Independent references: float64 NumPy forward kinematics written from the textbook formulas (not from
diffkin's kernels), pose errors, the iiwa's global configurations and, for the validation tier,
Pinocchio's view of a robot (imported on use: the unit tier needs only diffkin, numpy, jax, optax and
hypothesis)."""

from __future__ import annotations

import jax
import numpy as np

import diffkin as dk
from diffkin import se3

ALL_GC = np.array([[g2, g4, g6] for g2 in (1, -1) for g4 in (1, -1) for g6 in (1, -1)], dtype=np.float64)
"""``(8, 3)``: the eight global configurations ``(gc2, gc4, gc6)`` of an SRS arm."""


def _rot(axis: str, angle: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` rotations by ``angle`` about the x or z axis."""
    c, s = np.cos(angle), np.sin(angle)
    M = np.zeros(np.shape(angle) + (4, 4))
    M[..., 3, 3] = 1.0
    i, j, k = (0, 1, 2) if axis == "z" else (1, 2, 0)
    M[..., i, i], M[..., i, j], M[..., j, i], M[..., j, j], M[..., k, k] = c, -s, s, c, 1.0
    return M


def _trans(axis: str, dist: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` translations by ``dist`` along the x or z axis."""
    M = np.broadcast_to(np.eye(4), np.shape(dist) + (4, 4)).copy()
    M[..., "xyz".index(axis), 3] = dist
    return M


def dh_fk(chain, q) -> np.ndarray:
    """FK of a ``DHChain`` as the product of its DH matrices: ``(..., dof) -> (..., 4, 4)`` poses ``T_base_ee``.

    Standard DH multiplies ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` per joint, modified DH
    ``Rx(alpha) Tx(a) Rz(theta) Tz(d)``, between ``chain.base`` and ``chain.tool``.
    """
    q = np.asarray(q, dtype=np.float64)
    batch = q.shape[:-1]
    a, alpha, d, off = (np.asarray(v, dtype=np.float64) for v in (chain.a, chain.alpha, chain.d, chain.theta_offset))
    T = np.broadcast_to(np.asarray(chain.base, dtype=np.float64), batch + (4, 4)).copy()
    for i, kind in enumerate(chain.joint_types):
        theta = q[..., i] + off[i] if kind == "R" else np.full(batch, off[i])
        di = d[i] + q[..., i] if kind == "P" else np.full(batch, d[i])
        alpha_i, a_i = np.full(batch, alpha[i]), np.full(batch, a[i])
        if chain.modified:
            A = _rot("x", alpha_i) @ _trans("x", a_i) @ _rot("z", theta) @ _trans("z", di)
        else:
            A = _rot("z", theta) @ _trans("z", di) @ _trans("x", a_i) @ _rot("x", alpha_i)
        T = T @ A
    return T @ np.asarray(chain.tool, dtype=np.float64)


def _screw_exp(S: np.ndarray, kind: str, theta: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` ``exp([S] theta)`` of a unit screw ``S = [v; w]`` by Rodrigues' formula (``theta (...)``)."""
    v, w, t = S[:3], S[3:], theta[..., None, None]
    E = np.broadcast_to(np.eye(4), theta.shape + (4, 4)).copy()
    if kind == "R":
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        E[..., :3, :3] = np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K
        E[..., :3, 3] = (np.eye(3) * t + (1 - np.cos(t)) * K + (t - np.sin(t)) * K @ K) @ v
    else:
        E[..., :3, 3] = v * theta[..., None]
    return E


def poe_fk(chain, q) -> np.ndarray:
    """FK of a ``PoEChain``, ``exp([S1] q1) ... exp([Sn] qn) M`` by Rodrigues' formula: ``(..., dof) -> (..., 4, 4)``
    poses ``T_base_ee``."""
    q = np.asarray(q, dtype=np.float64)
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    for i, S in enumerate(np.asarray(chain.screws, np.float64)):
        T = T @ _screw_exp(S, chain.joint_types[i], q[..., i])
    return T @ np.asarray(chain.home, np.float64)


def robot_poses(robot, q) -> np.ndarray:
    """``(nf, 4, 4)`` world poses of a fixed-root ``Robot``'s frames at ``q (dof,)``, from its arrays by the
    tree's definition: ``T_body[j + 1] = T_body[parents[j]] @ joint_poses[j] @ exp([screws[j]] theta_j)``,
    ``theta_j = multipliers[j] q[sources[j]] + offsets[j]``, each frame at ``frame_poses[f]`` in its body."""
    q = np.asarray(q, dtype=np.float64)
    arrays = (robot.joint_poses, robot.screws, robot.multipliers, robot.offsets, robot.frame_poses)
    joint_poses, screws, multipliers, offsets, frame_poses = (np.asarray(a, np.float64) for a in arrays)
    bodies = [np.eye(4)]
    for j, parent in enumerate(robot.parents):
        theta = np.asarray(multipliers[j] * q[robot.sources[j]] + offsets[j])
        if robot.joint_types[j] != "B":
            bodies.append(bodies[parent] @ joint_poses[j] @ _screw_exp(screws[j], robot.joint_types[j], theta))
        elif robot.joint_types[: j + 1].count("B") % 3 == 1:  # the first of a ball joint's three: all three bodies
            T = bodies[parent] @ joint_poses[j]
            bodies += [T, T, T @ ball_motion(screws[j : j + 3], q[robot.sources[j] : robot.sources[j] + 3])]
    return np.stack([bodies[b] @ frame_poses[f] for f, b in enumerate(robot.frame_bodies)])


def rodrigues(r) -> np.ndarray:
    """``(3, 3)`` rotation of the rotation vector ``r``: ``cos t I + sin t [a] + (1 - cos t) a a^T``."""
    r = np.asarray(r, np.float64)
    t = np.linalg.norm(r)
    if t == 0:
        return np.eye(3)
    a = r / t
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.cos(t) * np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * np.outer(a, a)


def ball_motion(screws, r) -> np.ndarray:
    """``(4, 4)`` motion of a ball joint with screws ``[c x e_k; e_k]`` ``(3, 6)`` at rotation vector ``r``
    (in the axes ``e_k``): a rotation about the centre ``c``, read off the screws by least squares."""
    screws = np.asarray(screws, np.float64)
    E = screws[:, 3:]  # rows e_k
    K = np.concatenate([-np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]]) for e in E])
    c = np.linalg.lstsq(K, screws[:, :3].reshape(-1), rcond=None)[0]  # c x e_k = -[e_k] c
    T = np.eye(4)
    T[:3, :3] = rodrigues(E.T @ np.asarray(r, np.float64))
    T[:3, 3] = c - T[:3, :3] @ c
    return T


def fk(chain, q) -> np.ndarray:
    """:func:`dh_fk` or :func:`poe_fk`, whichever fits the chain."""
    return dh_fk(chain, q) if isinstance(chain, dk.DHChain) else poe_fk(chain, q)


def rotation_angle(R) -> np.ndarray:
    """``(..., 3, 3) -> (...,)``: angle of rotations, ``atan2(|vee(R)|, (tr R - 1) / 2)`` (accurate near 0 and pi)."""
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.arctan2(np.linalg.norm(skew, axis=-1) / 2, cos)


def pose_errors(T, T_ref) -> tuple[np.ndarray, np.ndarray]:
    """Position errors (m) and rotation-angle errors (rad) between ``(..., 4, 4)`` poses, each ``(...,)``."""
    T, T_ref = np.asarray(T, dtype=np.float64), np.asarray(T_ref, dtype=np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - T_ref[..., :3, 3], axis=-1)
    return pos, rotation_angle(np.swapaxes(T_ref[..., :3, :3], -1, -2) @ T[..., :3, :3])


def pose(R, p) -> np.ndarray:
    """``(4, 4)`` pose of a rotation ``(3, 3)`` and a position ``(3,)``."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def frame_errors(T, targets):
    """Position (m) and rotation (rad) errors ``(n, k)`` between poses ``T`` and ``targets`` (float64)."""
    targets = np.asarray(targets, np.float64)
    pos = np.linalg.norm(T[..., :3, 3] - targets[..., :3, 3], axis=-1)
    with jax.enable_x64(True):
        rot = np.asarray(se3.rotation_angle(targets[..., :3, :3] @ np.swapaxes(T[..., :3, :3], -1, -2)))
    return pos, rot


# ------------------------------------------------------------------ Pinocchio (the validation install)


def pin_q(model, robot, q):
    """Pinocchio's configuration for our ``q``: mimic joints set from their sources (Pinocchio's
    default URDF reader keeps them as independent joints)."""
    import pinocchio as pin

    values = dict(zip(robot.joint_names, q, strict=True))
    for name, (source, m, o) in robot.mimic.items():
        values[name] = m * values[source] + o
    qp = pin.neutral(model)
    for name, value in values.items():
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:  # continuous joints: (cos, sin)
            qp[joint.idx_q : joint.idx_q + 2] = np.cos(value), np.sin(value)
        else:
            qp[joint.idx_q] = value
    return qp


def pin_poses(path, robot, q, names, base=None):
    """``(n, k, 4, 4)`` world poses of frames ``names`` by Pinocchio (float64), the root at ``base``."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    out = np.zeros((len(q), len(names), 4, 4))
    for i in range(len(q)):
        pin.framesForwardKinematics(model, data, pin_q(model, robot, np.asarray(q[i], np.float64)))
        for k, name in enumerate(names):
            M = data.oMf[model.getFrameId(name, pin.BODY)].homogeneous
            out[i, k] = M if base is None else np.asarray(base[i], np.float64) @ M
    return out
