"""The residual of several frame targets of a whole robot, from one forward pass of its tree.

Per target ``k`` (frame ``f_k`` with target ``T_t = [R_t p_t]``), the error is that of a chain,
``e = [p_t - p; ROT_WEIGHT log(R_t R^T)]`` in world axes, then (when the target has weights)
turned into the target frame and weighted per axis, ``W R_t^T e``: a zero weight frees that axis
(its rows are dropped). Position targets have no frame: their weights act in world axes. The
residual stacks the targets' rows; its Jacobian ``d(-r)/dx`` has one column per joint (locked
joints: none moves) and, when the floating base is solved, six more for the root's body twist.

The state ``x`` is ``(n, P)``: the joint values, then for a solved base the root pose
``[p; R row by row]`` (12 rows), updated by ``T_world_root exp([dv; dw])``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin import kinematics
from diffkin.ik._problem import ROT_WEIGHT, Entries, Eval, project, settle
from diffkin.models.robot import Robot

_ONES = (1.0,) * 6
BASE_ROWS = 12  # state rows of a solved root pose: p (3), then R row by row (9)


class TreeProblem(NamedTuple):
    """A flat batch of multi-target problems of one robot, all in one dtype.

    Attributes:
        robot: the robot.
        frames: static, per target, its frame index.
        weights: static, per target, 6 weights of ``[v; w]`` in the target frame (world axes for a
            position target); ``(1,) * 6`` keeps world axes.
        p: per target, its position entries, each ``(P,)``.
        R: per target, its rotation entries ``3 x 3`` (each ``(P,)``), or ``None`` for a position target.
        lower, upper: ``(dof,)`` limits; ``wrap``: ``(dof,)`` unlimited revolute joints.
        respect_limits: static; clip the joints to the limits.
        locked: static, per joint, whether it is locked; ``locked_q``: ``(dof, P)`` its values.
        base: the root pose ``T_world_root`` (entries ``(P,)`` or constants) when not solved.
        solve_base: static; the root pose is part of the state.
    """

    robot: Robot
    frames: tuple[int, ...]
    weights: tuple[tuple[float, ...], ...]
    p: tuple
    R: tuple
    lower: jax.Array
    upper: jax.Array
    wrap: jax.Array
    respect_limits: bool
    locked: tuple[bool, ...]
    locked_q: jax.Array
    base: rg.Rigid
    solve_base: bool

    @property
    def dof(self) -> int:
        return self.robot.dof

    def project(self, x: jax.Array) -> jax.Array:
        """Joints wrapped/clipped as for a chain, locked joints at their values; the root pose unchanged."""
        q = project(x[: self.dof], self.lower, self.upper, self.wrap, self.respect_limits)
        if any(self.locked):
            q = jnp.where(jnp.asarray(self.locked)[:, None], self.locked_q, q)
        return jnp.concatenate([q, x[self.dof :]]) if self.solve_base else q

    def retract(self, x: jax.Array, dx: jax.Array) -> jax.Array:
        """``q + dq``, and the root pose moved by ``exp`` of the body twist ``dx[dof:]``, projected."""
        q = x[: self.dof] + dx[: self.dof]
        if self.solve_base:
            T = rg.compose(
                self.root(x),
                rg.screw_exp(tuple(dx[self.dof : self.dof + 3]), tuple(dx[self.dof + 3 :]), jnp.ones((), x.dtype)),
            )
            q = jnp.concatenate([q, jnp.stack(list(T.p) + [e for row in T.R for e in row])])
        return self.project(q)

    def root(self, x: jax.Array) -> rg.Rigid:
        """``T_world_root`` at the state ``x``."""
        if not self.solve_base:
            return self.base
        b = x[self.dof :]
        return rg.Rigid(tuple(tuple(b[3 + 3 * i + j] for j in range(3)) for i in range(3)), tuple(b[:3]))

    def evaluate(self, x: jax.Array, jacobian: bool = True) -> Eval:
        """Residual, Jacobian and per-target errors ``(k, P)`` at ``x``, from one forward pass."""
        return settle(self.residual(x, jacobian))

    def residual(self, x: jax.Array, jacobian: bool = True) -> Entries:
        """The entries of :meth:`evaluate` (see :func:`diffkin.ik._problem.residual`); errors one per target."""
        dtype = x.dtype
        root = self.root(x)
        bodies, screws = self.robot._bodies(list(x[: self.dof]), root)
        base_screws = kinematics._root_screws(root) if self.solve_base else []
        zero = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        r, J, pos_err, rot_err = [], [], [], []
        for k, f in enumerate(self.frames):
            T = self.robot._frame(bodies, f)
            e = [rg.add(self.p[k][i], -T.p[i]) for i in range(3)]
            angle = None
            if self.R[k] is not None:
                w, angle = rg.so3_log(rg.matmul(self.R[k], tuple(rg.column(T.R, j) for j in range(3))))
                e += [rg.mul(ROT_WEIGHT, c) for c in w]
            columns = []
            if jacobian:
                joint_columns = [
                    zero if lock else c for lock, c in zip(self.locked, self.robot._columns(screws, f), strict=True)
                ]
                columns = kinematics._world_from_space(joint_columns + base_screws, T.p)
            weights = self.weights[k]
            if weights != _ONES and angle is not None:  # into the target frame: R_t^T e, R_t^T J
                Rt = tuple(rg.column(self.R[k], j) for j in range(3))
                e = list(rg.rotate(Rt, tuple(e[:3]))) + list(rg.rotate(Rt, tuple(e[3:])))
                columns = [(rg.rotate(Rt, v), rg.rotate(Rt, w)) for v, w in columns]
            rows = [[c[0][i] for c in columns] for i in range(3)]
            rows += [[rg.mul(ROT_WEIGHT, c[1][i]) for c in columns] for i in range(3)]
            free = [a for a in range(len(e)) if weights[a] != 0.0]
            pos_err.append(_norm([e[a] for a in free if a < 3], dtype))
            if angle is None:
                rot_err.append(jnp.zeros_like(pos_err[-1]))
            elif all(weights[3:]):
                rot_err.append(angle)
            else:  # the rotation about the free axes ignored
                rot_err.append(_norm([e[a] for a in free if a >= 3], dtype) / ROT_WEIGHT)
            r += [rg.mul(weights[a], e[a]) for a in free]
            J += [[rg.mul(weights[a], c) for c in rows[a]] for a in free] if jacobian else []
        return Entries(r, J, rg.add(*(rg.mul(e, e) for e in r)), pos_err, rot_err)

    def screen_cost(self, x: jax.Array) -> jax.Array:
        return self.evaluate(x, jacobian=False).cost


def _norm(entries: list, dtype) -> jax.Array:
    """Euclidean norm of the entries, capped at the largest float (outputs stay finite)."""
    if not entries:
        return jnp.zeros((), dtype)
    return jnp.minimum(jnp.sqrt(rg.add(*(rg.mul(e, e) for e in entries))), jnp.finfo(dtype).max)
