"""A frame's pose (or position) in the world, weighted per axis: the target of a chain's end effector
and of each frame of ``dk.ik.solve(robot, {frame: target})``.

The error is ``e = [p_t - p; ROT_WEIGHT log(R_t R^T)]`` in world axes; with weights it is turned
into the target frame and weighted per axis, ``W R_t^T e``: a zero weight frees that axis (its row
is dropped). A position target has no frame: its weights act in world axes. The Jacobian rows are
``d(-e)/dx``: the velocity of the frame's origin and its angular velocity per column of the state.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin.ik._terms import Rows, Target

#: Metres per radian in the residual: the rotation error enters as ``ROT_WEIGHT * angle``, so a
#: 1e-4 rad rotation error counts like a 2e-5 m position error (about a tenth of an arm's reach).
ROT_WEIGHT = 0.2
ONES = (1.0,) * 6


def weights_of(value, label: str, position_only: bool) -> tuple[float, ...]:
    """Six weights of ``[v; w]`` from ``value`` (six non-negative numbers or a pair ``(w_pos, w_rot)``)."""
    w = np.asarray(value, dtype=float) if np.ndim(value) else None
    if w is None or w.shape not in ((2,), (6,)) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(
            f"weights[{label}]: expected 6 non-negative weights of [v; w] or a pair (w_pos, w_rot), got {value!r}"
        )
    w = np.repeat(w, 3) if w.shape == (2,) else w
    if not np.any(w[: 3 if position_only else 6]):
        raise ValueError(f"weights[{label}]: every weight is zero (the target would constrain nothing)")
    return tuple(float(v) for v in w)


def target_entries(T: jax.Array, position_only: bool) -> tuple:
    """``(p, R)``: the entries ``(P,)`` of targets ``(P, 4, 4)`` (``R`` ``None`` for positions ``(P, 3)``)."""
    p = tuple(T[:, i] if position_only else T[:, i, 3] for i in range(3))
    R = None if position_only else tuple(tuple(T[:, i, j] for j in range(3)) for i in range(3))
    return p, R


def error_rows(T: rg.Rigid, columns, p_t, R_t, weights: tuple[float, ...], dtype) -> Rows:
    """The rows of a pose error: ``T`` the pose reached and ``columns`` its point velocities ``(v, w)``
    per column of the state (empty: no Jacobian), or all of them as one array ``(6, n) + shape`` of
    ``[v; w]`` (:meth:`diffkin.ik._problem.Kinematics.point_columns`; the Jacobian is then one array),
    both in world axes."""
    if not isinstance(columns, list):
        without = error_rows(T, [], p_t, R_t, weights, dtype)
        return without._replace(J=jacobian_rows(columns, R_t, weights))
    e = [rg.add(p_t[i], -T.p[i]) for i in range(3)]
    angle = None
    if R_t is not None:
        w, angle = rg.so3_log(rg.matmul(R_t, tuple(rg.column(T.R, j) for j in range(3))))
        e += [rg.mul(ROT_WEIGHT, c) for c in w]
    if weights != ONES and angle is not None:  # into the target frame: R_t^T e, R_t^T J
        Rt = tuple(rg.column(R_t, j) for j in range(3))
        e = list(rg.rotate(Rt, tuple(e[:3]))) + list(rg.rotate(Rt, tuple(e[3:])))
        columns = [(rg.rotate(Rt, v), rg.rotate(Rt, w)) for v, w in columns]
    rows = [[c[0][i] for c in columns] for i in range(3)]
    rows += [[rg.mul(ROT_WEIGHT, c[1][i]) for c in columns] for i in range(3)]
    free = [a for a in range(len(e)) if weights[a] != 0.0]
    pos_err = _norm([e[a] for a in free if a < 3], dtype)
    if angle is None:
        rot_err = jnp.zeros_like(pos_err)
    elif all(weights[3:]):
        rot_err = angle
    else:  # the rotation about the free axes ignored
        rot_err = _norm([e[a] for a in free if a >= 3], dtype) / ROT_WEIGHT
    r = [rg.mul(weights[a], e[a]) for a in free]
    J = [[rg.mul(weights[a], c) for c in rows[a]] for a in free] if columns else []
    return Rows(r, J, pos_err, rot_err)


def jacobian_rows(columns: jax.Array, R_t, weights: tuple[float, ...]) -> jax.Array:
    """``(k, n) + shape``: the Jacobian rows of :func:`error_rows` (the free axes' ``k``) from the point
    velocities ``columns`` ``(6, n) + shape`` (``[v; w]``, world axes; ``(3, n) + shape``: ``v`` alone,
    a position), with the operations the entries take, in the same order (the same numbers)."""
    lead = (1,) * (columns.ndim - 2)
    if weights != ONES and R_t is not None:  # into the target frame: R_t^T v, R_t^T w (rg.rotate, rg.dot)
        Rt = jnp.stack(
            [jnp.stack([jnp.broadcast_to(R_t[i][j], columns.shape[2:]) for j in range(3)]) for i in range(3)]
        )
        Rt = jnp.concatenate([Rt, Rt], axis=1)[:, :, None]  # (3, 6, 1) + shape: R_t[i][a % 3]
        blocks = np.asarray([0, 0, 0, 3, 3, 3])
        columns = (Rt[0] * columns[blocks] + Rt[1] * columns[blocks + 1]) + Rt[2] * columns[blocks + 2]
    rows = columns  # (3, n) + shape: a point's velocities alone
    if len(columns) == 6:
        scale = np.asarray([1.0] * 3 + [ROT_WEIGHT] * 3).reshape((6, 1) + lead)
        rows = jnp.where(scale != 1.0, jnp.asarray(scale, columns.dtype) * columns, columns)
    free = np.asarray([a for a in range(3 if R_t is None else 6) if weights[a] != 0.0])  # (a position: v's rows)
    w = np.asarray(weights)[free].reshape((-1, 1) + lead)
    rows = rows if len(free) == 6 else rows[free]
    return rows if np.all(w == 1.0) else jnp.where(w != 1.0, jnp.asarray(w, columns.dtype) * rows, rows)


def screen_cost(T: rg.Rigid, p_t, R_t, weights: tuple[float, ...], dtype) -> rg.Entry:
    """A cheap cost of the pose ``T`` against ``(p_t, R_t)``: ``|p_t - p|^2 + ROT_WEIGHT^2 (3 - trace(R_t^T R))``.

    The rotation term is ``2 (1 - cos angle)``, the squared angle near 0. Weighted targets take
    their squared residual instead (no Jacobian).
    """
    if weights != ONES:
        return rg.add(*(rg.mul(e, e) for e in error_rows(T, [], p_t, R_t, weights, dtype).r))
    terms = [rg.add(p_t[i], -T.p[i]) ** 2 for i in range(3)]
    if R_t is not None:
        trace = rg.add(*(rg.mul(T.R[i][j], R_t[i][j]) for i in range(3) for j in range(3)))
        terms.append(ROT_WEIGHT**2 * (3.0 - trace))
    return rg.add(*terms)


def _norm(entries: list, dtype) -> jax.Array:
    """Euclidean norm of the entries, capped at the largest float (a target ~1e154 m away would square
    to inf: outputs stay finite)."""
    if not entries:
        return jnp.zeros((), dtype)
    return jnp.minimum(jnp.sqrt(rg.add(*(rg.mul(e, e) for e in entries))), jnp.finfo(dtype).max)


@dataclasses.dataclass(frozen=True)
class PoseTarget(Target):
    """The pose (or the position) of ``frame`` in the world.

    Attributes:
        frame: the frame (a robot's frame index; ``None``: a chain's end effector).
        position_only: the target is a position ``(P, 3)`` (orientation free), else a pose ``(P, 4, 4)``.
        weights: six weights of ``[v; w]`` in the target frame (world axes for a position).
    """

    frame: int | None
    position_only: bool
    weights: tuple[float, ...] = ONES
    #: its Jacobian is read as one array (:meth:`diffkin.ik._problem.Kinematics.point_columns`)
    point_columns: ClassVar[bool] = True

    @property
    def frames(self) -> tuple[int | None, ...]:  # type: ignore[override]  # (Term's field, derived here)
        return (self.frame,)

    def bind(self, target: jax.Array) -> tuple:
        return target_entries(target, self.position_only)

    def rows(self, kin, bound: tuple, jacobian: bool) -> Rows:
        T = kin.pose(self.frame)
        columns = getattr(kin, "point_columns", lambda frame: None)(self.frame) if jacobian else None
        if columns is None:
            columns = rg.world_from_space(kin.columns(self.frame), T.p) if jacobian else []
        p_t, R_t = bound
        return error_rows(T, columns, p_t, R_t, self.weights, kin.dtype)

    def screen(self, kin, bound: tuple) -> rg.Entry:
        p_t, R_t = bound
        return screen_cost(kin.pose(self.frame), p_t, R_t, self.weights, kin.dtype)


def from_mapping(robot, targets, weights) -> list[tuple[PoseTarget, jax.Array, str]]:
    """The terms of ``dk.ik.solve(robot, {frame_name: target})``: ``(term, target array, label)`` each,
    checked on the host (``weights`` keyed by frame name)."""
    from diffkin.ik._args import check_target

    if not isinstance(targets, Mapping):
        raise TypeError(f"target: for a Robot, expected a non-empty mapping frame name -> target, got {targets!r}")
    out = []
    for name, target in targets.items():
        if not isinstance(name, str):
            raise TypeError(f"target: expected frame names as keys (relative targets go in relative=), got {name!r}")
        array, position_only, _ = check_target(target, f"target[{name!r}]")
        w = ONES if name not in weights else weights_of(weights[name], repr(name), position_only)
        out.append((PoseTarget(robot.frame_index(name), position_only, w), array, repr(name)))
    return out
