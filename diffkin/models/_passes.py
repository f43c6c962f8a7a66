"""The passes of whole robots (:mod:`diffkin.models.forward`'s ``Pass``): :class:`RobotPass`, entry by
entry, and :class:`ScannedPass`, rows of arrays (the scanned forward pass's, :mod:`diffkin.models._scanned`).

They read their robot through its fields only (``frame_poses``, ``frame_bodies``, ``ancestors``,
``sources``, ...): the model modules build on them, never the other way.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._static import host
from diffkin._xla import materialize


def entries(flat: jax.Array) -> rg.Rigid:
    """A pose from its 12 entries on the leading axis (``R`` row by row, then ``p``)."""
    R = tuple(tuple(flat[3 * i + j] for j in range(3)) for i in range(3))
    return rg.Rigid(R, tuple(flat[9 + i] for i in range(3)))


def rows(T: jax.Array) -> jax.Array:
    """``(k, 12)``: the 12 entries of each of ``k`` poses ``(k, 4, 4)``."""
    return jnp.concatenate([T[:, :3, :3].reshape(-1, 9), T[:, :3, 3]], axis=1)


def per_row(flat: jax.Array, ndim: int) -> rg.Rigid:
    """The poses of ``flat (k, 12)`` as entries ``(k, 1, ...)``, against values ``(k,) + batch`` (``ndim`` axes)."""
    return entries(flat.T[(slice(None), slice(None)) + (None,) * ndim])


class RobotPass:
    """The :class:`~diffkin.models.forward.Pass` of a robot: body poses and joint screws, frames on demand."""

    def __init__(self, robot, bodies: list[rg.Rigid], screws: list, multipliers: list):
        """``robot``: the :class:`~diffkin.Robot`; per body its world pose, per joint its world screw and multiplier."""
        self.robot, self.bodies, self.screws, self.multipliers = robot, bodies, screws, multipliers
        self._poses: dict[int, rg.Rigid] = {}
        self.dependent: list[rg.Entry] = []  # the dependent joints' values of a robot with loops (Robot.forward)
        self.fold: list[list[rg.Entry]] = []  # their d q_dep / d q
        self.loop_gap: rg.Entry = 0.0  # the largest gap of its loops (metres)

    def pose(self, frame: int | None = None) -> rg.Rigid:
        """World pose of frame ``frame`` (an index into ``robot.frame_names``)."""
        if frame is None:
            raise TypeError("frame: a robot has no single end effector; give a frame index")
        if frame not in self._poses:
            T_body_frame = rg.from_matrix(host(self.robot.frame_poses)[frame])
            self._poses[frame] = rg.compose(self.bodies[self.robot.frame_bodies[frame]], T_body_frame)
        return self._poses[frame]

    def columns(self, frame: int | None = None) -> list[tuple[rg.Vec3, rg.Vec3]]:
        """Per entry of ``q``, the space twist of frame ``frame`` per unit ``q_i``: the sum over the joints
        on the frame's path that ``q_i`` drives of ``multiplier * screw`` (zero if none)."""
        if frame is None:
            raise TypeError("frame: a robot has no single end effector; give a frame index")
        robot, zero = self.robot, (0.0, 0.0, 0.0)
        columns: list = [(zero, zero)] * (robot.dof + len(robot.dependent_names))
        for j in robot.ancestors(robot.frame_bodies[frame]):
            v, w = self.screws[j]
            i, m = robot.sources[j], self.multipliers[j]
            columns[i] = (rg.vadd(columns[i][0], rg.scale(m, v)), rg.vadd(columns[i][1], rg.scale(m, w)))
        vs, ws = [v for v, _ in columns], [w for _, w in columns]
        return [(self._folded(vs, i), self._folded(ws, i)) for i in range(robot.dof)]

    def _folded(self, columns: list[rg.Vec3], i: int) -> rg.Vec3:
        """Column ``i`` of ``q`` plus the dependent joints' columns times ``d q_dep / d q_i`` (loops)."""
        out = columns[i]
        for d, row in enumerate(self.fold):
            out = rg.vadd(out, rg.scale(row[i], columns[self.robot.dof + d]))
        return out

    def poses(self) -> list[rg.Rigid]:
        """Every frame, in ``robot.frame_names`` order."""
        return [self.pose(f) for f in range(len(self.robot.frame_names))]

    def com(self, velocities: bool = True) -> tuple[rg.Vec3, list[rg.Vec3]]:
        """The centre of mass in the world, and per entry of ``q`` its velocity per unit ``q_i``
        (empty without ``velocities``).

        Joint ``j`` carries the bodies below it, of mass ``M_j`` and first moment ``S_j = sum m p``
        (world); its space screw ``(v_j, w_j)`` moves the centre by ``(M_j v_j + w_j x S_j) / M``.
        """
        robot = self.robot
        masses = rg.per_joint(host(robot.masses), snap=False)  # tiny masses still weigh
        c = host(robot.body_coms)
        moments = [
            rg.scale(masses[b], rg.vadd(rg.rotate(T.R, rg.vector(c[b])), T.p)) for b, T in enumerate(self.bodies)
        ]
        screws = self.screws
        if velocities:  # every column reads them: computed once, not inside each column's kernel
            moments, screws = _computed_once(moments, screws)
        for j in reversed(range(len(robot.parents))):  # subtree sums, leaves first (children follow parents)
            parent = robot.parents[j]
            masses[parent] = rg.add(masses[parent], masses[j + 1])
            moments[parent] = rg.vadd(moments[parent], moments[j + 1])
        inverse = _reciprocal(masses[0])
        zero = (0.0, 0.0, 0.0)
        columns: list[rg.Vec3] = [zero] * (robot.dof + len(robot.dependent_names)) if velocities else []
        for j, (v, w) in enumerate(screws if velocities else []):
            i, k = robot.sources[j], rg.mul(self.multipliers[j], inverse)
            moved = rg.vadd(rg.scale(masses[j + 1], v), rg.cross(w, moments[j + 1]))
            columns[i] = rg.vadd(columns[i], rg.scale(k, moved))
        columns = [self._folded(columns, i) for i in range(robot.dof)] if velocities else []
        return rg.scale(inverse, moments[0]), columns


