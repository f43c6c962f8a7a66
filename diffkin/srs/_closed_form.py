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
:mod:`diffkin._rigid`), which XLA's CPU backend runs much faster than a ``vmap`` of 3x3 products,
with the fused :func:`diffkin._trig.sincos` and :func:`diffkin._trig.atan2` in place of XLA's
slow ``sin``, ``cos`` and ``atan2``. :func:`ik` materialises its stages (inputs, pose geometry,
``R03``, matrix entries) so that XLA computes each shared value once, and takes large batches in
steps of :data:`CHUNK` problems.
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from diffkin import _rigid as rg
from diffkin._checks import broadcast_batch, instance, pose_array, real_array, rigid_poses, sign_array
from diffkin._trig import atan2, sincos
from diffkin._xla import in_steps, materialize, stacked_atan2
from diffkin.srs._arm import AN_ARM, SRSArm

POSE_TOL = {False: 1e-4, True: 1e-9}
"""Largest entry of ``fk(q) - target`` (rotation entries, and position in metres) of a valid solution:
float32 (key ``False``), float64 (``True``); far above the closed form's rounding, far below a wrong solution."""

CHUNK = 4096
"""Problems per step of :func:`ik` on large batches (:func:`diffkin._xla.in_steps`)."""


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` with a finite derivative (0) where ``x <= 0``."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


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


class AngleEntries(NamedTuple):
    """The entries (1-indexed) of ``R03`` and ``R47`` that the joint angles depend on.

    Each is an entry (an array over the batch), or a :class:`Trig` for the entries as functions of
    ``psi`` (hence typed ``Any``).
    """

    r11: Any
    r21: Any
    r31: Any
    r12: Any
    r22: Any
    r32: Any
    r33: Any
    w11: Any
    w21: Any
    w31: Any
    w13: Any
    w23: Any
    w33: Any
    w32: Any


ANGLE_ENTRIES = ("r11", "r21", "r31", "r12", "r22", "r32", "w11", "w21", "w31", "w13", "w23", "w33")
"""The entries :func:`joint_angles` uses (``r33`` and ``w32`` only enter the joint-limit roots)."""


def _times(g, x):
    return x.scaled(g) if isinstance(x, Trig) else g * x


def tangent_pairs(e: AngleEntries, g2, g6) -> list[tuple]:
    """``(num, den)`` of the tangent-type joints 1, 3, 5, 7: ``theta = atan2(num, den)`` (Shimizu's form)."""
    return [
        (_times(g2, e.r22), _times(g2, e.r12)),
        (_times(-g2, e.r33), _times(-g2, e.r31)),
        (_times(g6, e.w23), _times(g6, e.w13)),
        (_times(g6, e.w32), _times(-g6, e.w31)),
    ]


def _spherical(g, num, den, cos_b, m11, m21, m31) -> list[tuple[jax.Array, jax.Array]]:
    """``(y, x)`` pairs whose ``atan2`` are the angles ``a, b, c`` of ``M = Rz(a) Rx(-pi/2) Rz(b) Rx(pi/2) Rz(c) X``
    with ``X`` fixing the x axis.

    ``a = atan2(num, den)`` with ``(num, den) = g (sin a, cos a) |sin b|``, ``b = atan2(g |sin b|, cos b)``
    (accurate near ``b = 0``, unlike ``g acos(cos b)``), and ``c`` from the first column
    ``(m11, m21, m31)`` of ``M`` given ``a`` and ``b``: ``(cos c, sin c, 0) = (Rz(a) Rx(-pi/2) Rz(b))^T M e1``.
    Solving ``c`` after ``a`` and ``b`` reproduces ``M`` exactly even where ``a`` is ill-conditioned
    (``sin b -> 0``, where only ``a + c`` is determined), so the solution always reaches the pose.
    """
    h2 = num * num + den * den
    flat = h2 == 0
    sin_b = g * safe_sqrt(h2)
    # h (cos c, sin c): positive scaling leaves the angle unchanged and saves two divisions
    y = jnp.where(flat, m21, den * m21 - num * m11)
    x = jnp.where(flat, cos_b * m11, cos_b * (den * m11 + num * m21) - g * h2 * m31)
    return [(num, den), (sin_b, cos_b), (y, x)]


def joint_angles(e: AngleEntries, g2, g6, theta4) -> list[jax.Array]:
    """The seven joint angles (radians) from the matrix entries (arrays) and ``gc2, gc6, theta4``.

    Shoulder ``R03 = R01 R12 R23`` and wrist ``R47 = R45 R56 R67`` have the same structure
    (:func:`_spherical`); away from ``theta2, theta6 = 0`` the result equals Shimizu's
    ``theta3 = atan2(-gc2 r33, -gc2 r31)``, ``theta7 = atan2(gc6 w32, -gc6 w31)``.
    """
    (n1, d1), _, (n5, d5), _ = tangent_pairs(e, g2, g6)
    shoulder = _spherical(g2, n1, d1, e.r32, e.r11, e.r21, e.r31)
    wrist = _spherical(g6, n5, d5, e.w33, e.w11, e.w21, e.w31)
    angles = stacked_atan2(shoulder + wrist)  # one atan2 (one lax.cond) for the six angles
    return angles[:3] + [theta4] + angles[3:]


def _rows(flat) -> rg.Mat3:
    """The matrix with the given nine entries, row by row."""
    return (tuple(flat[0:3]), tuple(flat[3:6]), tuple(flat[6:9]))


def _columns(cols) -> rg.Mat3:
    """The matrix with the given three columns."""
    return tuple(tuple(cols[j][i] for j in range(3)) for i in range(3))


def shoulder_frame(d_se, d_ew, x_sw: rg.Vec3, c4, s4) -> tuple[rg.Vec3, rg.Mat3]:
    """The shoulder-wrist axis ``u = x_sw / |x_sw|`` and the reference shoulder frame ``R03_ref``.

    ``R03_ref = R01(theta1v) R12(theta2v) R23(0)`` puts the arm (shoulder, elbow, wrist) in the
    vertical plane through ``x_sw`` (``theta1v = atan2(y, x)``, 0 on the joint-1 axis). ``theta2v``
    is solved from ``x_sw = R03_ref [-d_ew s4, d_se + d_ew c4, 0]`` (the shoulder-wrist vector in
    frame 3), normalised so that ``R03_ref`` stays a rotation when the target is out of reach.

    Args:
        d_se, d_ew: upper arm and forearm lengths, metres.
        x_sw: shoulder-to-wrist vector in the base frame, metres (3 entries).
        c4, s4: cosine and sine of ``theta4``.
    """
    x, y, z = x_sw
    rho2 = x * x + y * y
    on_axis = rho2 == 0
    rho = safe_sqrt(rho2)
    inv_rho = 1.0 / jnp.where(on_axis, 1.0, rho)
    c1, s1 = jnp.where(on_axis, 1.0, x * inv_rho), jnp.where(on_axis, 0.0, y * inv_rho)
    v_x, v_y = -d_ew * s4, d_se + d_ew * c4
    cn, sn = v_x * rho + v_y * z, v_y * rho - v_x * z
    norm2 = cn * cn + sn * sn
    degenerate = norm2 == 0
    inv_norm = 1.0 / jnp.where(degenerate, 1.0, safe_sqrt(norm2))
    c2, s2 = jnp.where(degenerate, 1.0, cn * inv_norm), jnp.where(degenerate, 0.0, sn * inv_norm)
    length2 = rho2 + z * z
    inv_length = 1.0 / jnp.where(length2 == 0, 1.0, safe_sqrt(length2))
    u = (x * inv_length, y * inv_length, jnp.where(length2 == 0, 1.0, z * inv_length))
    ref = ((c1 * c2, c1 * s2, s1), (s1 * c2, s1 * s2, -c1), (-s2, c2, 0.0))
    return u, ref


def shoulder_matrices(u: rg.Vec3, ref: rg.Mat3) -> tuple[rg.Mat3, rg.Mat3, rg.Mat3]:
    """``(As, Bs, Cs)`` with ``R03(psi) = As sin(psi) + Bs cos(psi) + Cs``: ``ref`` rotated by ``psi`` about ``u``."""
    a_cols = [rg.cross(u, rg.column(ref, k)) for k in range(3)]
    b_cols = [rg.scale(-1.0, rg.cross(u, a)) for a in a_cols]
    c_cols = [rg.vadd(rg.column(ref, k), rg.scale(-1.0, b)) for k, b in enumerate(b_cols)]
    return _columns(a_cols), _columns(b_cols), _columns(c_cols)


class PoseGeometry(NamedTuple):
    """Everything about one pose and global configuration that does not depend on ``psi``.

    Attributes:
        u, ref: the shoulder-wrist axis and the reference shoulder frame (:func:`shoulder_frame`).
        R07: target rotation (3x3 entries).
        c4, s4, theta4: the elbow angle and its cosine and sine.
        g2, g6: the global-configuration signs of joints 2 and 6.
        reachable: whether ``|d_se - d_ew| <= |x_sw| <= d_se + d_ew`` (up to rounding).
    """

    u: rg.Vec3
    ref: rg.Mat3
    R07: rg.Mat3
    c4: jax.Array
    s4: jax.Array
    theta4: jax.Array
    g2: jax.Array
    g6: jax.Array
    reachable: jax.Array

    def angle_entries(self, R03: rg.Mat3) -> AngleEntries:
        """The joint-angle entries of ``R03`` and of ``R47 = R34^T R03^T R07``.

        Linear in ``R03``: applied to ``As, Bs, Cs`` it gives the coefficients of the wrist
        matrices ``Aw, Bw, Cw``.
        """
        a0, a1, a2 = (rg.column(R03, k) for k in range(3))
        x7, y7, z7 = (rg.column(self.R07, j) for j in range(3))
        col0 = rg.vadd(rg.scale(self.c4, a0), rg.scale(self.s4, a1))  # columns 0 and 2 of R04 = R03 R34
        col2 = rg.vadd(rg.scale(-self.s4, a0), rg.scale(self.c4, a1))
        return AngleEntries(
            R03[0][0],
            R03[1][0],
            R03[2][0],
            R03[0][1],
            R03[1][1],
            R03[2][1],
            R03[2][2],
            rg.dot(col0, x7),
            -rg.dot(a2, x7),
            rg.dot(col2, x7),
            rg.dot(col0, z7),
            -rg.dot(a2, z7),
            rg.dot(col2, z7),
            rg.dot(col2, y7),
        )

    def trig_entries(self) -> AngleEntries:
        """The joint-angle entries as functions of ``psi``."""
        per_matrix = [self.angle_entries(M) for M in shoulder_matrices(self.u, self.ref)]
        return AngleEntries(*(Trig(*abc) for abc in zip(*per_matrix, strict=True)))

    def angles(self, psi) -> list[jax.Array]:
        """The seven joint angles (radians) at arm angles ``psi``.

        ``R03`` and the entries are materialised (:func:`diffkin._xla.materialize`): each feeds several
        later expressions, which XLA would otherwise recompute in every one.
        """
        s, c = sincos(psi)
        As, Bs, Cs = shoulder_matrices(self.u, self.ref)
        R03 = _rows(list(materialize([As[i][j] * s + Bs[i][j] * c + Cs[i][j] for i in range(3) for j in range(3)])))
        e = self.angle_entries(R03)
        e = e._replace(**dict(zip(ANGLE_ENTRIES, materialize([getattr(e, k) for k in ANGLE_ENTRIES]), strict=True)))
        return joint_angles(e, self.g2, self.g6, self.theta4)


def pose_geometry(arm: SRSArm, target: jax.Array, gc: jax.Array) -> PoseGeometry:
    """The :class:`PoseGeometry` of poses ``target (..., 4, 4)`` and ``gc (..., 3)`` (same float dtype)."""
    dtype = target.dtype
    d_bs, d_se, d_ew, d_wf = (jnp.asarray(v, dtype) for v in (arm.d_bs, arm.d_se, arm.d_ew, arm.d_wf))
    g2, g4, g6 = gc[..., 0], gc[..., 1], gc[..., 2]
    R07: rg.Mat3 = tuple(tuple(target[..., i, j] for j in range(3)) for i in range(3))
    x_sw = (
        target[..., 0, 3] - d_wf * R07[0][2],
        target[..., 1, 3] - d_wf * R07[1][2],
        target[..., 2, 3] - d_wf * R07[2][2] - d_bs,
    )
    # Materialised stages (see PoseGeometry.angles): the inputs, read once from their interleaved
    # layout, then the geometry.
    flat = list(materialize([e for row in R07 for e in row] + list(x_sw) + [g2, g4, g6]))
    R07, x_sw, (g2, g4, g6) = _rows(flat[:9]), tuple(flat[9:12]), flat[12:]
    c4_raw = (rg.dot(x_sw, x_sw) - d_se * d_se - d_ew * d_ew) / (2.0 * d_se * d_ew)
    reachable = jnp.abs(c4_raw) <= 1.0 + 64.0 * jnp.finfo(dtype).eps
    c4 = jnp.clip(c4_raw, -1.0, 1.0)
    s4 = g4 * safe_sqrt(1.0 - c4 * c4)
    u, ref = shoulder_frame(d_se, d_ew, x_sw, c4, s4)
    flat = list(materialize(list(u) + [e for row in ref for e in row][:8] + [c4, s4, atan2(s4, c4)]))  # ref[2][2] = 0
    u, ref, (c4, s4, theta4) = tuple(flat[:3]), _rows(flat[3:11] + [0.0]), flat[11:]
    return PoseGeometry(u, ref, R07, c4, s4, theta4, g2, g6, reachable)


def within_limits(arm: SRSArm, q: list[jax.Array]) -> jax.Array:
    """Whether every joint angle of ``q`` (seven arrays) lies in ``[lower, upper]``."""
    within = [(qi >= arm.lower[i].astype(qi.dtype)) & (qi <= arm.upper[i].astype(qi.dtype)) for i, qi in enumerate(q)]
    return functools.reduce(jnp.logical_and, within)


def prepare(arm: SRSArm, target, gc, **extra) -> tuple[jax.Array, ...]:
    """Checked ``(target, gc, *extra arrays)`` cast to one float dtype; raises on the host."""
    instance(arm, SRSArm, "arm", AN_ARM)
    target = pose_array(target)
    gc = sign_array(gc, "gc", 3, "(gc2, gc4, gc6)")
    arrays = {name: real_array(x, name) for name, x in extra.items()}
    dtype = jnp.result_type(target, *arrays.values())
    broadcast_batch(target=target.shape[:-2], gc=gc.shape[:-1], **{k: v.shape for k, v in arrays.items()})
    return target.astype(dtype), gc.astype(dtype), *(v.astype(dtype) for v in arrays.values())


def ik(arm: SRSArm, target: ArrayLike, psi: ArrayLike, gc: ArrayLike) -> tuple[jax.Array, jax.Array]:
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
    shape = jnp.broadcast_shapes(target.shape[:-2], psi.shape, gc.shape[:-1])
    n = math.prod(shape)
    if n <= CHUNK:
        q, valid = _solve(arm, target, psi, gc)
        return jnp.broadcast_to(q, shape + (7,)), jnp.broadcast_to(valid, shape)
    inputs = (
        jnp.broadcast_to(target, shape + (4, 4)).reshape(n, 4, 4),
        jnp.broadcast_to(psi, shape).reshape(n),
        jnp.broadcast_to(gc, shape + (3,)).reshape(n, 3),
    )
    q, valid = in_steps(functools.partial(_solve, arm), inputs, CHUNK)
    return q.reshape(shape + (7,)), valid.reshape(shape)


def _solve(arm: SRSArm, target, psi, gc) -> tuple[jax.Array, jax.Array]:
    """:func:`ik` of checked inputs in one step."""
    geometry = pose_geometry(arm, target, gc)
    q = geometry.angles(psi)
    shape = jnp.broadcast_shapes(*(x.shape for x in q))
    q = [jnp.broadcast_to(x, shape) for x in q]
    valid = geometry.reachable & within_limits(arm, q) & _checked(arm, target, psi, gc, q)
    q_stacked = jnp.stack(q, axis=-1)
    return jnp.where(jnp.isfinite(q_stacked), q_stacked, 0.0), jnp.broadcast_to(valid, shape)


def _checked(arm: SRSArm, target, psi, gc, q: list) -> jax.Array:
    """Whether the inputs are what the closed form assumes and ``q`` (7 arrays) reaches ``target``.

    ``gc`` entries exactly ``+-1``, ``target`` rigid (:func:`diffkin._checks.rigid_poses`), ``psi``
    finite, and the forward kinematics of ``q`` within :data:`POSE_TOL` (position, metres, and
    rotation entries) of ``target`` (false for non-finite ``q``). Computed entry by entry from one
    forward pass: no pose matrices are formed.
    """
    ok = jnp.all(jnp.abs(gc) == 1.0, axis=-1) & rigid_poses(target) & jnp.isfinite(psi)
    ee = arm.chain().forward(q).pose()
    errors = [jnp.abs(ee.R[i][j] - target[..., i, j]) for i in range(3) for j in range(3)]
    errors += [jnp.abs(ee.p[i] - target[..., i, 3]) for i in range(3)]
    err = functools.reduce(jnp.maximum, errors)
    return ok & (err <= POSE_TOL[jnp.finfo(target.dtype).bits >= 64])


def arm_angle(arm: SRSArm, q: ArrayLike) -> tuple[jax.Array, jax.Array]:
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
    instance(arm, SRSArm, "arm", AN_ARM)
    q = real_array(q, "q", "joint angles")
    if q.ndim == 0 or q.shape[-1] != 7:
        raise ValueError(f"q: expected shape (..., 7) for an SRS arm, got {q.shape}")
    dtype = q.dtype
    d_se, d_ew = jnp.asarray(arm.d_se, dtype), jnp.asarray(arm.d_ew, dtype)
    (s1, c1), (s2, c2), (s3, c3), (s4, c4) = rg.sincos_each([q[..., i] for i in range(4)])
    R03 = (
        (c1 * c2 * c3 - s1 * s3, c1 * s2, c1 * c2 * s3 + s1 * c3),
        (s1 * c2 * c3 + c1 * s3, s1 * s2, s1 * c2 * s3 - c1 * c3),
        (-s2 * c3, c2, -s2 * s3),
    )
    x_sw = rg.vadd(rg.scale(-d_ew * s4, rg.column(R03, 0)), rg.scale(d_se + d_ew * c4, rg.column(R03, 1)))
    As, Bs, _ = shoulder_matrices(*shoulder_frame(d_se, d_ew, x_sw, c4, s4))
    frobenius = lambda A, B: rg.add(*(rg.mul(A[i][j], B[i][j]) for i in range(3) for j in range(3)))  # noqa: E731
    psi = atan2(frobenius(R03, As), frobenius(R03, Bs))
    gc = jnp.where(q[..., 1::2] >= 0, 1.0, -1.0).astype(dtype)
    return psi, gc
