"""PyRoki's collision-aware IK and trajectory optimisation on a Panda, as a peer for diffkin's benchmarks.

Follows PyRoki's ``examples/pyroki_snippets/_solve_ik_with_collision.py`` (chungmin99/pyroki @ 70b30a5,
jaxls @ 50a58be): one jaxls least-squares problem per target with PyRoki's own costs and weights
(pose: position 5, orientation 1; soft joint limits 100; rest pose 0.01; self collision margin
0.02 m, weight 5; world collision margin 0.05 m, weight 10), Levenberg-Marquardt with jaxls'
defaults (at most 100 iterations, one start at the middle of the joint limits), dense Cholesky.
The batch is ``jax.vmap`` of that solve, jitted once per batch size and obstacle counts.
:func:`solve_trajectories` follows ``examples/pyroki_snippets/_trajopt.py`` (same commits) from a start
to a joint goal.

PyRoki has no success flag: ``solve_batch`` returns the configurations and the caller checks them.
PyRoki has no box either (its world shapes: ``HalfSpace``, ``Sphere``, ``Capsule``, ``Heightmap``);
see ``solve_batch`` for how a box is represented here.

PyRoki is imported inside the functions, so importing this module needs neither PyRoki nor jaxls.
Run ``python experiments/_pyroki_peer.py`` for a smoke run (8 targets, a sphere, a floor).
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

POSE_WEIGHTS = (5.0, 1.0)  # position, orientation (PyRoki's example)
LIMIT_WEIGHT, REST_WEIGHT = 100.0, 0.01
SELF_MARGIN, SELF_WEIGHT = 0.02, 5.0
WORLD_MARGIN, WORLD_WEIGHT = 0.05, 10.0
SMOOTH_WEIGHT = 0.1  # consecutive configurations of a path (PyRoki's trajectory example)
# PyRoki's trajectory example: timesteps; its swept-capsule world collision (activation distance, weight); its
# start/end constraints (on two timesteps each); its five-point velocity-limit, acceleration and jerk costs
TRAJ_STEPS = 25
SWEEP_MARGIN, SWEEP_WEIGHT = 0.1, 20.0
ENDS_WEIGHT = 100.0
VELOCITY_WEIGHT, ACCELERATION_WEIGHT, JERK_WEIGHT = 10.0, 0.1, 0.1
EXAMPLE_DURATION = 24 * 0.02  # the example's (timesteps - 1) x dt, seconds
GOAL_TOL = (5e-3, 0.05)  # m, rad: its goal reached (the loose tolerance of this project's earlier PyRoki comparisons)


def _package_handler(urdf_path: str):
    """``package://pkg/rel`` -> the first ``<ancestor of the URDF>/pkg/rel`` that exists."""

    def handler(fname: str) -> str:
        rel = fname.removeprefix("package://").removeprefix("file://")
        d = os.path.dirname(os.path.abspath(urdf_path))
        while True:
            if os.path.exists(os.path.join(d, rel)):
                return os.path.join(d, rel)
            if os.path.dirname(d) == d:
                return fname
            d = os.path.dirname(d)

    return handler


def srdf_disabled_pairs(srdf_path: str) -> tuple[tuple[str, str], ...]:
    """The ``<disable_collisions link1= link2=>`` pairs of an SRDF."""
    import xml.etree.ElementTree as ET

    root = ET.parse(srdf_path).getroot()
    return tuple((e.get("link1", ""), e.get("link2", "")) for e in root.iter("disable_collisions"))


