"""What obstacles rule out of a base placement before any IK (``base_placement(..., avoid=, model=)``).

Two parts of a robot do not move with its joints: the shapes of its root body (fixed to the base) and
the shapes of the body that carries the tool frame (fixed to the tool: at a task, where the task pose
puts them). A base whose root-body shapes come within the margin of an obstacle collides at every
configuration, and a task whose tool-body shapes, placed at the task pose, come within the margin
collides at every solution from any base: neither can be solved clear (``dk.ik.solve(...,
avoid=)``), whatever the map says. The links between are checked by IK only
(:meth:`~diffkin.workspace.Placement.verify` with ``avoid``).
"""

from __future__ import annotations

import numpy as np

from diffkin.models.robot import Robot


def checked(model, avoid) -> tuple[Robot, str]:
    """``model`` as the ``(robot, frame_name)`` pair that ``avoid`` (a :class:`~diffkin.ik.Avoid` with
    obstacles shared by every problem) is of."""
    from diffkin.collision import World
    from diffkin.ik.interface import check_avoid

    if not (isinstance(model, tuple) and len(model) == 2 and isinstance(model[0], Robot)):
        raise ValueError("avoid: needs model=(robot, frame_name), the map's robot and tool frame")
    robot, frame = model
    if frame not in robot.frame_names:
        raise ValueError(f"model: no frame {frame!r} in the robot (frames: {', '.join(robot.frame_names)})")
    check_avoid(robot, avoid)
    if not isinstance(avoid.world, World):
        raise ValueError("avoid: expected obstacles (a dk.ik.Avoid with a world)")
    if avoid.world.batch != ():
        raise ValueError(f"avoid: expected one world shared by every base, got problem axes {avoid.world.batch}")
    return robot, frame


def subset(geom, shapes: np.ndarray):
    """The :class:`~diffkin.collision.Geometry` of only ``shapes`` (sorted indices into ``geom``'s shapes,
    which are ordered by kind), without self-collision pairs: its distances are those shapes' rows."""
    import dataclasses

    import jax

    starts = np.cumsum((0, *geom.counts))
    kinds = tuple(
        jax.tree.map(lambda x, i=shapes[(shapes >= lo) & (shapes < hi)] - lo: x[i], kind)
        for kind, lo, hi in zip(geom.shapes, starts[:-1], starts[1:], strict=True)
    )

    def pick(values: tuple) -> tuple:
        return tuple(values[i] for i in shapes) if values else values

    return dataclasses.replace(
        geom,
        shapes=kinds,
        shape_frames=pick(geom.shape_frames),
        shape_names=pick(geom.shape_names),
        shape_bodies=pick(geom.shape_bodies),
        shape_links=pick(geom.shape_links),
        pair_list=(),
        fits=(),
        shape_overshoot=pick(geom.shape_overshoot),
    )


_COMPILED: list[tuple] = []  # the last few (robot, geom, world, shapes, compiled distances), matched by identity


def _distances(robot: Robot, avoid, shapes: np.ndarray):
    """``world_distances`` of ``shapes`` jitted with the robot, its shapes and the obstacles as constants
    (eager, it runs op by op; compiled over a traced robot, it compiles for minutes), kept for the next
    call with the same objects."""
    import jax

    from diffkin.collision import world_distances

    for r, g, w, s, fn in _COMPILED:
        if r is robot and g is avoid.geom and w is avoid.world and np.array_equal(s, shapes):
            return fn
    geom = subset(avoid.geom, shapes)
    fn = jax.jit(lambda q, base: world_distances(robot, geom, q, avoid.world, base=base))
    _COMPILED.insert(0, (robot, avoid.geom, avoid.world, shapes, fn))
    del _COMPILED[4:]
    return fn


def _gap(robot: Robot, avoid, shapes: np.ndarray, T_world_root: np.ndarray) -> np.ndarray:
    """``(M,)`` the smallest distance of ``shapes`` (indices in ``avoid.geom``) to the obstacles, the robot's
    root at ``T_world_root (M, 4, 4)`` and its joints at the middle of their limits (the shapes checked
    are those the joints do not move relative to that pose; only they are measured)."""
    q = np.broadcast_to(_mid(robot), (len(T_world_root), robot.dof))
    d = np.asarray(_distances(robot, avoid, shapes)(q, T_world_root))
    return d.min(axis=(1, 2), initial=np.inf)


def _mid(robot: Robot) -> np.ndarray:
    lower, upper = np.asarray(robot.lower, np.float64), np.asarray(robot.upper, np.float64)
    return np.where(np.isfinite(lower) & np.isfinite(upper), (lower + upper) / 2, np.clip(0.0, lower, upper))


def blocked(robot: Robot, frame: str, avoid, bases: np.ndarray, tasks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which bases and which tasks collide at every solution (see the module).

    Args:
        robot, frame: the map's robot and tool frame.
        avoid: a :class:`~diffkin.ik.Avoid`, obstacles in the world frame.
        bases: ``(M, 4, 4)`` ``T_world_base``, the robot's root poses.
        tasks: ``(N, 4, 4)`` ``T_world_task``, poses of ``frame``.

    Returns:
        ``(M,)`` and ``(N,)`` bool: within ``avoid.margin`` of an obstacle.
    """
    margin = float(avoid.margin)
    body = np.asarray(robot.frame_bodies)[np.asarray(avoid.geom.shape_frames, np.int64)]
    root, tool = np.flatnonzero(body == 0), np.flatnonzero(body == robot.frame_bodies[robot.frame_names.index(frame)])
    base_blocked, task_blocked = np.zeros(len(bases), bool), np.zeros(len(tasks), bool)
    if root.size:
        base_blocked = _gap(robot, avoid, root, bases) < margin
    if tool.size and tool[0] not in root:  # (a tool on the root body: the bases cover it)
        from diffkin.kinematics import fk

        T_root_frame = np.asarray(fk(robot, _mid(robot), frame), np.float64)
        task_blocked = _gap(robot, avoid, tool, tasks @ np.linalg.inv(T_root_frame)) < margin
    return base_blocked, task_blocked
