"""The robot's centre of mass at a point of the world (3-D, or its horizontal components only):
balance over the feet of a humanoid or a quadruped.

The error is ``c_t - c`` in world axes (the vertical row dropped for a horizontal target); its
Jacobian rows are the centre's velocity per column of the state (:meth:`RobotPass.com`). Success
needs ``|c_t - c| <= pos_tol`` over the constrained axes.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin._checks import real_array
from diffkin.ik._terms import Rows, Target
from diffkin.ik._terms.pose import ONES, error_rows, screen_cost, target_entries
from diffkin.kinematics import massive

HORIZONTAL = (1.0, 1.0, 0.0, 1.0, 1.0, 1.0)  # weights of a horizontal target: the z row dropped


@dataclasses.dataclass(frozen=True)
class ComTarget(Target):
    """The centre of mass at a target ``(P, 3)`` (a horizontal target carries ``z = 0``, unweighted).

    Attributes:
        frames: every frame of the robot (every joint can move the centre of mass).
        weights: the weights of ``[x, y, z]`` (then three unused): :data:`HORIZONTAL` or ones.

    Its error is ``IKResult.com_err`` (``result_field``), not a column of ``pos_err``.
    """

    frames: tuple[int, ...]
    weights: tuple[float, ...] = ONES
    position_only: bool = True
    result_field = "com_err"
    #: its Jacobian is read as one array where the model allows (:meth:`diffkin.ik._problem.Kinematics.com_columns`)
    com_columns: ClassVar[bool] = True

    def bind(self, target: jax.Array) -> tuple:
        return target_entries(target, True)

    def rows(self, kin, bound: tuple, jacobian: bool) -> Rows:
        given = getattr(kin, "com_columns", lambda: None)() if jacobian else None
        if given is not None:  # the velocities as one array (diffkin.ik._problem.Kinematics.com_columns)
            return error_rows(rg.Rigid(rg.IDENTITY.R, given[0]), given[1], bound[0], None, self.weights, kin.dtype)
        c, velocities = kin.com(jacobian)
        zero = (0.0, 0.0, 0.0)
        columns = [(v, zero) for v in velocities] if jacobian else []
        p_t, _ = bound
        return error_rows(rg.Rigid(rg.IDENTITY.R, c), columns, p_t, None, self.weights, kin.dtype)

    def screen(self, kin, bound: tuple) -> rg.Entry:
        p_t, _ = bound
        return screen_cost(rg.Rigid(rg.IDENTITY.R, kin.com(False)[0]), p_t, None, self.weights, kin.dtype)


def from_target(robot, com, weights) -> list[tuple[ComTarget, jax.Array, str]]:
    """The term of ``dk.ik.solve(robot, ..., com=c)``: ``[(term, (..., 3) target, label)]``, checked on
    the host (``weights`` are the other targets': a centre of mass takes none)."""
    massive(robot)
    target = real_array(com, "com", "centre-of-mass positions")
    if target.ndim < 1 or target.shape[-1] not in (2, 3):
        raise ValueError(f"com: expected shape (..., 3) (a point) or (..., 2) (horizontal: x, y), got {target.shape}")
    frames = tuple(range(len(robot.frame_names)))
    if target.shape[-1] == 3:
        return [(ComTarget(frames), target, "'com'")]
    return [
        (ComTarget(frames, HORIZONTAL), jnp.concatenate([target, jnp.zeros_like(target[..., :1])], axis=-1), "'com'")
    ]