def panda_robot(urdf_path: str, srdf_path: str | None = None) -> tuple[Any, Any]:
    """PyRoki ``Robot`` and ``RobotCollision`` (one capsule per link) of the Panda URDF at ``urdf_path``.

    ``package://`` mesh paths resolve against the URDF's ancestor folders (for example-robot-data,
    ``share/``). PyRoki itself ignores only parent/child link pairs for self collision; with
    ``srdf_path`` the SRDF's ``<disable_collisions>`` pairs, and every pair involving a link
    without collision geometry (PyRoki gives such a link a zero-radius capsule at its origin), are
    passed to PyRoki as ``user_ignore_pairs`` as well. Without them many Panda pairs overlap in
    every configuration (link5-link7, hand-link6/7, fingers-link7) and self-collision costs never
    vanish. The geometry-less links' zero-radius capsules (points at ``panda_link8`` and
    ``panda_hand_tcp``) still count against world obstacles, as in PyRoki.
    """
    import pyroki as pk
    import yourdfpy

    urdf = yourdfpy.URDF.load(
        urdf_path, filename_handler=_package_handler(urdf_path), load_meshes=False, load_collision_meshes=False
    )
    robot = pk.Robot.from_urdf(urdf)
    ignore: tuple[tuple[str, str], ...] = ()
    if srdf_path is not None:
        empty = [n for n in robot.links.names if not urdf.link_map[n].collisions]
        ignore = srdf_disabled_pairs(srdf_path) + tuple((e, n) for e in empty for n in robot.links.names if n != e)
    coll = pk.collision.RobotCollision.from_urdf(urdf, user_ignore_pairs=ignore)
    if not np.all(np.asarray(coll.coll.size)[[bool(urdf.link_map[n].collisions) for n in coll.link_names], 0] > 0):
        raise RuntimeError("some collision meshes did not load (zero-size capsules)")
    return robot, coll