def _computed_once(moments: list[rg.Vec3], screws: list) -> tuple[list[rg.Vec3], list]:
    """Body moments and joint screws behind one barrier (:func:`diffkin._xla.materialize`): XLA's CPU
    fusion would otherwise recompute the forward pass inside the kernel of every centre-of-mass
    column (Talos: 1.4x faster)."""
    flat = [e for m in moments for e in m] + [e for v, w in screws for e in (*v, *w)]
    arrays = [i for i, e in enumerate(flat) if not isinstance(e, float)]
    if arrays:
        done = materialize([flat[i] for i in arrays])
        for k, i in enumerate(arrays):
            flat[i] = done[k]
    nb = len(moments)
    rest = flat[3 * nb :]
    return (
        [tuple(flat[3 * b : 3 * b + 3]) for b in range(nb)],
        [(tuple(rest[6 * j : 6 * j + 3]), tuple(rest[6 * j + 3 : 6 * j + 6])) for j in range(len(screws))],
    )


def _reciprocal(total: rg.Entry) -> rg.Entry:
    """``1 / total`` of a total mass, 0 for a massless robot (finite under ``jit``; the host refuses it)."""
    if isinstance(total, float):
        return 1.0 / total if total > 0.0 else 0.0
    positive = total > 0
    return jnp.where(positive, 1.0 / jnp.where(positive, total, 1.0), 0.0)


