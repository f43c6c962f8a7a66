"""The result of :func:`diffkin.traj.optimize`: a timed motion, its checks, and why it failed."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from diffkin.traj import _spline


class Trajectory(NamedTuple):
    """Motions of a batch of problems (a pytree): uniform cubic B-splines in joint space, timed.

    Every field has the problems' batch shape ``(...)`` in front.

    Attributes:
        q: ``(..., K, dof)`` the motion at the knots (radians / metres); ``q[..., 0, :]`` the start,
            ``q[..., -1, :]`` the goal's joint values.
        t: ``(..., K)`` seconds, the knots' times (``t[..., 0] = 0``, ``t[..., -1] = duration``).
        duration: ``(...,)`` seconds.
        success: ``(...,)`` bool, ``goal_ok & limits_ok & clear``.
        goal_ok: ``(...,)`` bool: the goal was reached (a joint goal always; a pose goal when its IK
            solution is within ``pos_tol``/``rot_tol``, and clear of obstacles when ``avoid`` is given).
        limits_ok: ``(...,)`` bool: along the whole continuous motion the joints stay within their
            limits and the velocity, acceleration (and jerk) within :class:`~diffkin.traj.Limits`
            (checked by exact bounds of the spline's derivatives, not by samples).
        clear: ``(...,)`` bool: ``clearance >= avoid.margin`` (``True`` without ``avoid``).
        clearance: ``(...,)`` metres, a certified lower bound of the smallest distance that ``avoid``
            checks over the whole continuous motion (``inf`` without ``avoid``).
        path_length: ``(...,)`` the joint-space length ``int |dq/dt| dt`` (radians / metres,
            Euclidean over the joints), measured along the curve at 16 points per segment.
        control: ``(..., K + 2, dof)`` the spline's control points (what :meth:`at` evaluates).
        segment_time: ``(...,)`` seconds per segment (``t`` is its multiples).
    """

    q: jax.Array
    t: jax.Array
    duration: jax.Array
    success: jax.Array
    goal_ok: jax.Array
    limits_ok: jax.Array
    clear: jax.Array
    clearance: jax.Array
    path_length: jax.Array
    control: jax.Array
    segment_time: jax.Array

    def at(self, t, derivative: int = 0) -> jax.Array:
        """The motion at times ``t`` (seconds): ``(..., dof)``, exactly the curve that was checked.

        Args:
            t: times broadcasting with the batch shape ``(...)``, or with more leading axes
                (``(T, ...)`` gives ``(T, ..., dof)``); clamped to ``[0, duration]``.
            derivative: 0 (joint values), 1 (velocity), 2 (acceleration) or 3 (jerk), per second.
        """
        h = self.segment_time
        u = jnp.asarray(t, h.dtype) / h
        return _spline.evaluate(self.control, u, derivative) / h[..., None] ** derivative
