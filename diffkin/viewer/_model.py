"""One view of every diffkin model for the viewer: named frames, their tree, jitted poses and IK.

Chains (``DHChain``, ``PoEChain``) have the frames ``base``, ``link1`` ... ``link<dof>`` (the
frames of :func:`diffkin.link_poses`) and ``ee`` (:func:`diffkin.fk`, tool included), in a line.
A :class:`diffkin.Robot` has its own ``frame_names`` in a tree: a body's first frame hangs from
the first frame of its parent body, the body's other (fixed) frames from its first frame.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

import diffkin as dk
from diffkin._xla import solver_jit


@dataclasses.dataclass
class Kinematics:
    """Host-side description of a model for drawing, and its jitted functions.

    Attributes:
        model: the diffkin model.
        frame_names: names of the drawn frames.
        frame_parents: per frame, the index of the frame it hangs from (``-1`` for the root).
        joint_names, lower, upper: the actuated joints (the order of ``q``) and their limits
            (``lower``/``upper`` finite: unlimited joints get ``[-pi, pi]``).
        poses: ``q (dof,) -> (len(frame_names), 4, 4)`` world poses, jitted.
        ends: the frames that can have an IK target.
    """

    model: object
    frame_names: tuple[str, ...]
    frame_parents: tuple[int, ...]
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    poses: Callable[[jax.Array], jax.Array]
    ends: tuple[str, ...]

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def chain(self, end: str):
        """The serial chain IK moves for target frame ``end``, and the indices of its joints in ``q``."""
        if isinstance(self.model, dk.Robot):
            chain = self.model.chain(end)
            return chain, np.array([self.joint_names.index(n) for n in chain.joint_names])
        if end != "ee":
            raise ValueError(f"end: a serial chain has the single end frame 'ee', got {end!r}")
        return self.model, np.arange(self.dof)


def kinematics(model, ends: Sequence[str] | None = None) -> Kinematics:
    """The :class:`Kinematics` of a chain or robot.

    Args:
        model: ``DHChain``, ``PoEChain`` or ``Robot``.
        ends: frames to give IK targets (default: a chain's ``ee``; a robot's leaf frames whose
            path from the root is a serial chain, at most eight).

    Raises:
        TypeError: not a diffkin model.
        ValueError: an unknown frame in ``ends``.
    """
    lo = np.asarray(model.lower, dtype=np.float64)
    hi = np.asarray(model.upper, dtype=np.float64)
    lower, upper = np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)
    if isinstance(model, dk.Robot):
        names = tuple(model.frame_names)
        first: dict[int, int] = {}  # body -> its first frame
        for f, body in enumerate(model.frame_bodies):
            first.setdefault(body, f)
        parents = []
        for f, body in enumerate(model.frame_bodies):
            if f != first[body]:
                parents.append(first[body])
            elif body == 0:
                parents.append(-1)
            else:
                parents.append(first.get(model.parents[body - 1], -1))
        poses = jax.jit(lambda q: dk.link_poses(model, q))
        if ends is None:
            leaves = [f for f in range(len(names)) if f not in parents and parents[f] >= 0]
            ends = []
            for f in leaves:
                try:
                    model.chain(names[f])
                except ValueError:
                    continue
                ends.append(names[f])
            ends = ends[:8]
        else:
            for end in ends:
                model.frame_index(end)
    elif isinstance(model, (dk.DHChain, dk.PoEChain)):
        names = ("base", *(f"link{i + 1}" for i in range(model.dof)), "ee")
        parents = list(range(-1, model.dof + 1))
        poses = jax.jit(lambda q: jnp.concatenate([dk.link_poses(model, q), dk.fk(model, q)[None]]))
        if ends is None:
            ends = ("ee",)
        elif any(end != "ee" for end in ends):
            raise ValueError(f"ends: a serial chain has the single end frame 'ee', got {list(ends)}")
    else:
        raise TypeError(f"model: expected a DHChain, PoEChain or Robot, got {type(model).__name__}")
    return Kinematics(model, names, tuple(parents), tuple(model.joint_names), lower, upper, poses, tuple(ends))


def make_ik(kin: Kinematics, end: str, num_seeds: int) -> tuple[Callable, np.ndarray]:
    """A jitted one-target IK for frame ``end`` from a warm start, and the chain's joint indices in ``q``.

    The function maps ``(T (4, 4), q0 (n,), key)`` to :class:`diffkin.ik.IKResult` of the chain
    (``n`` its joints): ``dk.ik.solve(chain, T, q0=q0, key=key, num_seeds=num_seeds)``.
    """
    chain, index = kin.chain(end)
    solve = solver_jit(lambda T, q0, key: dk.ik.solve(chain, T, q0=q0, key=key, num_seeds=num_seeds))
    return solve, index


def make_ik_avoiding(kin: Kinematics, end: str, num_seeds: int, avoid) -> tuple[Callable, np.ndarray]:
    """A jitted one-target IK of a whole :class:`diffkin.Robot` that keeps clear of ``avoid``, and
    the indices of its joints in ``q`` (all of them).

    The function maps ``(T_world_target (4, 4), q0 (dof,), key, T_world_root (4, 4))`` to
    :class:`diffkin.ik.IKResult` with ``pos_err``, ``rot_err`` of the one target as scalars:
    ``dk.ik.solve(robot, {end: T}, q0=q0, key=key, num_seeds=num_seeds, base=T_world_root,
    avoid=avoid)``, every joint free (the obstacles are in the world, the root fixed where it is
    drawn). A fixed robot's root is always at the identity (only a floating robot's results move
    it): its ``T_world_root`` is not passed on, which saves a third of the compilation. The robot
    and ``avoid`` (a ``dk.ik.Avoid`` of its geometry) are closed over.
    """
    robot = kin.model
    assert isinstance(robot, dk.Robot)  # (checked by show)

    def solve(T, q0, key, T_world_root):
        base = T_world_root if robot.floating else None
        res = dk.ik.solve(robot, {end: T}, q0=q0, key=key, num_seeds=num_seeds, base=base, avoid=avoid)
        return res._replace(pos_err=res.pos_err[..., 0], rot_err=res.rot_err[..., 0])

    return solver_jit(solve), np.arange(kin.dof)
