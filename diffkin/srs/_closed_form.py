"""Closed-form inverse kinematics of an SRS arm parametrized by the arm angle ``psi``.

Notation of Shimizu et al. (IEEE T-RO 2008) and Faria et al. (MMT 2018), iiwa signs. With the
shoulder at ``x_s = [0, 0, d_bs]``, the wrist at ``x_w = p - d_wf z_7`` and ``x_sw = x_w - x_s``,
the elbow angle ``theta4`` is fixed by ``|x_sw|``; the shoulder frame is the reference frame
``R03_ref`` (the arm with ``theta3 = 0``) rotated by ``psi`` about ``u = x_sw / |x_sw|``:
``R03(psi) = As sin(psi) + Bs cos(psi) + Cs`` with ``As = [u]x R03_ref``, ``Bs = -[u]x^2 R03_ref``,
``Cs = u u^T R03_ref``, and the wrist ``R47(psi) = R34^T R03(psi)^T R07 = Aw sin(psi) + Bw cos(psi) + Cw``.
Every joint is then a function of ``(sin psi, cos psi)`` through a few entries of these matrices:
joints 1, 3, 5, 7 are ``atan2`` of two such entries ("tangent type"), joints 2, 6 the angle whose
cosine is one entry ("cosine type").

Everything is written entry by entry over the batch (structure of arrays, as in
:mod:`diffkin._rigid`), which XLA's CPU backend runs much faster than a ``vmap`` of 3x3 products.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin.srs._arm import SRSArm, broadcast_batch, check_arm, float_input, gc_input, pose_input


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` with a finite derivative (0) where ``x <= 0``."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_atan2(y, x):
    """``atan2(y, x)``; 0 with a finite derivative at ``y = x = 0``.

    Reduced to the octant ``[0, pi/4]`` and computed with ``arctan``, which XLA's CPU backend
    runs about five times faster than ``arctan2``; the result equals ``arctan2`` up to rounding.
    """
    ax, ay = jnp.abs(x), jnp.abs(y)
    steep = ay > ax
    num, den = jnp.where(steep, ax, ay), jnp.where(steep, ay, ax)
    r = jnp.arctan(num / jnp.where(den > 0, den, 1.0))
    r = jnp.where(steep, 0.5 * jnp.pi - r, r)
    r = jnp.where(x < 0, jnp.pi - r, r)
    return jnp.where(jnp.signbit(y), -r, r)


class Trig(NamedTuple):
    """The function ``a sin(psi) + b cos(psi) + c`` of the arm angle (entries of one batch shape)."""

    a: jax.Array
    b: jax.Array
    c: jax.Array

    def at(self, s, c):
        """Value at ``sin(psi) = s``, ``cos(psi) = c``."""
        return self.a * s + self.b * c + self.c

    def scaled(self, g) -> Trig:
        return self.map(lambda x: g * x)

    def map(self, f) -> Trig:
        return Trig(f(self.a), f(self.b), f(self.c))


class Entries(NamedTuple):
    """The entries (1-indexed) of ``R03`` and ``R47`` that the joint angles depend on.

    Each is an array, or a :class:`Trig` for the entries as functions of ``psi``.
    """

    r11: jax.Array
    r21: jax.Array
    r31: jax.Array
    r12: jax.Array
    r22: jax.Array
    r32: jax.Array
    r33: jax.Array
    w11: jax.Array
    w21: jax.Array
    w31: jax.Array
    w13: jax.Array
    w23: jax.Array
    w33: jax.Array
    w32: jax.Array


def _times(g, x):
    return x.scaled(g) if isinstance(x, Trig) else g * x


def tangent_pairs(e: Entries, g2, g6) -> list[tuple]:
    """``(num, den)`` of the tangent-type joints 1, 3, 5, 7: ``theta = atan2(num, den)`` (Shimizu's form)."""
    return [
        (_times(g2, e.r22), _times(g2, e.r12)),
        (_times(-g2, e.r33), _times(-g2, e.r31)),
        (_times(g6, e.w23), _times(g6, e.w13)),
        (_times(g6, e.w32), _times(-g6, e.w31)),
    ]


def _spherical(g, num, den, cos_b, m11, m21, m31) -> list[jax.Array]:
    """Angles ``a, b, c`` of ``M = Rz(a) Rx(-pi/2) Rz(b) Rx(pi/2) Rz(c) X`` with ``X`` fixing the x axis.

    ``a = atan2(num, den)`` with ``(num, den) = g (sin a, cos a) |sin b|``, ``b = atan2(g |sin b|, cos b)``
    (accurate near ``b = 0``, unlike ``g acos(cos b)``), and ``c`` from the first column
    ``(m11, m21, m31)`` of ``M`` given ``a`` and ``b``: ``(cos c, sin c, 0) = (Rz(a) Rx(-pi/2) Rz(b))^T M e1``.
    Solving ``c`` after ``a`` and ``b`` reproduces ``M`` exactly even where ``a`` is ill-conditioned
    (``sin b -> 0``, where only ``a + c`` is determined), so the solution always reaches the pose.
    """
    h = safe_sqrt(num * num + den * den)
    flat = h == 0
    h_safe = jnp.where(flat, 1.0, h)
    cos_a, sin_a = jnp.where(flat, 1.0, den / h_safe), jnp.where(flat, 0.0, num / h_safe)
    sin_b = g * h
    c = safe_atan2(cos_a * m21 - sin_a * m11, cos_b * (cos_a * m11 + sin_a * m21) - sin_b * m31)
    return [safe_atan2(num, den), safe_atan2(sin_b, cos_b), c]


def joint_angles(e: Entries, g2, g6, theta4) -> list[jax.Array]:
    """The seven joint angles (radians) from the matrix entries (arrays) and ``gc2, gc6, theta4``.

    Shoulder ``R03 = R01 R12 R23`` and wrist ``R47 = R45 R56 R67`` have the same structure
    (:func:`_spherical`); away from ``theta2, theta6 = 0`` the result equals Shimizu's
    ``theta3 = atan2(-gc2 r33, -gc2 r31)``, ``theta7 = atan2(gc6 w32, -gc6 w31)``.
    """
    (n1, d1), _, (n5, d5), _ = tangent_pairs(e, g2, g6)
    shoulder = _spherical(g2, n1, d1, e.r32, e.r11, e.r21, e.r31)
    wrist = _spherical(g6, n5, d5, e.w33, e.w11, e.w21, e.w31)
    return shoulder + [theta4] + wrist


def _columns(cols) -> rg.Mat3:
    """The matrix with the given three columns."""
    return tuple(tuple(cols[j][i] for j in range(3)) for i in range(3))  # type: ignore[return-value]


def shoulder_matrices(d_se, d_ew, x_sw: rg.Vec3, c4, s4) -> tuple[rg.Mat3, rg.Mat3, rg.Mat3]:
    """``(As, Bs, Cs)`` with ``R03(psi) = As sin(psi) + Bs cos(psi) + Cs``.

    The reference frame ``R03_ref = R01(theta1v) R12(theta2v) R23(0)`` puts the arm (shoulder,
    elbow, wrist) in the vertical plane through ``x_sw`` (``theta1v = atan2(y, x)``, 0 on the
    joint-1 axis). ``theta2v`` is solved from ``x_sw = R03_ref [-d_ew s4, d_se + d_ew c4, 0]``
    (the shoulder-wrist vector in frame 3), normalised so that ``R03_ref`` stays a rotation
    when the target is out of reach.

    Args:
        d_se, d_ew: upper arm and forearm lengths, metres.
        x_sw: shoulder-to-wrist vector in the base frame, metres (3 entries).
        c4, s4: cosine and sine of ``theta4``.
    """
    x, y, z = x_sw
    rho = safe_sqrt(x * x + y * y)
    on_axis = rho == 0
    rho_safe = jnp.where(on_axis, 1.0, rho)
    c1, s1 = jnp.where(on_axis, 1.0, x / rho_safe), jnp.where(on_axis, 0.0, y / rho_safe)
    v_x, v_y = -d_ew * s4, d_se + d_ew * c4
    cn, sn = v_x * rho + v_y * z, v_y * rho - v_x * z
    norm = safe_sqrt(cn * cn + sn * sn)
    degenerate = norm == 0
    norm_safe = jnp.where(degenerate, 1.0, norm)
    c2, s2 = jnp.where(degenerate, 1.0, cn / norm_safe), jnp.where(degenerate, 0.0, sn / norm_safe)
    ref = ((c1 * c2, c1 * s2, s1), (s1 * c2, s1 * s2, -c1), (-s2, c2, 0.0))
    length = safe_sqrt(x * x + y * y + z * z)
    length_safe = jnp.where(length == 0, 1.0, length)
    u = (x / length_safe, y / length_safe, jnp.where(length == 0, 1.0, z / length_safe))
    a_cols = [rg.cross(u, rg.column(ref, k)) for k in range(3)]
    b_cols = [rg.scale(-1.0, rg.cross(u, a)) for a in a_cols]
    c_cols = [rg.vadd(rg.column(ref, k), rg.scale(-1.0, b)) for k, b in enumerate(b_cols)]
    return _columns(a_cols), _columns(b_cols), _columns(c_cols)


class PoseGeometry(NamedTuple):
    """Everything about one pose and global configuration that does not depend on ``psi``.

    Attributes:
        As, Bs, Cs: shoulder coefficient matrices, ``R03(psi) = As sin(psi) + Bs cos(psi) + Cs``.
        R07: target rotation (3x3 entries).
        c4, s4, theta4: the elbow angle and its cosine and sine.
        g2, g6: the global-configuration signs of joints 2 and 6.
        reachable: whether ``|d_se - d_ew| <= |x_sw| <= d_se + d_ew`` (up to rounding).
    """

    As: rg.Mat3
    Bs: rg.Mat3
    Cs: rg.Mat3
    R07: rg.Mat3
    c4: jax.Array
    s4: jax.Array
    theta4: jax.Array
    g2: jax.Array
    g6: jax.Array
    reachable: jax.Array

    def entries(self, R03: rg.Mat3) -> Entries:
        """The joint-angle entries of ``R03`` and of ``R47 = R34^T R03^T R07``.

        Linear in ``R03``: applied to ``As, Bs, Cs`` it gives the coefficients of the wrist
        matrices ``Aw, Bw, Cw``.
        """
        a0, a1, a2 = (rg.column(R03, k) for k in range(3))
        x7, y7, z7 = (rg.column(self.R07, j) for j in range(3))
        col0 = rg.vadd(rg.scale(self.c4, a0), rg.scale(self.s4, a1))  # columns 0 and 2 of R04 = R03 R34
        col2 = rg.vadd(rg.scale(-self.s4, a0), rg.scale(self.c4, a1))
        return Entries(R03[0][0], R03[1][0], R03[2][0], R03[0][1], R03[1][1], R03[2][1], R03[2][2],
                       rg.dot(col0, x7), -rg.dot(a2, x7), rg.dot(col2, x7),
                       rg.dot(col0, z7), -rg.dot(a2, z7), rg.dot(col2, z7), rg.dot(col2, y7))

    def trig_entries(self) -> Entries:
        """The joint-angle entries as functions of ``psi``."""
        per_matrix = [self.entries(M) for M in (self.As, self.Bs, self.Cs)]
        return Entries(*(Trig(*abc) for abc in zip(*per_matrix, strict=True)))

    def angles(self, psi) -> list[jax.Array]:
        """The seven joint angles (radians) at arm angles ``psi``."""
        s, c = jnp.sin(psi), jnp.cos(psi)
        R03 = tuple(tuple(self.As[i][j] * s + self.Bs[i][j] * c + self.Cs[i][j] for j in range(3)) for i in range(3))
        return joint_angles(self.entries(R03), self.g2, self.g6, self.theta4)


def pose_geometry(arm: SRSArm, target: jax.Array, gc: jax.Array) -> PoseGeometry:
    """The :class:`PoseGeometry` of poses ``target (..., 4, 4)`` and ``gc (..., 3)`` (same float dtype)."""
    dtype = target.dtype
    d_bs, d_se, d_ew, d_wf = (jnp.asarray(v, dtype) for v in (arm.d_bs, arm.d_se, arm.d_ew, arm.d_wf))
    g2, g4, g6 = gc[..., 0], gc[..., 1], gc[..., 2]
    R07 = tuple(tuple(target[..., i, j] for j in range(3)) for i in range(3))
    x_sw = (target[..., 0, 3] - d_wf * R07[0][2], target[..., 1, 3] - d_wf * R07[1][2],
            target[..., 2, 3] - d_wf * R07[2][2] - d_bs)
    c4_raw = (rg.dot(x_sw, x_sw) - d_se * d_se - d_ew * d_ew) / (2.0 * d_se * d_ew)
    reachable = jnp.abs(c4_raw) <= 1.0 + 64.0 * jnp.finfo(dtype).eps
    c4 = jnp.clip(c4_raw, -1.0, 1.0)
    s4 = g4 * safe_sqrt(1.0 - c4 * c4)
    As, Bs, Cs = shoulder_matrices(d_se, d_ew, x_sw, c4, s4)
    return PoseGeometry(As, Bs, Cs, R07, c4, s4, safe_atan2(s4, c4), g2, g6, reachable)


def within_limits(arm: SRSArm, q: list[jax.Array]) -> jax.Array:
    """Whether every joint angle of ``q`` (seven arrays) lies in ``[lower, upper]``."""
    ok = True
    for i, qi in enumerate(q):
        ok = ok & (qi >= arm.lower[i].astype(qi.dtype)) & (qi <= arm.upper[i].astype(qi.dtype))
    return ok


def prepare(arm: SRSArm, target, gc, **extra):
    """Checked ``(target, gc, *extra arrays)`` cast to one float dtype; raises on the host."""
    check_arm(arm)
    target = pose_input(target)
    gc = gc_input(gc)
    arrays = {name: float_input(x, name) for name, x in extra.items()}
    dtype = jnp.result_type(target, *arrays.values())
    broadcast_batch(target=target.shape[:-2], gc=gc.shape[:-1], **{k: v.shape for k, v in arrays.items()})
    return target.astype(dtype), gc.astype(dtype), *(v.astype(dtype) for v in arrays.values())


def ik(arm: SRSArm, target: jax.Array, psi: jax.Array, gc: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Closed-form inverse kinematics at arm angle ``psi`` and global configuration ``gc``.

    Args:
        arm: the arm model.
        target: ``(..., 4, 4)`` flange poses ``T_base_flange`` (the frame of ``dk.fk(arm.chain(), q)``).
        psi: ``(...)`` arm angles, radians: the rotation of the arm plane about the shoulder-wrist
            axis ``u``, counter-clockwise about ``u``, from the reference plane (the vertical plane
            through ``u``, i.e. ``theta3 = 0``).
        gc: ``(..., 3)`` global configuration ``(gc2, gc4, gc6)``, each ``+1`` or ``-1``: the signs
            of joints 2, 4, 6 (``+1`` for an angle ``>= 0``).

    Returns:
        ``q (..., 7)`` joint angles (radians, finite everywhere) and ``valid (...,)``: the pose is in
        reach and ``q`` is within ``[arm.lower, arm.upper]``. The batch shape is that of ``target``,
        ``psi`` and ``gc`` broadcast together; the dtype is that of ``target`` and ``psi``.

    Raises:
        TypeError: ``arm`` is not an :class:`SRSArm`, or non-numeric inputs.
        ValueError: ``target`` not ``(..., 4, 4)``, ``gc`` not ``(..., 3)`` of ``+-1``, or batch
            shapes that do not broadcast.
    """
    target, gc, psi = prepare(arm, target, gc, psi=psi)
    geometry = pose_geometry(arm, target, gc)
    q = geometry.angles(psi)
    shape = jnp.broadcast_shapes(*(x.shape for x in q))
    q = [jnp.broadcast_to(x, shape) for x in q]
    valid = geometry.reachable & within_limits(arm, q)
    return jnp.stack(q, axis=-1), jnp.broadcast_to(valid, shape)


def arm_angle(arm: SRSArm, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Arm angle and global configuration of joint configurations: the inverse of :func:`ik`.

    ``psi`` is the angle of the rotation about ``u`` that takes the reference shoulder frame
    ``R03_ref`` to ``R03(q)``: ``psi = atan2(<R03, As>, <R03, Bs>)`` (Frobenius products; they equal
    ``2 sin(psi)`` and ``2 cos(psi)``). It is also the angle of the elbow about ``u`` from the
    reference elbow, and stays defined for a stretched elbow (``theta4 = 0``).

    Args:
        arm: the arm model.
        q: ``(..., 7)`` joint angles, radians.

    Returns:
        ``psi (...,)`` in ``[-pi, pi]`` and ``gc (..., 3)`` (``+1`` where ``q2, q4, q6 >= 0``, else
        ``-1``), in the dtype of ``q``, such that ``ik(arm, fk(arm.chain(), q), psi, gc)`` gives back
        ``q`` (up to rounding, away from ``q2 = 0`` and ``q6 = 0`` where ``q1 + q3``, resp.
        ``q5 + q7``, is all the pose determines).

    Raises:
        TypeError: ``arm`` is not an :class:`SRSArm`.
        ValueError: ``q`` is not ``(..., 7)``.
    """
    check_arm(arm)
    q = float_input(q, "q")
    if q.ndim == 0 or q.shape[-1] != 7:
        raise ValueError(f"q: expected shape (..., 7) for an SRS arm, got {q.shape}")
    dtype = q.dtype
    d_se, d_ew = jnp.asarray(arm.d_se, dtype), jnp.asarray(arm.d_ew, dtype)
    c = [jnp.cos(q[..., i]) for i in range(4)]
    s = [jnp.sin(q[..., i]) for i in range(4)]
    c1, c2, c3, c4 = c
    s1, s2, s3, s4 = s
    R03 = (
        (c1 * c2 * c3 - s1 * s3, c1 * s2, c1 * c2 * s3 + s1 * c3),
        (s1 * c2 * c3 + c1 * s3, s1 * s2, s1 * c2 * s3 - c1 * c3),
        (-s2 * c3, c2, -s2 * s3),
    )
    x_sw = rg.vadd(rg.scale(-d_ew * s4, rg.column(R03, 0)), rg.scale(d_se + d_ew * c4, rg.column(R03, 1)))
    As, Bs, _ = shoulder_matrices(d_se, d_ew, x_sw, c4, s4)
    frobenius = lambda A, B: rg.add(*(rg.mul(A[i][j], B[i][j]) for i in range(3) for j in range(3)))  # noqa: E731
    psi = safe_atan2(frobenius(R03, As), frobenius(R03, Bs))
    gc = jnp.where(q[..., 1::2] >= 0, 1.0, -1.0).astype(dtype)
    return psi, gc
