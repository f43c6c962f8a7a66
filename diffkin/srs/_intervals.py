"""Feasible arm angles under joint limits, and sampling of the self-motion manifold.

For one pose and global configuration, each joint angle is a function of ``psi``:
``theta = atan2(num(psi), den(psi))`` (joints 1, 3, 5, 7) or ``cos(theta) = w(psi)`` (joints 2, 6),
with ``num, den, w`` of the form ``a sin(psi) + b cos(psi) + c`` (see :mod:`._closed_form`). A
joint can enter or leave its limits only where ``theta(psi) = limit``:

- tangent type: ``num cos(L) - den sin(L) = 0`` (the solutions of ``theta = L`` and ``theta = L + pi``;
  the singular ``psi`` where ``num = den = 0`` and ``theta`` jumps by ``pi`` solves it for every
  ``L``, so it is always among the roots);
- cosine type: ``w = cos(L)`` (``theta = +-L``).

Each equation ``a sin(psi) + b cos(psi) + c = 0`` has the closed-form roots
``psi = atan2(a, b) +- acos(-c / hypot(a, b))``. Sorting the 24 roots of the six joints and the
ends ``-pi, pi`` splits the circle into 25 pieces on which every joint is either within its limits
or not; one test per piece (at its midpoint) and merging neighbours gives the feasible set exactly.
Extra roots (``theta = L + pi``, the other sign of a cosine-type joint) only split pieces.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from diffkin._checks import instance, pose_array, positive_int
from diffkin._trig import sincos
from diffkin._xla import stacked_atan2
from diffkin.srs._arm import AN_ARM, SRSArm
from diffkin.srs._closed_form import (
    AngleEntries,
    Trig,
    ik,
    joint_angles,
    pose_geometry,
    prepare,
    safe_sqrt,
    tangent_pairs,
    within_limits,
)

_ROOTS = 24  # 6 joints x 2 limits x 2 roots
_PIECES = _ROOTS + 1
MAX_INTERVALS = (_PIECES + 1) // 2  # K: pieces alternate at worst between feasible and not
ALL_GC = np.array([[g2, g4, g6] for g2 in (1, -1) for g4 in (1, -1) for g6 in (1, -1)], dtype=np.float64)
"""``(8, 3)``: every global configuration ``(gc2, gc4, gc6)``, each sign ``+1`` or ``-1``."""


def _roots(f: Trig) -> jax.Array:
    """``(..., 2 m)``: the two roots in ``[-pi, pi)`` of each of ``m`` equations ``f(psi) = 0`` (entries ``(..., m)``).

    ``-pi`` stands for a missing root (it only adds an empty piece).
    """
    r = safe_sqrt(f.a * f.a + f.b * f.b)
    ratio = -f.c / jnp.where(r > 0, r, 1.0)
    exists = (r > 0) & (jnp.abs(ratio) <= 1.0)
    ratio = jnp.clip(ratio, -1.0, 1.0)
    phase, half_width = stacked_atan2([(f.a, f.b), (safe_sqrt(1.0 - ratio * ratio), ratio)])
    roots = jnp.concatenate([phase + half_width, phase - half_width], -1)
    roots = jnp.mod(roots + jnp.pi, 2.0 * jnp.pi) - jnp.pi
    return jnp.where(jnp.concatenate([exists, exists], -1), roots, -jnp.pi)


def _limit_roots(arm: SRSArm, e: AngleEntries, g2, g6, dtype) -> jax.Array:
    """``(..., 24)`` roots of ``theta_j(psi) = lower_j`` and ``= upper_j`` for joints 1, 2, 3, 5, 6, 7.

    Args:
        e: the joint-angle entries as :class:`Trig` functions of ``psi``.
    """
    limits = jnp.clip(jnp.stack([arm.lower, arm.upper], -1).astype(dtype), -jnp.pi, jnp.pi)  # (7, 2)
    cos_l, sin_l = jnp.cos(limits), jnp.sin(limits)
    stacked = lambda trigs: Trig(*(jnp.stack(x, -1)[..., None] for x in zip(*trigs, strict=True)))  # noqa: E731  (..., m, 1)
    num, den = (stacked(t) for t in zip(*tangent_pairs(e, g2, g6), strict=True))
    tangent = (0, 2, 4, 6)
    f_tan = Trig(*(n * cos_l[tangent, :] - d * sin_l[tangent, :] for n, d in zip(num, den, strict=True)))  # (..., 4, 2)
    w = stacked([e.r32, e.w33])
    f_cos = Trig(*(jnp.broadcast_to(x, x.shape[:-1] + (2,)) for x in (w.a, w.b, w.c - cos_l[(1, 5), :])))
    flat = lambda f: Trig(*(x.reshape(x.shape[:-2] + (-1,)) for x in f))  # noqa: E731
    return _roots(Trig(*(jnp.concatenate(x, -1) for x in zip(flat(f_tan), flat(f_cos), strict=True))))


def feasible_arm_angles(arm: SRSArm, target: ArrayLike, gc: ArrayLike) -> tuple[jax.Array, jax.Array]:
    """The exact set of arm angles whose :func:`ik` solution is in reach and within every joint limit.

    Args:
        arm: the arm model.
        target: ``(..., 4, 4)`` flange poses in the base frame.
        gc: ``(..., 3)`` global configurations ``(gc2, gc4, gc6)`` of ``+-1``.

    Returns:
        ``intervals (..., K, 2)`` closed intervals ``[lo, hi]`` of ``psi`` (radians,
        ``-pi <= lo <= hi <= pi``, sorted, disjoint; a set through ``psi = pi`` is split into
        ``[lo, pi]`` and ``[-pi, hi]``) and ``mask (..., K)`` of the intervals in use (the first
        ones); unused intervals are ``[0, 0]``. ``K = 13`` always suffices. The batch shape is that
        of ``target`` and ``gc`` broadcast together. Pieces narrower than ``64 eps`` (rounding
        noise at double roots) are merged into their left neighbour.

    Raises:
        TypeError, ValueError: as :func:`ik`.
    """
    target, gc = prepare(arm, target, gc)
    dtype = target.dtype
    geometry = pose_geometry(arm, target, gc)
    e = geometry.trig_entries()
    g2, g6 = geometry.g2, geometry.g6
    shape = jnp.broadcast_shapes(target.shape[:-2], gc.shape[:-1])
    ends = [jnp.full(shape, -jnp.pi, dtype), jnp.full(shape, jnp.pi, dtype)]
    roots = jnp.broadcast_to(_limit_roots(arm, e, g2, g6, dtype), shape + (_ROOTS,))
    cuts = jnp.sort(jnp.concatenate([roots] + [x[..., None] for x in ends], -1), -1)
    left, right = cuts[..., :-1], cuts[..., 1:]
    mid = 0.5 * (left + right)
    s, c = sincos(mid)
    per_piece = lambda x: x[..., None]  # noqa: E731 (one value per pose -> broadcast over the pieces)
    values = AngleEntries(*(t.map(per_piece).at(s, c) for t in e))
    angles = joint_angles(values, per_piece(g2), per_piece(g6), per_piece(geometry.theta4))
    feasible = per_piece(geometry.reachable) & within_limits(arm, angles)
    # Pieces of rounding width take the verdict of the last wide piece before them.
    index = jnp.arange(_PIECES)
    wide = (right - left) > 64.0 * jnp.finfo(dtype).eps
    last_wide = jax.lax.cummax(jnp.where(wide, index, -1), axis=feasible.ndim - 1)
    feasible = (last_wide >= 0) & jnp.take_along_axis(feasible, jnp.maximum(last_wide, 0), -1)
    before = jnp.concatenate([jnp.zeros_like(feasible[..., :1]), feasible[..., :-1]], -1)
    after = jnp.concatenate([feasible[..., 1:], jnp.zeros_like(feasible[..., :1])], -1)
    starts, stops = feasible & ~before, feasible & ~after
    slots = jnp.arange(MAX_INTERVALS)

    def compact(flags, values):
        """The values at the raised flags, in order, in the first slots (0 elsewhere)."""
        rank = jnp.cumsum(flags, -1) - 1
        hit = flags[..., None] & (rank[..., None] == slots)
        return jnp.sum(jnp.where(hit, values[..., None], 0.0), -2)

    intervals = jnp.stack([compact(starts, left), compact(stops, right)], -1)
    mask = slots < jnp.sum(starts, -1, keepdims=True)
    return intervals, mask


def sample_self_motion(
    arm: SRSArm,
    target: ArrayLike,
    n: int,
    *,
    key: jax.Array | None = None,
    gc: jax.Array | None = None,
    avoid=None,
    model=None,
) -> tuple[jax.Array, jax.Array]:
    """``n`` exact IK solutions of one pose spread over its whole self-motion within the joint limits.

    The feasible arm angles of every global configuration (or of ``gc``) are laid end to end and
    ``n`` points are placed on them in equal steps (stratified: one per step, at the step's centre,
    or uniformly at random within it when ``key`` is given), so every feasible interval receives a
    share of samples proportional to its length (to within one).

    Args:
        arm: the arm model.
        target: ``(4, 4)`` flange pose in the base frame.
        n: number of samples (a positive Python int; static under ``jit``).
        key: optional ``jax.random`` key for jittered samples; ``None`` gives evenly spaced ones.
        gc: optional ``(3,)`` global configuration to sample; default all eight.
        avoid: optional :class:`~diffkin.ik.Avoid` ``(geom, world, margin)`` of ``model``'s
            geometry, as IK's ``avoid=``: a sample whose clearance is below the margin is not
            ``valid``. (The pair ``(robot, Avoid)`` of earlier releases is still read, with a
            DeprecationWarning.)
        model: with ``avoid``, the :class:`~diffkin.Robot` whose seven joints are the arm's (its
            URDF with collision geometry), as ``model=`` of :func:`diffkin.workspace.base_placement`.

    Returns:
        ``q (n, 7)`` joint angles (radians) and ``valid (n,)``: false when the pose has no
        feasible arm angle (then ``q`` is finite but meaningless), in rounding at an interval end,
        or (with ``avoid``) where the arm collides.

    Raises:
        TypeError: ``n`` not an int, ``arm`` not an :class:`SRSArm`, a bad ``avoid`` or ``model``.
        ValueError: ``n <= 0``, ``target`` not ``(4, 4)``, ``gc`` not ``(3,)`` of ``+-1``, ``avoid``
            without ``model`` (or ``model`` without ``avoid``), a ``model`` without seven joints or
            ``avoid`` geometry of another robot.
    """
    instance(arm, SRSArm, "arm", AN_ARM)
    robot, avoid = _robot_and_avoid(model, avoid)
    n = positive_int(n, "n", "a positive int (number of samples)")
    target = pose_array(target)
    if target.shape != (4, 4):
        raise ValueError(f"target: expected one (4, 4) pose, got shape {target.shape}")
    if gc is not None and jnp.shape(gc) != (3,):
        raise ValueError(f"gc: expected shape (3,) (one global configuration), got {jnp.shape(gc)}")
    gcs = ALL_GC if gc is None else jnp.asarray(gc)[None]
    intervals, mask = feasible_arm_angles(arm, target, gcs)  # (G, K, 2), (G, K)
    dtype = intervals.dtype
    lo = intervals[..., 0].reshape(-1)
    length = jnp.where(mask, intervals[..., 1] - intervals[..., 0], 0.0).reshape(-1)
    ends = jnp.cumsum(length)
    total = ends[-1]
    step = jnp.arange(n, dtype=dtype)
    offset = jnp.full((n,), 0.5, dtype) if key is None else jax.random.uniform(key, (n,), dtype)
    position = (step + offset) * (total / n)
    which = jnp.minimum(jnp.searchsorted(ends, position, side="right"), length.shape[0] - 1)
    psi = lo[which] + jnp.clip(position - (ends[which] - length[which]), 0.0, length[which])
    gc_of = jnp.asarray(gcs, dtype)[which // MAX_INTERVALS]
    q, valid = ik(arm, target, psi, gc_of)
    valid = valid & (total > 0)
    if avoid is not None:
        valid = valid & (avoid.clearance(robot, q) >= avoid.margin)
    return q, valid


def _robot_and_avoid(model, avoid) -> tuple:
    """``(robot, avoid)`` of ``model=`` and ``avoid=`` (``(None, None)`` without them), checked on the host:
    a seven-joint robot and an ``Avoid`` of its geometry. The pair ``avoid=(robot, Avoid)`` of earlier
    releases is read as ``model=robot, avoid=Avoid``, with a DeprecationWarning."""
    from diffkin.ik.interface import check_avoid
    from diffkin.models.robot import Robot

    if isinstance(avoid, tuple) and model is None:
        if len(avoid) != 2:
            raise TypeError(f"avoid: expected a dk.ik.Avoid(geom, world, margin), got a tuple of {len(avoid)}")
        warnings.warn(
            "sample_self_motion(avoid=(robot, Avoid)) is deprecated: pass avoid=Avoid(...), model=robot "
            "(as dk.workspace.base_placement takes them)",
            DeprecationWarning,
            stacklevel=3,
        )
        model, avoid = avoid
    if avoid is None:
        if model is not None:
            raise ValueError("model: only needed with avoid (the robot whose shapes are checked)")
        return None, None
    if model is None:
        raise ValueError("avoid: needs model=robot, the Robot whose seven joints are the arm's")
    instance(model, Robot, "model", "a diffkin.Robot whose joints are the arm's")
    if model.dof != 7:
        raise ValueError(f"model: expected a robot with the arm's 7 joints, got {model.dof}")
    check_avoid(model, avoid)
    return model, avoid