def _box_halfspaces(boxes: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Points and outward normals ``(B, 6, 3)`` of the six face planes of each box."""
    points, normals = [], []
    for pose, half in boxes:
        R, c, h = np.asarray(pose)[:3, :3], np.asarray(pose)[:3, 3], np.asarray(half)
        n = np.concatenate([R.T, -R.T])  # (6, 3): +x, +y, +z, -x, -y, -z axes of the box
        points.append(c + np.concatenate([h, h])[:, None] * n)
        normals.append(n)
    return np.stack(points), np.stack(normals)


@functools.cache
def _batched_solver():
    """``jit(vmap(solve one target))``; jax retraces only for new shapes or a new robot."""
    import jax
    import jax.numpy as jnp
    import jaxlie
    import jaxls
    import pyroki as pk
    from loguru import logger
    from pyroki.collision import HalfSpace, Sphere, colldist_from_sdf

    logger.disable("jaxls")  # an INFO line per cost at every trace

    @jaxls.Cost.factory
    def box_cost(vals, robot, robot_coll, joint_var, faces: HalfSpace, margin: float, weight: float):
        # (B, N links, 6 faces) signed distances to each face's half-space; their max over the
        # faces is a lower bound of the distance to the box (exact when a face is nearest).
        d = robot_coll.compute_world_collision_distance(robot, vals[joint_var], faces).max(axis=-1)
        return (colldist_from_sdf(d, margin) * weight).flatten()

    def solve_one(robot, coll, link_index, target, spheres, box_points, box_normals, plane_point, plane_normal):
        joint_var = robot.joint_var_cls(0)
        costs = [
            pk.costs.pose_cost(robot, joint_var, jaxlie.SE3.from_matrix(target), link_index, *POSE_WEIGHTS),
            pk.costs.limit_cost(robot, joint_var, weight=LIMIT_WEIGHT),
            pk.costs.rest_cost(joint_var, jnp.array(joint_var.default_factory()), weight=REST_WEIGHT),
            pk.costs.self_collision_cost(robot, coll, joint_var, margin=SELF_MARGIN, weight=SELF_WEIGHT),
        ]
        if spheres is not None:
            world = Sphere.from_center_and_radius(spheres[:, :3], spheres[:, 3])
            costs.append(pk.costs.world_collision_cost(robot, coll, joint_var, world, WORLD_MARGIN, WORLD_WEIGHT))
        if plane_point is not None:
            world = HalfSpace.from_point_and_normal(plane_point, plane_normal)
            costs.append(pk.costs.world_collision_cost(robot, coll, joint_var, world, WORLD_MARGIN, WORLD_WEIGHT))
        if box_points is not None:
            faces = HalfSpace.from_point_and_normal(box_points, box_normals)
            costs.append(box_cost(robot, coll, joint_var, faces, WORLD_MARGIN, WORLD_WEIGHT))
        problem = jaxls.LeastSquaresProblem(costs, [joint_var]).analyze()
        return problem.solve(verbose=False, linear_solver="dense_cholesky")[joint_var]

    in_axes = (None, None, None, 0, None, None, None, None, None)
    return jax.jit(jax.vmap(solve_one, in_axes=in_axes))


def solve_batch(
    robot: Any,
    coll: Any,
    target_link: str,
    targets: np.ndarray,
    spheres: np.ndarray,
    boxes: Sequence[tuple[np.ndarray, np.ndarray]],
    plane: tuple[np.ndarray, float] | None,
) -> tuple[np.ndarray, list[str]]:
    """PyRoki's collision-aware IK for each of ``targets`` ``(N, 4, 4)`` (poses of ``target_link``).

    Obstacles: ``spheres`` ``(k, 4)`` rows ``[x, y, z, r]``; ``boxes`` ``(T_world_box 4x4, half
    extents (3,))``; ``plane`` ``(unit normal, offset)``, the solid half-space ``normal . x <= offset``,
    or ``None``. PyRoki has no box shape; a box is the intersection of its six face half-spaces
    (PyRoki ``HalfSpace``), each link capsule's distance to it the largest of its distances to the six
    half-spaces, which is exact when a face is the nearest feature and underestimates near edges and
    corners (by up to a factor of sqrt 3 at a corner): conservative, never lets a capsule into a box
    unpenalised. Boxes get the same margin and weight as PyRoki's other world obstacles.

    Returns:
        ``(N, dof)`` configurations in PyRoki's actuated joint order, and that order's joint names.
        Not clipped to the limits (PyRoki's limits are a soft cost).
    """
    import jax.numpy as jnp

    dt = jnp.zeros(()).dtype  # float64 when the caller enabled jax_enable_x64
    target = jnp.asarray(targets, dt)
    link_index = jnp.asarray(robot.links.names.index(target_link), jnp.int32)
    sph = jnp.asarray(spheres, dt).reshape(-1, 4)
    bp = bn = pp = pn = None
    if len(boxes):
        bp, bn = (jnp.asarray(a, dt) for a in _box_halfspaces(boxes))
    if plane is not None:
        n = np.asarray(plane[0], np.float64)
        pp, pn = jnp.asarray(n * float(plane[1]), dt), jnp.asarray(n, dt)
    q = _batched_solver()(robot, coll, link_index, target, sph if len(sph) else None, bp, bn, pp, pn)
    return np.asarray(q), list(robot.joints.actuated_names)


@functools.cache
def _path_solver(steps: int):
    """``jit(vmap(solve one path of steps waypoints))`` of :func:`solve_paths`."""
    import jax
    import jax.numpy as jnp
    import jaxlie
    import jaxls
    import pyroki as pk
    from loguru import logger

    logger.disable("jaxls")

    def solve_one(robot, link_index, targets, q0):
        path = robot.joint_var_cls(jnp.arange(steps))
        each = jax.tree.map(lambda x: x[None], robot)  # the robot broadcast over the waypoints
        costs = [
            pk.costs.pose_cost(each, path, jaxlie.SE3.from_matrix(targets), link_index[None], *POSE_WEIGHTS),
            pk.costs.limit_cost(each, path, LIMIT_WEIGHT),
            pk.costs.rest_cost(path, jnp.asarray(path.default_factory())[None], REST_WEIGHT),
            pk.costs.smoothness_cost(
                robot.joint_var_cls(jnp.arange(1, steps)), robot.joint_var_cls(jnp.arange(steps - 1)), SMOOTH_WEIGHT
            ),
        ]
        start = jaxls.VarValues.make((path.with_value(jnp.broadcast_to(q0, (steps, q0.shape[-1]))),))
        return jaxls.LeastSquaresProblem(costs, [path]).analyze().solve(start, verbose=False)[path]

    return jax.jit(jax.vmap(solve_one, in_axes=(None, None, 0, 0)))


def solve_paths(robot: Any, target_link: str, waypoints: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """PyRoki's trajectory optimisation (``examples/pyroki_snippets/_trajopt.py``'s costs) along given waypoints.

    One jaxls problem per path over all its configurations: the pose of ``target_link`` at every
    waypoint (PyRoki's IK weights: position 5, orientation 1), soft joint limits (100), the rest pose
    (0.01) and the difference of consecutive configurations (0.1, the trajectory example's smoothness
    weight); every configuration starts at ``q0``; jaxls' defaults (Levenberg-Marquardt, conjugate
    gradients, at most 100 iterations). The example's own start/end constraints and collision sweeps
    are left out: here every waypoint is a target. ``jax.vmap`` over the paths.

    Args:
        waypoints: ``(P, T, 4, 4)`` poses of ``target_link``.
        q0: ``(P, dof)`` start configurations in PyRoki's actuated joint order.

    Returns:
        ``(P, T, dof)`` configurations (float32 unless the caller enabled ``jax_enable_x64``).
    """
    import jax.numpy as jnp

    dt = jnp.zeros(()).dtype
    link_index = jnp.asarray(robot.links.names.index(target_link), jnp.int32)
    solve = _path_solver(int(waypoints.shape[1]))
    return np.asarray(solve(robot, link_index, jnp.asarray(waypoints, dt), jnp.asarray(q0, dt)))


@functools.cache
def _trajopt_solver(steps: int):
    """``jit(vmap(solve one trajectory of steps timesteps))`` of :func:`solve_trajectories`."""
    import jax
    import jax.numpy as jnp
    import jaxlie
    import jaxls
    import pyroki as pk
    from loguru import logger
    from pyroki.collision import Capsule, HalfSpace, colldist_from_sdf, collide

    logger.disable("jaxls")

    def swept(robot, coll, q_prev, q_next, faces, capsules):
        # (5 x links, boxes + capsules) signed distances of the swept capsules: a box's the largest over its faces
        sweep = coll.get_swept_capsules(robot, q_prev, q_next)
        box = collide(sweep.reshape((-1, 1, 1)), faces.reshape((1, *faces.get_batch_axes()))).max(axis=-1)
        return jnp.concatenate([box, collide(sweep.reshape((-1, 1)), capsules.reshape((1, -1)))], axis=-1)

    def sweep_cost(vals, robot, coll, prev, nxt, faces, capsules):
        d = swept(robot, coll, vals[prev], vals[nxt], faces, capsules)
        return (colldist_from_sdf(d, SWEEP_MARGIN) * SWEEP_WEIGHT).flatten()

    def ends_cost(vals, var, q):
        return ((vals[var] - q) * ENDS_WEIGHT).flatten()

    def solve_one(robot, coll, start, goal, dt, face_points, face_normals, cylinder_poses, radius, length):
        faces = HalfSpace.from_point_and_normal(face_points, face_normals)  # (boxes, 6)
        capsules = Capsule(pose=jaxlie.SE3.from_matrix(cylinder_poses), size=jnp.stack([radius, length], -1))
        var = lambda a, b: robot.joint_var_cls(jnp.arange(a, steps + b))  # noqa: E731  timesteps a .. steps + b - 1
        traj = var(0, 0)
        each, each_coll, faces_1, capsules_1 = (
            jax.tree.map(lambda x: x[None], x) for x in (robot, coll, faces, capsules)
        )
        costs = [
            pk.costs.rest_cost(traj, traj.default_factory()[None], REST_WEIGHT),
            pk.costs.limit_cost(each, traj, LIMIT_WEIGHT),
            jaxls.Cost(sweep_cost, (each, each_coll, var(0, -1), var(1, 0), faces_1, capsules_1)),
            jaxls.Cost(ends_cost, (var(0, 2 - steps), start[None])),
            jaxls.Cost(ends_cost, (var(steps - 2, 0), goal[None])),
            pk.costs.smoothness_cost(var(1, 0), var(0, -1), SMOOTH_WEIGHT),
            pk.costs.five_point_velocity_cost(each, var(4, 0), var(3, -1), var(1, -3), var(0, -4), dt, VELOCITY_WEIGHT),
            pk.costs.five_point_acceleration_cost(
                var(2, -2), var(4, 0), var(3, -1), var(1, -3), var(0, -4), dt, ACCELERATION_WEIGHT
            ),
            pk.costs.five_point_jerk_cost(
                var(6, 0), var(5, -1), var(4, -2), var(2, -4), var(1, -5), var(0, -6), dt, JERK_WEIGHT
            ),
        ]
        start_vals = jaxls.VarValues.make((traj.with_value(jnp.linspace(start, goal, steps)),))
        q = jaxls.LeastSquaresProblem(costs, [traj]).analyze().solve(start_vals, verbose=False)[traj]
        own = jax.vmap(lambda a, b: swept(robot, coll, a, b, faces, capsules).min())(q[:-1], q[1:]).min()
        return q, own

    return jax.jit(jax.vmap(solve_one, in_axes=(None, None, 0, 0, 0, 0, 0, 0, 0, 0)))


def solve_trajectories(
    robot: Any,
    coll: Any,
    start: np.ndarray,
    goal: np.ndarray,
    boxes: tuple[np.ndarray, np.ndarray],
    cylinders: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PyRoki's trajectory optimisation (``examples/pyroki_snippets/_trajopt.py``) from ``start`` to ``goal``.

    Its formulation for each problem, with its costs and weights: 25 timesteps, initialised on the straight
    line from ``start`` to ``goal`` (the example solves IK for them first; here they are joint configurations);
    the first two timesteps held at ``start`` and the last two at ``goal`` (weight 100); rest pose (0.01); soft
    joint limits (100); swept-capsule world collision between consecutive timesteps (activation distance
    0.1 m, weight 20; no self collision, as in the example); smoothness (0.1); five-point velocity-limit (10),
    acceleration (0.1) and jerk (0.1) costs at ``dt``; jaxls' defaults (Levenberg-Marquardt, conjugate
    gradients, at most 100 iterations). ``jax.vmap`` over the problems.

    The example's ``dt`` (0.02 s, 0.48 s in all) is for a short hand motion; here ``dt`` makes the straight line
    run its most limited joint at half its velocity limit (at least the example's 0.48 s in all).

    Obstacles, each problem the same counts (pad with far-away shapes): a box is the intersection of its six
    face half-spaces (as :func:`solve_batch`: a swept capsule's distance the largest over the faces, a lower
    bound); a cylinder is PyRoki's ``Capsule`` of its radius and length (its axis, caps beyond its ends: it
    covers the cylinder).

    Args:
        start, goal: ``(P, dof)`` configurations in PyRoki's actuated joint order.
        boxes: ``T_world_box (P, B, 4, 4)`` and half extents ``(P, B, 3)``.
        cylinders: ``T_world_cylinder (P, C, 4, 4)`` (axis: local z), radius ``(P, C)`` and length ``(P, C)``.

    Returns:
        ``(P, 25, dof)`` configurations at the timesteps, ``dt (P,)`` seconds, and ``(P,)`` the smallest signed
        distance (m) of the swept capsules to the obstacles as PyRoki models them (>= 0: clear by its own
        model).
    """
    import jax.numpy as jnp

    dt_type = jnp.zeros(()).dtype
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    straight = np.max(np.abs(goal - start) / np.asarray(robot.joints.velocity_limits), axis=-1)
    dt = np.maximum(2 * straight, EXAMPLE_DURATION) / (TRAJ_STEPS - 1)
    faces = [_box_halfspaces(list(zip(T, h, strict=True))) for T, h in zip(*boxes, strict=True)]
    args = (start, goal, dt, np.stack([p for p, _ in faces]), np.stack([n for _, n in faces]), *cylinders)
    q, own = _trajopt_solver(TRAJ_STEPS)(robot, coll, *(jnp.asarray(a, dt_type) for a in args))
    return np.asarray(q), dt, np.asarray(own)


def locked(robot: Any, values: dict[str, float]) -> Any:
    """``robot`` with each actuated joint of ``values`` (and its mimics) given the limits ``[value, value]``.

    PyRoki cannot lock a joint; its limit cost (weight 100) then holds the joint there, as diffkin's ``locked``
    does (MBM's Panda fingers at 0.065 m, beyond the URDF's 0.04).
    """
    import jax.numpy as jnp
    import jax_dataclasses as jdc

    j = robot.joints
    value = np.array(j.lower_limits, np.float64)
    index = [j.actuated_names.index(name) for name in values]
    value[index] = list(values.values())
    # the actuated joint each joint is or follows (-1: neither), and every joint held through it
    follows = np.where(np.asarray(j.actuated_indices) >= 0, j.actuated_indices, j.mimic_act_indices)
    held = np.isin(follows, index)
    at = value[follows[held]] * np.asarray(j.mimic_multiplier)[held] + np.asarray(j.mimic_offset)[held]
    lo_all, hi_all = np.array(j.lower_limits_all), np.array(j.upper_limits_all)
    lo_all[held], hi_all[held] = at, at
    lo, hi = np.array(j.lower_limits), np.array(j.upper_limits)
    lo[index], hi[index] = value[index], value[index]
    joints = jdc.replace(
        j,
        **{k: jnp.asarray(v, j.lower_limits.dtype) for k, v in
           dict(lower_limits=lo, upper_limits=hi, lower_limits_all=lo_all, upper_limits_all=hi_all).items()},
    )  # fmt: skip
    return jdc.replace(robot, joints=joints)


def _example_robot_data_panda() -> tuple[str, str]:
    from _bench import example_robot_data

    root = os.path.join(example_robot_data(), "panda_description")
    return os.path.join(root, "urdf", "panda.urdf"), os.path.join(root, "srdf", "panda.srdf")


def _smoke(n: int = 8, seed: int = 0) -> None:
    import jax
    import jax.numpy as jnp
    import jaxlie
    from pyroki.collision import HalfSpace, Sphere

    urdf, srdf = _example_robot_data_panda()
    robot, coll = panda_robot(urdf, srdf)
    link = "panda_hand"
    sphere = np.array([[0.45, 0.0, 0.35, 0.1]])
    floor = (np.array([0.0, 0.0, 1.0]), -0.2)
    world = [
        Sphere.from_center_and_radius(sphere[0, :3], sphere[0, 3]),
        HalfSpace.from_point_and_normal(floor[0] * floor[1], floor[0]),
    ]

    @jax.jit
    @jax.vmap
    def clearance(q):  # smallest world and self signed distance (PyRoki's capsules)
        w = jnp.stack([coll.compute_world_collision_distance(robot, q, g).min() for g in world]).min()
        return w, coll.compute_self_collision_distance(robot, q).min()

    # Targets: poses of in-limit configurations clear of the obstacles and of themselves.
    lo, hi = np.asarray(robot.joints.lower_limits), np.asarray(robot.joints.upper_limits)
    q = np.random.default_rng(seed).uniform(lo, hi, (64 * n, len(lo)))
    w, s = (np.asarray(a) for a in clearance(jnp.asarray(q)))
    q_true = q[(w > 0) & (s > 0)][:n]
    targets = np.asarray(
        jaxlie.SE3(robot.forward_kinematics(jnp.asarray(q_true))[:, robot.links.names.index(link)]).as_matrix()
    )

    args = (robot, coll, link, targets, sphere, [], floor)
    t0 = time.perf_counter()
    q_sol, names = solve_batch(*args)
    t1 = time.perf_counter()
    warm = []
    for _ in range(3):
        t = time.perf_counter()
        q_sol, _ = solve_batch(*args)
        warm.append(time.perf_counter() - t)
    T = np.asarray(
        jaxlie.SE3(robot.forward_kinematics(jnp.asarray(q_sol))[:, robot.links.names.index(link)]).as_matrix()
    )
    pos_err = np.linalg.norm(T[:, :3, 3] - targets[:, :3, 3], axis=-1)
    cos = (np.einsum("nij,nij->n", T[:, :3, :3], targets[:, :3, :3]) - 1) / 2
    rot_err = np.arccos(np.clip(cos, -1, 1))
    w, s = (np.asarray(a) for a in clearance(jnp.asarray(q_sol)))
    over = np.maximum(q_sol - hi, 0) + np.maximum(lo - q_sol, 0)
    print(f"jax {jax.__version__} {jax.default_backend()} dtype {q_sol.dtype}; joints {names}")
    print(f"active self pairs {len(coll.active_idx_i)}; {len(q_true)} targets for {link}")
    print(
        f"first call (trace, compile, solve): {t1 - t0:.2f} s; warm batch (median of 3): {np.median(warm) * 1e3:.1f} ms"
    )
    print("position error (mm):", np.array2string(pos_err * 1e3, precision=3))
    print("rotation error (mrad):", np.array2string(rot_err * 1e3, precision=3))
    print("min world distance (m):", np.array2string(w, precision=3))
    print("min self distance (m):", np.array2string(s, precision=3))
    print(f"max joint-limit violation: {over.max():.2e}")


if __name__ == "__main__":
    _smoke()
