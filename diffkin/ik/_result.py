"""The result of an inverse-kinematics solve."""

from __future__ import annotations

from typing import NamedTuple

import jax


class IKResult(NamedTuple):
    """Solutions of a batch of inverse-kinematics problems (a pytree).

    Every field has the batch shape ``...`` of the targets.

    Attributes:
        q: ``(..., dof)`` best configuration found per target (radians / metres); within
            ``[lower, upper]`` when solved with ``respect_limits=True``. Differentiable with
            respect to the target and the chain's parameters (implicit function theorem).
        success: ``(...,)`` bool, ``pos_err <= pos_tol`` and ``rot_err <= rot_tol``, decided in the
            solver's dtype with a margin for its rounding (float32: 9.5e-7 m and 1.9e-6 rad), so that
            it also holds when the solution is checked in exact arithmetic.
        pos_err: ``(...,)`` distance in metres between the reached and the target position.
        rot_err: ``(...,)`` angle in radians of the residual rotation ``R_target R(q)^T``
            (0 for position-only targets).
        iters: ``(...,)`` int32 number of solver iterations the returned seed ran.
        base: ``(..., 4, 4)`` the solved root pose ``T_world_root`` of a floating robot solved
            with ``solve_base=True``, else ``None``.
        com_err: ``(...,)`` distance in metres between the centre of mass and its target (over the
            horizontal axes for a horizontal target) when solved with ``com=``, else ``None``.
        clearance: ``(...,)`` metres, the smallest distance that ``avoid`` checks (self pairs,
            shapes to obstacles) at ``q``, when solved with ``avoid=``, else ``None``; success then
            also needs ``clearance >= avoid.margin``.

    For a :class:`~diffkin.Robot` with ``k`` targets, ``pos_err`` and ``rot_err`` are ``(..., k)``
    (in the order of the ``targets`` mapping), each measured on the target's weighted axes only,
    and ``success`` means every target is within tolerance.
    """

    q: jax.Array
    success: jax.Array
    pos_err: jax.Array
    rot_err: jax.Array
    iters: jax.Array
    base: jax.Array | None = None
    com_err: jax.Array | None = None
    clearance: jax.Array | None = None
