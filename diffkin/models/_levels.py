"""The forward pass of a robot as arrays, the bodies of one depth of the tree at a time, and the columns
of its Jacobians (frames', centre of mass's) as arrays read from it.

:meth:`diffkin.Robot.forward` unrolls the tree joint by joint, entry by entry, folding the model's
constants: the fastest program for a few poses. A consumer that reads every joint's screw and many
bodies (the IK's Jacobian of a whole robot, :class:`diffkin.ik._problem.Kinematics`) takes this pass
instead: XLA's CPU backend compiles each kernel apart, and gathering the unrolled pass's entries into
arrays costs a kernel per entry, where this pass costs about one per depth of the tree.

Each body is stored in its own axes turned so that its joint's axis is the third (``B = R Pi``, ``Pi``
a constant rotation with ``Pi e3`` the joint's axis: a signed permutation for an axis along a
coordinate axis, as in URDF and MJCF files). A joint's motion is then a rotation about the third axis,
and a body's pose from its parent's ``Tp = [Bp pp]`` is::

    Y = Tp M                      # M = [[Pi_p^T R0 Pi, Pi_p^T t0], [0, 1]]: constant, mostly zeros
    B = [c Y0 + s Y1, c Y1 - s Y0, Y2],  p = Y3 + theta Y2 (prismatic: s = 0, c = 1)

``Y`` reads only the parent's columns that some joint's ``M`` reads (host constants, slices and broadcasts);
the bodies of one depth are one expression, computed once (:func:`diffkin._xla.computed_once`: XLA would
otherwise recompute the depths above in every kernel that reads them). A joint's world axis is its body's
third column and its origin lies on it (revolute joints' axes pass through their frames' origins): the
Jacobians' columns are gathered from one array of the bodies' axes and origins, one expression per frame,
written once in their final layout. Whole-robot IK on the CPU is bound by memory traffic: the bodies'
other entries are not copied.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._static import host, is_concrete
from diffkin._xla import computed_once, stacked_sincos

_TOL = 1e-12  # host values this close to 0 are structural zeros


def takes(robot) -> bool:
    """Whether this pass computes ``robot``'s: a tree of one-axis joints (at least one; no ball joint, no closed
    loop, no scanned path) with concrete numbers, each revolute about a unit axis through its joint frame's
    origin (``v = 0``) or prismatic along a unit axis (``w = 0``)."""
    if not robot.parents or robot.loop_bodies or robot.scanned or "B" in robot.joint_types:
        return False
    arrays = (robot.joint_poses, robot.screws, robot.multipliers, robot.offsets, robot.frame_poses)
    if not all(is_concrete(x) for x in arrays):
        return False
    S = np.asarray(robot.screws, np.float64)
    v, w = np.linalg.norm(S[:, :3], axis=1), np.linalg.norm(S[:, 3:], axis=1)
    revolute = (np.abs(w - 1.0) < 1e-9) & (v < _TOL)
    prismatic = (np.abs(v - 1.0) < 1e-9) & (w < _TOL)
    return bool(np.all(revolute | prismatic))


def _turned(axis: np.ndarray) -> np.ndarray:
    """A rotation ``Pi`` ``(3, 3)`` whose third column is the unit ``axis``: exact (a signed permutation)
    for an axis along a coordinate axis."""
    along = np.abs(axis) > _TOL
    k = (int(np.argmax(along)) + 1) % 3 if np.count_nonzero(along) == 1 else int(np.argmin(np.abs(axis)))
    u = np.eye(3)[k]
    e1 = u - (u @ axis) * axis
    e1 = e1 / np.linalg.norm(e1)
    return np.stack([e1, np.cross(axis, e1), axis], axis=1)


def _snapped(x: np.ndarray) -> np.ndarray:
    x = np.where(np.abs(x) < _TOL, 0.0, x)
    return np.where(np.abs(np.abs(x) - 1.0) < _TOL, np.sign(x), x)


class Layout(NamedTuple):
    """The static structure of the pass (host values, from the robot's numbers).

    Attributes:
        depths: per depth of the tree below the root, its joints (the bodies ``j + 1``), in order.
        row: ``(nb,)`` each body's row, counted through the depths in order (the root's is 0).
        turn: ``(nb, 3, 3)`` each body's ``Pi`` (the root's: the identity).
        steps: per depth, ``(parents, M, prismatic)``: the rows of the joints' parents in the depth above,
            each joint's ``M`` ``(k, 4, 4)`` (module docstring), and which joints slide.
        revolute: ``(nj,)`` bool.
    """

    depths: list
    row: np.ndarray
    turn: np.ndarray
    steps: list
    revolute: np.ndarray


def layout(robot) -> Layout:
    """The :class:`Layout` of ``robot`` (:func:`takes` it)."""
    P = np.asarray(host(robot.joint_poses), np.float64)
    S = np.asarray(host(robot.screws), np.float64)
    nj = len(robot.parents)
    revolute = np.linalg.norm(S[:, 3:], axis=1) > 0.5
    turn = np.stack([np.eye(3)] + [_turned(S[j, 3:] if revolute[j] else S[j, :3]) for j in range(nj)])
    depth = [0]
    for parent in robot.parents:
        depth.append(depth[parent] + 1)
    depths = [[j for j in range(nj) if depth[j + 1] == d] for d in range(1, max(depth) + 1)]
    row = np.zeros(nj + 1, np.int64)
    at, start = {0: 0}, 1
    steps = []
    for joints in depths:
        parents = np.asarray([at[robot.parents[j]] for j in joints], np.int64)
        M = np.zeros((len(joints), 4, 4))  # per joint, [[Pi_p^T R0 Pi, Pi_p^T t0], [0, 1]]
        for k, j in enumerate(joints):
            Tp = turn[robot.parents[j]].T
            M[k, :3, :3] = Tp @ P[j, :3, :3] @ turn[j + 1]
            M[k, :3, 3] = Tp @ P[j, :3, 3]
            M[k, 3, 3] = 1.0
        steps.append((parents, _snapped(M), ~revolute[np.asarray(joints)]))
        at = {j + 1: k for k, j in enumerate(joints)}
        row[np.asarray(joints) + 1] = start + np.arange(len(joints))
        start += len(joints)
    return Layout(depths, row, turn, steps, revolute)


def forward(robot, q: jax.Array, base: jax.Array) -> LevelPass:
    """The robot's forward pass (:func:`takes` it) as arrays, a depth of the tree at a time.

    Args:
        robot: the :class:`~diffkin.Robot`.
        q: ``(dof,) + batch`` joint values.
        base: ``(3, 4) + batch`` (or ``(3, 4)``): ``T_world_root`` ``[R p]``.

    Returns:
        A :class:`LevelPass`.
    """
    dtype = jnp.result_type(q, base)
    batch = tuple(np.broadcast_shapes(q.shape[1:], base.shape[2:]))
    lead = (None,) * len(batch)  # a constant against values + batch
    L = layout(robot)
    order = np.concatenate([np.asarray(d, np.int64) for d in L.depths])  # the joints in depth order
    m, o = (np.asarray(host(x), np.float64)[order][(slice(None), *lead)] for x in (robot.multipliers, robot.offsets))
    theta = jnp.asarray(m, dtype) * q[np.asarray(robot.sources, np.int64)[order]] + jnp.asarray(o, dtype)
    slide = ~L.revolute[order]
    angle = jnp.where(slide[(slice(None), *lead)], jnp.zeros((), dtype), theta) if slide.any() else theta
    (s,), (c,) = stacked_sincos((angle,))
    levels = [jnp.broadcast_to(jnp.asarray(base, dtype), (1, 3, 4) + batch)]
    at = 0
    for parents, M, prismatic in L.steps:
        k = len(parents)
        Tp = _rows(levels[-1], parents)  # (k, 3, 4) + batch
        # Y = Tp M over the parents' columns that some joint of the depth reads, read twice in the orders
        # that the new columns take (host-permuted M: no gather in the kernel)
        YA, YB = (_times(Tp, M[:, :, order], lead, dtype) for order in (_SECOND, _FIRST))
        sk, ck, tk = (x[at : at + k][:, None, None] for x in (s, c, theta))  # (k, 1, 1) + batch
        fa = ck * _constant(_ON_COS, lead, dtype) + _constant(_ONES, lead, dtype)  # [c, c, 1, 1]
        fb = sk * _constant(_ON_SIN, lead, dtype)  # [s, -s, 0, 0]
        if prismatic.any():
            slides = np.zeros((k, 1, 4))
            slides[prismatic, 0, 3] = 1.0
            fb = fb + tk * jnp.asarray(slides[(Ellipsis, *lead)], dtype)  # [.., theta] where it slides
        levels.append(computed_once(YA * fa + YB * fb, len(batch)))
        at += k
    return LevelPass(robot, L, levels)


_SECOND, _FIRST = np.asarray([0, 1, 2, 3]), np.asarray([1, 0, 2, 2])  # per column of a body, Y's read with fa, fb
_ON_COS, _ONES, _ON_SIN = (
    np.asarray([1.0, 1.0, 0.0, 0.0]),
    np.asarray([0.0, 0.0, 1.0, 1.0]),
    np.asarray([1.0, -1.0, 0.0, 0.0]),
)


def _constant(x: np.ndarray, lead: tuple, dtype) -> jax.Array:
    """A constant ``(4,)`` along the columns of poses ``(k, 3, 4) + batch``."""
    return jnp.asarray(x[(None, None, slice(None), *lead)], dtype)


def _times(T: jax.Array, M: np.ndarray, lead: tuple, dtype) -> jax.Array:
    """``T M``: poses ``(k, 3, 4) + batch`` (or one, ``(1, 3, 4) + batch``) times constants ``(k, 4, 4)``, over
    the columns of ``T`` that some row of ``M`` reads (slices and broadcasts: one expression)."""
    out = None
    for col in range(4):
        if M[:, col].any():
            term = T[:, :, col, None] * jnp.asarray(M[:, None, col][(Ellipsis, *lead)], dtype)
            out = term if out is None else out + term
    assert out is not None
    return out


def _rows(x: jax.Array, rows: np.ndarray) -> jax.Array:
    """``x[rows]`` for static ``rows``: a slice where they are consecutive (one row where all are one: it
    broadcasts against the others' constants)."""
    if np.all(rows == rows[0]):
        return x[rows[0] : rows[0] + 1]
    if np.all(np.diff(rows) == 1):
        return x[rows[0] : rows[-1] + 1]
    return x[rows]


class LevelPass:
    """The bodies of a robot's forward pass by depth (:func:`forward`) and what is read from them.

    Attributes:
        robot: the :class:`~diffkin.Robot`.
        layout: its :class:`Layout`.
        levels: per depth (the root's first), ``(k, 3, 4) + batch``: its bodies' ``[R Pi, p]`` in the world
            (rows :attr:`Layout.row` in all, counted on from depth to depth).
    """

    def __init__(self, robot, layout: Layout, levels: list):
        self.robot, self.layout, self.levels = robot, layout, levels
        self.starts = np.cumsum([0] + [len(x) for x in levels])  # each level's first row
        self.dtype = levels[0].dtype
        self._axes: jax.Array | None = None
        self.lead = (None,) * (levels[0].ndim - 3)  # a constant against values + batch

    def body(self, body: int) -> jax.Array:
        """``(3, 4) + batch``: body ``body``'s ``[R Pi, p]``, from its level."""
        row = self.layout.row[body]
        level = int(np.searchsorted(self.starts, row, side="right")) - 1
        return self.levels[level][row - self.starts[level]]

    def axes(self) -> jax.Array:
        """``(nb + 2, 3, 2) + batch``: per body (:attr:`Layout.row`), its third axis (its joint's, in the world)
        and its origin; then the root's first and second axes, each with its origin.
        One array (one concatenation of the levels' slices, computed once) that the Jacobians' columns are
        gathered from; the levels' other entries are not copied (whole robots' IK is bound by memory traffic)."""
        if self._axes is None:
            root = self.levels[0][:1]  # its columns 0 and 3, then 1 and 3: its first two axes and its origin
            pieces = [x[:, :, 2:] for x in self.levels] + [root[:, :, 0::3], root[:, :, 1::2]]
            self._axes = jnp.concatenate(pieces)  # (nb + 2, 3, 2) + batch (XLA does not fuse it into its readers)
        return self._axes

    def pose(self, frame: int) -> rg.Rigid:
        """The world pose of frame ``frame`` as entries ``batch`` (as :meth:`diffkin.models._passes.RobotPass.pose`)."""
        robot, L = self.robot, self.layout
        body = robot.frame_bodies[frame]
        F = np.asarray(host(robot.frame_poses), np.float64)[frame]
        G = _snapped(L.turn[body].T @ F[:3, :3])
        g = _snapped(L.turn[body].T @ F[:3, 3])
        T = self.body(body)  # (3, 4) + batch
        B = [[T[i, col] for col in range(3)] for i in range(3)]
        R = tuple(
            tuple(rg.add(*(rg.mul(float(G[col, j]), B[i][col]) for col in range(3))) for j in range(3))
            for i in range(3)
        )
        p = tuple(rg.add(*(rg.mul(float(g[col]), B[i][col]) for col in range(3)), T[i, 3]) for i in range(3))
        return rg.Rigid(R, p)  # type: ignore[arg-type]

    def _columns(self, joints, locked: tuple, root: bool) -> list:
        """The columns of the state as bodies, per term of a sum (a mimic joint's column adds to its source's):
        ``(row, axis, turns, scale)``, ``(n,)`` each: the body's row (:attr:`Layout.row`), its column that is
        the axis, whether it turns (else slides), the multiplier (0: no joint of ``joints`` there, or
        ``locked``); the root's six last where ``root`` (three slides along its axes, three turns about them)."""
        robot, L = self.robot, self.layout
        m = np.asarray(host(robot.multipliers), np.float64)
        driving: list[list[int]] = [[] for _ in range(robot.dof)]  # per entry of q, the joints it drives
        for j in joints:
            if not locked[robot.sources[j]]:
                driving[robot.sources[j]].append(j)
        out = []
        for t in range(max(1, max(map(len, driving)))):
            at = [d[t] if t < len(d) else None for d in driving]
            row = [0 if j is None else int(L.row[j + 1]) for j in at]
            axis = [2] * len(at)
            turns = [True if j is None else bool(L.revolute[j]) for j in at]
            scale = [0.0 if j is None else float(m[j]) for j in at]
            if root:
                row, axis = row + [0] * 6, axis + [0, 1, 2] * 2  # (axes(): the root's k-th axis at row_k)
                turns, scale = turns + [False] * 3 + [True] * 3, scale + [1.0 if t == 0 else 0.0] * 6
            out.append(tuple(np.asarray(x) for x in (row, axis, turns, scale)))
        return out

    def _along(self, term, rows: int) -> tuple[jax.Array, jax.Array]:
        """``(a, p)`` ``(3, n) + batch`` (``rows = 6``: ``a`` twice, ``(6, n) + batch``): per column of ``term``
        (:meth:`_columns`), its world axis and a point on it (gathered from :meth:`axes`)."""
        row, axis, _, _ = term
        nb = self.starts[-1]
        at = np.where(axis == 2, row, nb + axis)  # the root's first two axes follow the bodies
        X = self.axes()
        a = jnp.moveaxis(X[at, :, 0], 0, 1)  # (3, n) + batch
        return (a if rows == 3 else a[_TWICE]), jnp.moveaxis(X[row, :, 1], 0, 1)

    def _constant(self, x: np.ndarray) -> jax.Array:
        """A per-column constant ``(n,)`` against ``(k, n) + batch``."""
        return jnp.asarray(x[(None, slice(None), *self.lead)], self.dtype)

    def point_columns(self, frame: int, p: rg.Vec3, locked: tuple, root: bool) -> jax.Array:
        """``(6, n) + batch``: per column of the state (the joints', then the root's six where ``root``), the
        velocity of ``frame``'s origin ``p`` and its angular velocity ``[v; w]`` (world axes): ``[a x (p - p_j);
        a]`` for a turn, ``[a; 0]`` for a slide; zero for a ``locked`` joint or one off the frame's path. One
        expression (a stack of ``v`` and ``w`` would be a kernel each)."""
        robot = self.robot
        batch = self.levels[0].shape[3:]
        to = jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(e, self.dtype) for e in p), jnp.zeros(batch, self.dtype))[:3])
        linear = (np.arange(6) < 3)[(slice(None), None) + (None,) * len(batch)]
        J = None
        for term in self._columns(robot.ancestors(robot.frame_bodies[frame]), locked, root):
            _, _, turns, scale = term
            a, q = self._along(term, 6)
            d = to[:, None] - q  # (3, n) + batch
            crossed = a[_NEXT] * d[_AFTER] - a[_AFTER] * d[_NEXT]  # rows 0-2: a x d
            moved = (
                jnp.where(linear, crossed, a)
                if turns.all()
                else jnp.where(self._constant(turns) != 0, jnp.where(linear, crossed, a), jnp.where(linear, a, 0.0))
            )
            part = moved if np.all(scale == 1.0) else self._constant(scale) * moved
            J = part if J is None else J + part
        assert J is not None
        return J

    def com_columns(self, masses: np.ndarray, coms: np.ndarray, locked: tuple, root: bool):
        """The centre of mass ``(3,) + batch`` and its velocity per column of the state ``(3, n) + batch`` (the
        joints', then the root's six where ``root``; zero for a ``locked`` joint): a joint moves the bodies
        below it, mass ``M_j``, first moment ``S_j``, by ``a x (S_j - M_j p_j) / M`` (a turn) or ``M_j a / M``
        (a slide), the root the centre as a point; ``masses`` ``(nb,)``, ``coms`` ``(nb, 3)`` in the bodies'
        frames."""
        robot, L = self.robot, self.layout
        nj = len(robot.parents)
        body = np.argsort(L.row)  # per row, its body
        below = np.eye(nj + 1)  # below[k, b]: body b is in the subtree of body k (children follow parents)
        for j in reversed(range(nj)):
            below[robot.parents[j]] += below[j + 1]
        below = below[body][:, body]  # in rows
        mass = below @ masses[body]
        inverse = 1.0 / float(mass[0]) if mass[0] > 0.0 else 0.0
        # the subtree sums as one product (one kernel, not fused into its readers)
        S = jnp.tensordot(jnp.asarray(below, self.dtype), self._moments(masses, coms), axes=1)
        J = None
        n = robot.dof + (6 if root else 0)
        for term in self._columns(range(nj), locked, root):
            row, _, turns, scale = term
            a, p = self._along(term, 3)
            # d = S_j / M - (M_j / M) p_j, and M_j / M a; the root's columns move the centre as a point: d = c - p
            # and a (also for a robot without mass)
            k = np.where(np.arange(n) < robot.dof, mass[row] * inverse, 1.0)
            d = inverse * jnp.moveaxis(S[row], 0, 1) - self._constant(k) * p
            crossed = a[_NEXT[:3]] * d[_AFTER[:3]] - a[_AFTER[:3]] * d[_NEXT[:3]]
            moved = crossed if turns.all() else jnp.where(self._constant(turns) != 0, crossed, self._constant(k) * a)
            part = moved if np.all(scale == 1.0) else self._constant(scale) * moved
            J = part if J is None else J + part
        c = inverse * S[0]
        return (c[0], c[1], c[2]), J

    def _moments(self, masses: np.ndarray, coms: np.ndarray, level: int | None = None) -> jax.Array:
        """``(nb, 3) + batch`` in :attr:`Layout.row` order (or those of one ``level``): each body's first moment
        ``m (R c + p) = m (R Pi) (Pi^T c) + m p`` in the world."""
        if level is None:
            return jnp.concatenate([self._moments(masses, coms, d) for d in range(len(self.levels))])
        L = self.layout
        body = np.argsort(L.row)[self.starts[level] : self.starts[level + 1]]  # per row of the level, its body
        B = self.levels[level]
        turned = np.einsum("bij,bi->bj", L.turn, coms)[body] * masses[body, None]  # m Pi^T c
        k = jnp.asarray(turned[(slice(None), None, slice(None), *self.lead)], self.dtype)  # (k, 1, 3)
        mk = jnp.asarray(masses[body][(slice(None), None, *self.lead)], self.dtype)
        return ((B[:, :, 0] * k[:, :, 0] + B[:, :, 1] * k[:, :, 1]) + B[:, :, 2] * k[:, :, 2]) + mk * B[:, :, 3]


_TWICE = np.asarray([0, 1, 2, 0, 1, 2])  # rows of [v; w] from a vector's three
_NEXT, _AFTER = np.asarray([1, 2, 0, 1, 2, 0]), np.asarray([2, 0, 1, 2, 0, 1])  # a x d's operands, per row
