"""The forward pass of a robot with a long serial path, as one ``lax.scan`` over its joints.

:meth:`diffkin.Robot.forward` unrolls the tree joint by joint, folding the model's constants;
that is the fastest program for every arm, hand and humanoid, but its compile time grows faster
than the number of joints (a 200-joint snake: 14 s for FK, 74 s for its Jacobian), so snakes,
cable models and discretised continuum robots with hundreds of joints could not be compiled.
Past :data:`LONG` joints on one path the pass is this scan instead: every joint's exponential
is computed for all joints at once (elementwise over ``(joints,) + batch``), then the scan
composes each body's pose from its parent's, ``T_world_body[j + 1] = T_world_body[parents[j]]
@ joint_poses[j] @ exp([screws[j]] theta_j)``, in a buffer of every body's pose (so trees work
too). Compile time is then independent of the number of joints and run time linear in it.

The result is the same :class:`~diffkin.models.robot.RobotPass` (bodies and world screws as
entries, sliced from the scan's outputs), so every consumer of a pass works unchanged. Chains of
more than :data:`LONG` joints take it too (:func:`chain_forward`: a product of exponentials is a
tree whose joint poses are the identity).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._static import is_concrete
from diffkin.models.forward import JointValues
from diffkin.models.robot import RobotPass

# A robot whose longest path from the root has more joints than this takes the scanned pass.
LONG = 32


def longest_path(parents: Sequence[int]) -> int:
    """The most joints on one path from the root (``parents`` as in :class:`~diffkin.Robot`)."""
    depth = [0]
    for parent in parents:
        depth.append(depth[parent] + 1)
    return max(depth)


def _entries(flat: jax.Array) -> rg.Rigid:
    """A pose from its 12 entries on the leading axis (``R`` row by row, then ``p``)."""
    R = tuple(tuple(flat[3 * i + j] for j in range(3)) for i in range(3))
    return rg.Rigid(R, tuple(flat[9 + i] for i in range(3)))


def _rows(T: jax.Array) -> jax.Array:
    """``(k, 12)``: the 12 entries of each of ``k`` poses ``(k, 4, 4)``."""
    return jnp.concatenate([T[:, :3, :3].reshape(-1, 9), T[:, :3, 3]], axis=1)


def _per_row(rows: jax.Array, ndim: int) -> rg.Rigid:
    """The poses of ``rows (k, 12)`` as entries ``(k, 1, ...)``, against values ``(k,) + batch`` (``ndim`` axes)."""
    return _entries(rows.T[(slice(None), slice(None)) + (None,) * ndim])


def _flat(T: rg.Rigid, shape: tuple[int, ...], dtype) -> jax.Array:
    """The 12 entries of ``T`` stacked on a new leading axis, each broadcast to ``shape``."""
    return rg.stack(rg.leaves(T), shape, dtype, axis=0)


@dataclasses.dataclass(frozen=True)
class _ChainTree:
    """A :class:`~diffkin.PoEChain` as the tree the scan walks: body ``j + 1`` is body ``j`` moved by
    ``exp([screws[j]] q_j)`` (the joint poses are the identity: PoE screws are in the base frame); its
    frames are the base, each link (``link_homes``) and the end effector (``home``), on bodies 0 .. dof."""

    screws: jax.Array
    joint_poses: jax.Array
    frame_poses: jax.Array
    multipliers: jax.Array
    offsets: jax.Array
    dof: int

    @property
    def parents(self) -> tuple[int, ...]:
        return tuple(range(self.dof))

    sources = parents

    @property
    def frame_bodies(self) -> tuple[int, ...]:
        return (*range(self.dof + 1), self.dof)

    def ancestors(self, body: int) -> list[int]:
        return list(range(body))


def chain_forward(chain, q: Sequence[rg.Entry], base: rg.Rigid) -> ScannedPass:
    """The forward pass of a serial chain (as its own ``forward``), by a scan; frame ``None`` is the end effector.

    Args:
        chain: a :class:`~diffkin.PoEChain`, or a :class:`~diffkin.DHChain` (converted exactly by
            :func:`~diffkin.models.poe.to_poe`, on the host when its numbers are concrete).
        q: its ``dof`` joint values.
        base: the pose of its base frame in the world.
    """
    from diffkin.models.dh import DHChain
    from diffkin.models.poe import to_poe

    n = chain.dof
    first = chain.base if isinstance(chain, DHChain) else None  # DH frame 0 (its PoE form folds it in)
    if isinstance(chain, DHChain):
        with jax.ensure_compile_time_eval():  # a concrete chain's PoE form is a constant
            chain = to_poe(chain)
    dtype = jnp.result_type(chain.screws)
    eye = jnp.broadcast_to(jnp.eye(4, dtype=dtype), (n, 4, 4))
    first = eye[0] if first is None else jnp.asarray(first, dtype)
    homes = [first[None], jnp.asarray(chain.link_homes, dtype), jnp.asarray(chain.home, dtype)[None]]
    frames = jnp.concatenate(homes)  # the base, each link, the end effector
    tree = _ChainTree(chain.screws, eye, frames, jnp.ones(n, dtype), jnp.zeros(n, dtype), n)
    return forward(tree, q, base, end=n + 1)


def forward(robot, q: Sequence[rg.Entry], base: rg.Rigid, end: int | None = None) -> ScannedPass:
    """The robot's forward pass (as :meth:`diffkin.Robot.forward`), by a scan over its joints.

    Args:
        robot: the :class:`~diffkin.Robot` (or a :class:`_ChainTree`).
        q: its ``dof`` joint values (arrays of broadcastable batch shapes, or Python floats).
        base: ``T_world_root``.
        end: the frame that frame ``None`` means (a chain's end effector), or ``None`` (a robot).
    """
    nj = len(robot.parents)
    whole = q.array if isinstance(q, JointValues) else None  # the whole array: no slices to stack again
    leaves = [*(q if whole is None else [whole[..., 0]]), *rg.leaves(base)]  # (one joint stands for all)
    traced = [x for x in (robot.joint_poses, robot.screws, robot.multipliers, robot.offsets) if not is_concrete(x)]
    dtype = jnp.result_type(*(x for x in leaves if not isinstance(x, float)), *traced)  # as the unrolled pass's
    shape = rg.batch_shape(*leaves)
    lead = (slice(None),) + (None,) * len(shape)  # a (nj,) parameter against (nj,) + shape values

    if whole is None:
        Q = rg.stack(list(q), shape, dtype, axis=0)
    else:
        Q = jnp.broadcast_to(jnp.moveaxis(jnp.asarray(whole, dtype), -1, 0), (len(q), *shape))
    m, o = jnp.asarray(robot.multipliers, dtype), jnp.asarray(robot.offsets, dtype)
    theta = m[lead] * Q[np.asarray(robot.sources, np.int32)] + o[lead]  # (nj,) + shape
    S = jnp.asarray(robot.screws, dtype)
    v, w = tuple(S[:, i][lead] for i in range(3)), tuple(S[:, 3 + i][lead] for i in range(3))
    (E,) = rg.screw_exps([(v, w)], [theta])
    joint_poses = _rows(jnp.asarray(robot.joint_poses, dtype))

    def step(bodies, joint):
        j, parent, P_j, E_j = joint
        T_body = rg.compose(rg.compose(_entries(bodies[parent]), _entries(P_j)), _entries(E_j))
        return jax.lax.dynamic_update_index_in_dim(bodies, _flat(T_body, shape, dtype), j + 1, 0), None

    start = jnp.zeros((nj + 1, 12, *shape), dtype).at[0].set(_flat(base, shape, dtype))
    exps = jnp.moveaxis(_flat(E, (nj, *shape), dtype), 1, 0)  # (nj, 12) + shape
    parents = np.asarray(robot.parents, np.int32)
    bodies, _ = jax.lax.scan(step, start, (jnp.arange(nj), parents, joint_poses, exps))

    # Each joint's frame before its motion, for all joints at once (a second output of the scan
    # would make XLA copy the bodies' buffer at every step instead of updating it in place).
    T = rg.compose(_entries(jnp.moveaxis(bodies[parents], 1, 0)), _per_row(joint_poses, len(shape)))
    w_world = rg.rotate(T.R, w)
    v_world = rg.vadd(rg.rotate(T.R, v), rg.cross(T.p, w_world))
    return ScannedPass(robot, bodies, jnp.stack([*v_world, *w_world], axis=1), m, end)


class ScannedPass(RobotPass):
    """A :class:`~diffkin.models.robot.RobotPass` whose poses and screws are rows of arrays.

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
        return [_entries(self._bodies[b]) for b in range(len(self._bodies))]

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
        bodies = _entries(jnp.moveaxis(self._bodies[np.asarray([robot.frame_bodies[f] for f in indices])], 1, 0))
        F = _rows(jnp.asarray(robot.frame_poses, self._bodies.dtype)[np.asarray(indices)])
        return rg.compose(bodies, _per_row(F, self._bodies.ndim - 2))

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
