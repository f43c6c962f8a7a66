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

The result is a :class:`~diffkin.models._passes.ScannedPass`, a ``RobotPass`` (bodies and world screws as
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
from diffkin.models._passes import ScannedPass, entries, per_row, rows
from diffkin.models.forward import JointValues

# A robot whose longest path from the root has more joints than this takes the scanned pass.
LONG = 32


def longest_path(parents: Sequence[int]) -> int:
    """The most joints on one path from the root (``parents`` as in :class:`~diffkin.Robot`)."""
    depth = [0]
    for parent in parents:
        depth.append(depth[parent] + 1)
    return max(depth)


def _flat(T: rg.Rigid, shape: tuple[int, ...], dtype) -> jax.Array:
    """The 12 entries of ``T`` stacked on a new leading axis, each broadcast to ``shape``."""
    return rg.stack(rg.leaves(T), shape, dtype, axis=0)


@dataclasses.dataclass(frozen=True)
class _ChainTree:
    """A chain in PoE form as the tree the scan walks: body ``j + 1`` is body ``j`` moved by
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


def chain_forward(
    screws: jax.Array, link_homes: jax.Array, home: jax.Array, q: Sequence[rg.Entry], base: rg.Rigid, first=None
) -> ScannedPass:
    """The forward pass of a serial chain in product-of-exponentials form (as its own ``forward``), by a scan;
    frame ``None`` is the end effector.

    Args:
        screws, link_homes, home: the chain's :class:`~diffkin.PoEChain` arrays (a
            :class:`~diffkin.DHChain`'s from :func:`~diffkin.models.dh.poe_arrays`).
        q: its ``dof`` joint values.
        base: the pose of its base frame in the world.
        first: ``(4, 4)`` pose of its frame 0 (a DH chain's ``base``, which its PoE form folds into the
            others), or ``None``: the identity.
    """
    n = len(screws)
    dtype = jnp.result_type(screws)
    eye = jnp.broadcast_to(jnp.eye(4, dtype=dtype), (n, 4, 4))
    first = eye[0] if first is None else jnp.asarray(first, dtype)
    homes = [first[None], jnp.asarray(link_homes, dtype), jnp.asarray(home, dtype)[None]]
    frames = jnp.concatenate(homes)  # the base, each link, the end effector
    tree = _ChainTree(screws, eye, frames, jnp.ones(n, dtype), jnp.zeros(n, dtype), n)
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
    joint_poses = rows(jnp.asarray(robot.joint_poses, dtype))

    def step(bodies, joint):
        j, parent, P_j, E_j = joint
        T_body = rg.compose(rg.compose(entries(bodies[parent]), entries(P_j)), entries(E_j))
        return jax.lax.dynamic_update_index_in_dim(bodies, _flat(T_body, shape, dtype), j + 1, 0), None

    start = jnp.zeros((nj + 1, 12, *shape), dtype).at[0].set(_flat(base, shape, dtype))
    exps = jnp.moveaxis(_flat(E, (nj, *shape), dtype), 1, 0)  # (nj, 12) + shape
    parents = np.asarray(robot.parents, np.int32)
    bodies, _ = jax.lax.scan(step, start, (jnp.arange(nj), parents, joint_poses, exps))

    # Each joint's frame before its motion, for all joints at once (a second output of the scan
    # would make XLA copy the bodies' buffer at every step instead of updating it in place).
    T = rg.compose(entries(jnp.moveaxis(bodies[parents], 1, 0)), per_row(joint_poses, len(shape)))
    w_world = rg.rotate(T.R, w)
    v_world = rg.vadd(rg.rotate(T.R, v), rg.cross(T.p, w_world))
    return ScannedPass(robot, bodies, jnp.stack([*v_world, *w_world], axis=1), m, end)