class ScannedPass(RobotPass):
    """A :class:`RobotPass` whose poses and screws are rows of arrays.

    Besides the entry-wise methods of every pass, it gives many frames or columns at once as one
    pose or twist whose entries have a leading axis (:meth:`stacked_poses`, :meth:`stacked_columns`):
    a program that slices a thousand frames into entries and stacks them again compiles in minutes.
    A chain's pass (``end`` given) is a chain's :class:`~diffkin.models.forward.Pass`: frame ``None`` its
    end effector, :meth:`poses` its base and links (:attr:`frames` of them).
    """

    def __init__(self, robot, bodies: jax.Array, screws: jax.Array, multipliers: jax.Array, end: int | None = None):
        """``bodies (nj + 1, 12) + batch``, ``screws (nj, 6) + batch`` (world ``[v; w]``), ``multipliers (nj,)``."""
        self.robot, self._bodies, self._screws, self._m, self.end = robot, bodies, screws, multipliers, end
        self.dependent, self.fold, self.loop_gap = [], [], 0.0  # (no closed loops: Robot.tree_pass refuses them)
        self.frames = len(robot.frame_bodies) if end is None else end  # the frames of poses()

    @property
    def bodies(self) -> list[rg.Rigid]:  # type: ignore[override]
        return [entries(self._bodies[b]) for b in range(len(self._bodies))]

    @property
    def screws(self) -> list[tuple[rg.Vec3, rg.Vec3]]:  # type: ignore[override]
        return [_twist(s) for s in self._screws]

    @property
    def multipliers(self) -> list[rg.Entry]:  # type: ignore[override]
        return [self._m[j] for j in range(len(self._m))]

    def _frame(self, frame: int | None) -> int:
        if frame is not None:
            return frame
        if self.end is None:
            raise TypeError("frame: a robot has no single end effector; give a frame index")
        return self.end

    def pose(self, frame: int | None = None) -> rg.Rigid:
        return _index(self.stacked_poses([frame]), 0)

    def columns(self, frame: int | None = None) -> list[tuple[rg.Vec3, rg.Vec3]]:
        stacked = self.stacked_columns(frame)
        return [(_index(stacked[0], i), _index(stacked[1], i)) for i in range(self.robot.dof)]

    def poses(self) -> list[rg.Rigid]:
        stacked = self.stacked_poses(list(range(self.frames)))
        return [_index(stacked, f) for f in range(self.frames)]

    def stacked_poses(self, frames: Sequence[int | None]) -> rg.Rigid:
        """The world poses of ``frames``: entries ``(len(frames),) + batch``."""
        robot = self.robot
        indices = [self._frame(f) for f in frames]
        bodies = entries(jnp.moveaxis(self._bodies[np.asarray([robot.frame_bodies[f] for f in indices])], 1, 0))
        F = rows(jnp.asarray(robot.frame_poses, self._bodies.dtype)[np.asarray(indices)])
        return rg.compose(bodies, per_row(F, self._bodies.ndim - 2))

    def stacked_columns(self, frame: int | None) -> tuple[rg.Vec3, rg.Vec3]:
        """The space Jacobian of ``frame`` as one twist ``(v, w)`` with entries ``(dof,) + batch``: per entry of
        ``q``, the sum over the joints on the frame's path that it drives of ``multiplier * screw``."""
        robot = self.robot
        path = np.asarray(robot.ancestors(robot.frame_bodies[self._frame(frame)]), np.int64)
        lead = (slice(None),) + (None,) * (self._screws.ndim - 1)
        moved = self._m[path][lead] * self._screws[path]  # (len(path), 6) + batch
        moved = jnp.concatenate([moved, jnp.zeros_like(moved[:1])])  # a zero row at index len(path)
        driving: list[list[int]] = [[] for _ in range(robot.dof)]  # per entry of q, its rows of `moved`
        for row, j in enumerate(path):
            driving[robot.sources[j]].append(row)
        J = sum(  # gathers, not a scatter-add (10x faster on the CPU): one per joint driven by the same entry
            moved[np.asarray([rows[k] if k < len(rows) else len(path) for rows in driving])]
            for k in range(max(map(len, driving), default=0))
        )
        if isinstance(J, int):  # no joint moves the frame
            J = jnp.zeros((robot.dof, *moved.shape[1:]), moved.dtype)
        return _twist(jnp.moveaxis(J, 1, 0))


def _twist(s: jax.Array) -> tuple[rg.Vec3, rg.Vec3]:
    """``(v, w)`` from ``[v; w]`` on the leading axis."""
    return (s[0], s[1], s[2]), (s[3], s[4], s[5])


def _index(x, i: int):
    """Entry ``i`` of the leading axis of every entry of a pose or twist."""
    return jax.tree.map(lambda e: e[i], x)
