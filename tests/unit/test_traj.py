"""dk.traj.optimize: certified clearance (never above what dense sampling measures, and below zero for
a motion that passes through an obstacle between its knots), limits on the continuous motion, a
narrow passage, joint and pose goals, a world per problem, a goal in contact, bad input.

A two-link arm in the x-z plane (the collision example of docs/collision.md) among spheres; one
compiled program per shape of call, shared by the tests (module level).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import planar_capsule_arm

import diffkin as dk
from diffkin.collision import Sphere, World
from diffkin.traj import _certify, _limits, _optimize, _reach, _spline

URDF = planar_capsule_arm()
ROBOT = dk.load_robot(URDF)
GEOM = dk.collision.load(URDF, ROBOT)
MARGIN = 0.01
LIMITS = dk.traj.Limits(velocity=jnp.array([1.0, 1.5]), acceleration=jnp.array([2.0, 3.0]), jerk=20.0)
FAR = (5.0, 0.0, 5.0)  # a sphere no motion reaches (padding)


def _world(centres, radii) -> World:
    """A world per problem: ``centres`` ``(B, n, 3)``, ``radii`` ``(B, n)``."""
    return World(Sphere(jnp.asarray(centres, jnp.float32), jnp.asarray(radii, jnp.float32)))


@jax.jit
def _plan(q_start, goal, world):
    return dk.traj.optimize(
        ROBOT, q_start, goal, avoid=dk.ik.Avoid(GEOM, world, MARGIN), limits=LIMITS, knots=10, num_seeds=3
    )


# three problems, each among its own obstacles: a sphere over the arm held upright (the straight
# motion sweeps through it), a narrow passage (the elbow must bend, but not far), nothing near
START = jnp.array([[-1.2, 0.0], [-1.2, 0.0], [-1.0, 0.3]])
GOAL = jnp.array([[1.2, 0.0], [1.2, 0.0], [1.0, -0.3]])
WORLDS = _world(
    [[(0.0, 0.0, 1.0), FAR, FAR], [(0.0, 0.0, 1.0), (0.45, 0.0, 0.75), (-0.45, 0.0, 0.75)], [FAR, FAR, FAR]],
    [[0.1, 0.1, 0.1], [0.1, 0.12, 0.12], [0.1, 0.1, 0.1]],
)


@pytest.fixture(scope="module")
def planned():
    return _plan(START, GOAL, WORLDS)


def _dense(traj, n: int = 1501):
    """``(n, B)`` times over each motion and ``(n, B, dof)`` its configurations."""
    s = jnp.linspace(0.0, 1.0, n)[:, None]
    t = s * traj.duration
    return t, traj.at(t)


@jax.jit
def _clearance(q, world):
    return dk.collision.clearance(ROBOT, GEOM, q, world)


def _sampled_clearance(q, world) -> np.ndarray:
    """``(n, B)`` the exact clearance of configurations ``q`` ``(n, B, dof)``, each among its problem's world."""
    return np.asarray(_clearance(q, world))


def test_certified_clearance_never_above_sampled(planned):
    _, q = _dense(planned)
    sampled = _sampled_clearance(q, WORLDS).min(axis=0)
    assert np.all(np.asarray(planned.clearance) <= sampled + 1e-6)
    assert np.all(np.asarray(planned.clear) == (np.asarray(planned.clearance) >= MARGIN))


def test_obstacles_avoided_and_narrow_passage_solved(planned):
    assert np.asarray(planned.success).tolist() == [True, True, True]
    _, q = _dense(planned)
    assert np.all(_sampled_clearance(q, WORLDS).min(axis=0) >= MARGIN)
    # the straight motion of the first two collides: they bend the elbow; the third stays straight
    straight = jnp.linspace(0.0, 1.0, 1501)[:, None, None] * (GOAL - START) + START
    assert np.all(_sampled_clearance(straight, WORLDS).min(axis=0)[:2] < 0)
    assert np.max(np.abs(np.asarray(q[:, :2, 1]))) > 0.2
    length = np.linalg.norm(np.asarray(GOAL - START), axis=-1)
    np.testing.assert_allclose(np.asarray(planned.path_length)[2], length[2], rtol=1e-3)


def test_a_world_per_problem(planned):
    # problem 2 alone in problem 0's world would sweep through its sphere: the worlds were not mixed
    _, q = _dense(planned)
    own = _sampled_clearance(q, WORLDS).min(axis=0)
    swapped = _world([[(0.0, 0.0, 1.0), FAR, FAR]] * 3, [[0.1, 0.1, 0.1]] * 3)
    assert own[2] >= MARGIN
    assert _sampled_clearance(q, swapped).min(axis=0)[2] < own[2]


@pytest.mark.parametrize("at_once", [False, True], ids=["one-at-a-time", "all-at-once"])
def test_a_problem_s_motion_does_not_depend_on_the_others_in_its_batch(planned, at_once, monkeypatch):
    # problem 0 replaced by a copy of problem 2: problems 1 and 2 get the same motions (each problem draws
    # its seeds from its own key), whether the problems are planned one at a time (the CPU's way: the
    # same compiled program) or all at once (a GPU's way, posed here: a finished problem's curves are
    # left as they are and measure nothing while the others go on)
    worlds = jax.tree.map(lambda x: x.at[0].set(x[2]), WORLDS)
    plan = _plan
    if at_once:
        monkeypatch.setattr(_optimize, "problems_at_once", lambda n: n)
        plan = jax.jit(_plan.__wrapped__)  # traced afresh, with the patch
    other = plan(START.at[0].set(START[2]), GOAL.at[0].set(GOAL[2]), worlds)
    for name in ("control", "clearance", "segment_time", "success"):
        a, b = (np.asarray(getattr(t, name)) for t in (planned, other))
        np.testing.assert_allclose(b[1:], a[1:], rtol=1e-6, atol=1e-6, err_msg=name)


def test_a_later_round_solves_what_the_first_missed():
    # one seed, no descent: the first round is the straight line, which sweeps through the sphere over the
    # upright arm (test above); a later round's curve through a via point goes around it, certified clear
    traj = jax.jit(
        lambda s, g, w: dk.traj.optimize(
            ROBOT, s, g, avoid=dk.ik.Avoid(GEOM, w, MARGIN), limits=LIMITS, knots=10, num_seeds=1, max_iters=0
        )
    )(START[:1], GOAL[:1], jax.tree.map(lambda x: x[:1], WORLDS))
    assert bool(traj.success[0]) and float(traj.clearance[0]) >= MARGIN
    _, q = _dense(traj)
    world = jax.tree.map(lambda x: x[:1], WORLDS)
    assert _sampled_clearance(q, world).min() >= float(traj.clearance[0]) - 1e-6
    assert np.max(np.abs(np.asarray(traj.control[0, :, 1]))) > 0.2  # the elbow bends (straight: 0 throughout)


def test_a_goal_in_contact_fails_honestly(planned):
    # problem 2's goal inside a sphere (around its lower link's frame): no motion succeeds (it gets one
    # round); its result is finite, marked not clear, its certified clearance at most the goal's, and the
    # other problems' motions are as before
    centre = np.asarray(dk.fk(ROBOT, GOAL[2], "lower"))[:3, 3].astype(np.float32)
    worlds = jax.tree.map(lambda x: x.at[2].set(x[0]), WORLDS)
    worlds = World(Sphere(worlds.spheres.center.at[2, 0].set(centre), worlds.spheres.radius.at[2, 0].set(0.05)))
    goal_clearance = float(_sampled_clearance(GOAL[None], worlds)[0, 2])
    assert goal_clearance < 0
    traj = _plan(START, GOAL, worlds)
    assert not bool(traj.success[2]) and not bool(traj.clear[2])
    assert bool(traj.goal_ok[2]) and bool(traj.limits_ok[2])
    assert float(traj.clearance[2]) <= goal_clearance + 1e-6
    assert all(np.all(np.isfinite(np.asarray(x))) for x in (traj.control, traj.clearance, traj.duration))
    np.testing.assert_allclose(np.asarray(traj.control[:2]), np.asarray(planned.control[:2]), rtol=1e-6, atol=1e-6)


def test_limits_hold_on_the_continuous_motion(planned):
    t, q = _dense(planned, 4001)
    lower, upper = np.asarray(ROBOT.lower), np.asarray(ROBOT.upper)
    assert np.all((np.asarray(q) >= lower) & (np.asarray(q) <= upper))
    tol = 1 + 1e-5
    for k, bound in ((1, LIMITS.velocity), (2, LIMITS.acceleration), (3, LIMITS.jerk)):
        d = np.abs(np.asarray(planned.at(t, k)))
        assert np.all(d <= np.asarray(bound) * tol + 1e-6), k
    # the derivatives are those of the motion: central differences of at(t)
    dt = 1e-3
    tm = t[1:-1]
    fd = (planned.at(tm + dt) - planned.at(tm - dt)) / (2 * dt)
    np.testing.assert_allclose(np.asarray(planned.at(tm, 1)), np.asarray(fd), atol=2e-3)
    # starts and ends at rest, on the knots' times
    np.testing.assert_allclose(np.asarray(planned.at(jnp.zeros(3))), np.asarray(START), atol=1e-6)
    np.testing.assert_allclose(np.asarray(planned.at(planned.duration)), np.asarray(GOAL), atol=1e-5)
    np.testing.assert_allclose(np.asarray(planned.at(planned.duration, 1)), 0.0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(planned.t[:, -1]), np.asarray(planned.duration), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(planned.at(planned.t.T)), np.asarray(planned.q.swapaxes(0, 1)), atol=1e-5)


@jax.jit
def _certify_line(q_start, q_goal, world, margin=0.0):
    """The certificate (at ``margin``) of the straight motion from ``q_start`` to ``q_goal`` (5 knots), and its
    knots."""
    free = (q_start + q_goal)[None] / 2  # one free control point, in the middle
    P = _spline.control_points(q_start, free, q_goal)[None, None]  # (1, 1, 7, dof)
    avoid = dk.ik.Avoid(GEOM, world, margin).flat(())
    reach = _reach.reach(ROBOT, GEOM)
    lower, sampled = _certify.certified(ROBOT, avoid, reach, P, None, (False, False))
    pieces = _certify.PIECES
    mids = jnp.asarray((np.arange(4 * pieces) + 0.5) / pieces)[None, None]  # the 4 segments' pieces
    coarse, _ = _certify._bounds(ROBOT, avoid, reach, P, mids, 0.5 / pieces, None, (False, False))
    return lower[0, 0], sampled[0, 0], P[0, 0], _spline.knots(P[0, 0]), jnp.min(coarse)


def test_sampling_at_the_knots_misses_what_the_bound_rejects():
    # a straight motion whose knots all clear the sphere, which it passes through between two knots:
    # the certificate is below zero
    world = World(Sphere(jnp.array([[0.0, 0.0, 1.02]]), jnp.array([0.05])))
    lower, sampled, P, knots, _ = _certify_line(jnp.array([-1.0, 0.0]), jnp.array([0.6, 0.0]), world)
    assert float(_clearance(jnp.resize(knots, (2001, 2)), world).min()) > 0.05
    q = _spline.evaluate(P, jnp.linspace(0.0, 4.0, 2001))
    truth = float(_clearance(q, world).min())
    assert truth < 0
    assert float(lower) <= truth <= float(sampled) + 1e-9
    # and the reverse: where the certificate says clear, dense sampling agrees (far from the sphere)
    lower, _, P, _, coarse = _certify_line(jnp.array([-1.0, 0.0]), jnp.array([-0.4, 0.5]), world)
    q = _spline.evaluate(P, jnp.linspace(0.0, 4.0, 2001))
    truth = float(_clearance(q, world).min())
    assert 0 < float(lower) <= truth
    # clear of the margin on the pieces already: their bound is kept, not refined
    assert float(lower) == float(coarse)
    # below the margin (1 m here), the lowest pieces are cut finer: a tighter bound than the pieces' own, still
    # below the truth
    finer, _, _, _, _ = _certify_line(jnp.array([-1.0, 0.0]), jnp.array([-0.4, 0.5]), world, 1.0)
    assert float(coarse) < float(finer) <= truth and truth - float(finer) < 0.5 * (truth - float(coarse))


def test_reach_of_each_joint_to_each_shape():
    # joint 1's axis point (0, 0, 0.05) to the elbow (0.5), then to the lower capsule's centre (0.2) and its
    # half length plus radius (0.24); joint 2 from the elbow; the base does not move
    R = _reach.reach(ROBOT, GEOM)
    upper, lower, base = (GEOM.shape_links.index(n) for n in ("upper", "lower", "base"))
    np.testing.assert_allclose(R[:, lower], [0.5 + 0.2 + 0.24, 0.2 + 0.24], rtol=1e-6)
    np.testing.assert_allclose(R[:, upper], [0.25 + 0.3, 0.0], rtol=1e-6)
    np.testing.assert_allclose(R[:, base], [0.0, 0.0])


def test_chain_joint_and_pose_goals_in_float64():
    model = dk.robots.planar([0.5, 0.4, 0.3])
    with jax.enable_x64(True):
        q0 = jnp.zeros(3, jnp.float64)
        q1 = jnp.array([0.3, 0.6, 0.9])
        joint = dk.traj.optimize(model, q0, q1, knots=6, num_seeds=1, max_iters=5)
        assert joint.q.dtype == jnp.float64 and bool(joint.success) and float(joint.clearance) == np.inf
        np.testing.assert_allclose(np.asarray(joint.q[-1]), np.asarray(q1), atol=1e-12)
        # no obstacles: the straight line (its length) at the default limits (1 rad/s, 2 rad/s^2)
        np.testing.assert_allclose(float(joint.path_length), float(jnp.linalg.norm(q1 - q0)), rtol=1e-6)
        assert np.all(np.abs(np.asarray(joint.at(jnp.linspace(0, joint.duration, 999), 1))) <= 1.0 + 1e-9)
        # a pose goal: solved by IK, the motion ends on the pose; one out of reach (2 m away, the arm is 1.2 m
        # long): an honest failure, its numbers finite
        T = dk.fk(model, q1)
        far = T.at[0, 3].set(2.0).at[1, 3].set(0.0)
        pose = dk.traj.optimize(model, q0, jnp.stack([T, far]), knots=6, num_seeds=1, max_iters=5)
        assert pose.goal_ok.tolist() == [True, False] and pose.success.tolist() == [True, False]
        end = pose.at(pose.duration)
        np.testing.assert_allclose(np.asarray(dk.fk(model, end[0])), np.asarray(T), atol=1e-9)
        assert all(np.all(np.isfinite(np.asarray(x))) for x in (pose.control, pose.duration, pose.path_length, end))


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"q_start": jnp.zeros(3)}, ValueError, "q_start"),
        ({"goal": jnp.zeros(3)}, ValueError, "goal"),
        ({"q_start": "a"}, TypeError, "q_start"),
        ({"knots": 4}, ValueError, "knots"),
        ({"num_seeds": 0}, ValueError, "num_seeds"),
        ({"max_iters": -1}, ValueError, "max_iters"),
        ({"limits": dk.traj.Limits(jnp.ones(3), 1.0)}, ValueError, "Limits.velocity"),
        ({"limits": (1.0, 1.0)}, TypeError, "limits"),
        ({"avoid": GEOM}, TypeError, "avoid"),
        ({"locked": {"j9": 0.0}}, ValueError, "locked"),
        ({"q_start": jnp.array([np.nan, 0.0])}, ValueError, "q_start"),
        ({"base": jnp.eye(3)}, ValueError, "base"),
    ],
)
def test_bad_input(kwargs, error, match):
    args = {"q_start": jnp.zeros(2), "goal": jnp.ones(2)} | kwargs
    with pytest.raises(error, match=match):
        dk.traj.optimize(ROBOT, args.pop("q_start"), args.pop("goal"), **args)


def test_bad_limits():
    with pytest.raises(ValueError, match="Limits.acceleration"):
        dk.traj.Limits(velocity=1.0, acceleration=-1.0)
    with pytest.raises(TypeError, match="Limits.velocity"):
        dk.traj.Limits(velocity="fast", acceleration=1.0)


# an arm whose first and last joints turn about vertical axes away from the world origin: the feet of
# those axes from the origin lie far below the joints, the points nearest the joints' origins do not
OFFSET_ARM = """<robot name="arm">
  <link name="base"/>
  <link name="l1"><collision><origin xyz="0 0 0.2"/><geometry><capsule radius="0.04" length="0.4"/></geometry>
    </collision></link>
  <link name="l2"><collision><origin xyz="0.15 0 0"/><geometry><box size="0.3 0.05 0.05"/></geometry>
    </collision></link>
  <link name="l3"><collision><origin xyz="0 0 -0.15"/><geometry><capsule radius="0.03" length="0.3"/></geometry>
    </collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0.3 0.2 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.9"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0"/>
    <axis xyz="0 0 1"/><limit lower="-2.8" upper="2.8"/></joint>
</robot>"""


def test_reach_bounds_every_points_speed_and_follows_the_links():
    robot = dk.load_robot(OFFSET_ARM)
    geom = dk.collision.load(OFFSET_ARM, robot)
    R = _reach.reach(robot, geom)
    l1, l2, l3 = (geom.shape_links.index(n) for n in ("l1", "l2", "l3"))
    # j3 to its own capsule: the capsule's far end (0.3) plus its radius; j1 to it: the step to j2's
    # axis (0.9), to j3's (0.3), then 0.33; measured along the links, not from the feet of the axes
    np.testing.assert_allclose(R[2, l3], 0.33, rtol=1e-6)
    np.testing.assert_allclose(R[1, l3], 0.3 + 0.33, rtol=1e-6)
    np.testing.assert_allclose(R[0, l3], 0.9 + 0.3 + 0.33, rtol=1e-6)
    assert R[1, l1] == 0 and R[2, l2] == 0
    # and every bound holds: at random configurations, the speed of each shape's corner points per
    # unit of each joint's motion (central differences) stays within R minus the radius
    corners = {l1: [(0, 0, 0.0), (0, 0, 0.4)], l3: [(0, 0, 0.0), (0, 0, -0.3)]}
    corners[l2] = [(x, y, z) for x in (0.0, 0.3) for y in (-0.025, 0.025) for z in (-0.025, 0.025)]
    radius = {l1: 0.04, l2: 0.0, l3: 0.03}
    frames = {s: robot.frame_names.index(geom.shape_links[s]) for s in corners}
    q = np.random.default_rng(0).uniform(-2.5, 2.5, (200, 3))
    eps = 1e-6
    with jax.enable_x64(True):
        for c in range(3):
            step = eps * np.eye(3)[c]
            ahead, behind = (np.asarray(dk.link_poses(robot, jnp.asarray(q + d))) for d in (step, -step))
            for s, points in corners.items():
                p = np.c_[np.asarray(points), np.ones(len(points))]
                moved = (ahead[:, frames[s]] - behind[:, frames[s]]) @ p.T / (2 * eps)  # (200, 4, n)
                speed = np.max(np.linalg.norm(moved[:, :3], axis=1))
                assert speed <= max(R[c, s] - radius[s], 0.0) + 1e-6, (c, s, speed, R[c, s])


def test_default_limits_are_the_files_velocities():
    """Without ``limits`` a joint moves at most at its URDF ``<limit velocity>`` (1 rad/s where the file gives
    none), and beyond 1 rad/s where its file allows it."""
    urdf = OFFSET_ARM.replace('<limit lower="-3" upper="3"/>', '<limit lower="-3" upper="3" velocity="2.5"/>', 1)
    robot = dk.load_robot(urdf)
    np.testing.assert_array_equal(np.asarray(robot.velocity), [2.5, np.inf, np.inf])
    limits = _limits.default(robot.velocity)
    np.testing.assert_array_equal(np.asarray(limits.velocity), [2.5, 1.0, 1.0])
    q0, q1 = jnp.zeros(3), jnp.array([2.0, 0.2, 0.1])
    traj = dk.traj.optimize(robot, q0, q1, knots=6, num_seeds=1, max_iters=5)
    speed = np.max(np.abs(np.asarray(traj.at(jnp.linspace(0, traj.duration, 999), 1))), axis=0)
    assert bool(traj.success) and np.all(speed <= np.array([2.5, 1.0, 1.0]) * (1 + 1e-6))
    assert speed[0] > 1.0  # faster than the old 1 rad/s default: the file's limit is used


def _capsule_cloud(radius: float, length: float, count: int, rng) -> np.ndarray:
    """``(count, 3)`` random points on a capsule along z from 0 to ``length`` (its two hemispheres): a mesh whose
    hull has every point as a vertex."""
    u = rng.normal(size=(count, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return radius * u + np.outer(np.where(u[:, 2] > 0, length - radius, radius), [0.0, 0.0, 1.0])


def test_mesh_links_searched_on_fewer_vertices_certified_on_their_own():
    """The arm's links as meshes of 80 points (hulls of more vertices than the seeds and the descent measure,
    :data:`diffkin.traj._optimize.SEARCH_VERTICES`): the motion around the sphere over the upright arm is
    certified on the hulls themselves (never above what dense sampling of them measures, clear by the margin)."""
    rng = np.random.default_rng(3)
    meshes = {
        name: _capsule_cloud(r, length, 80, rng) for name, r, length in (("upper", 0.05, 0.5), ("lower", 0.04, 0.4))
    }
    vertex = {name: " ".join(f"{v:.6f}" for v in points.reshape(-1)) for name, points in meshes.items()}
    assets = "".join(f'<mesh name="{name}" vertex="{points}"/>' for name, points in vertex.items())
    mjcf = f"""<mujoco><compiler angle="radian"/><asset>{assets}</asset><worldbody>
      <body name="upper" pos="0 0 0.05"><joint name="j1" type="hinge" axis="0 1 0" range="-3 3"/>
        <geom type="mesh" mesh="upper"/><body name="lower" pos="0 0 0.5">
        <joint name="j2" type="hinge" axis="0 1 0" range="-3 3"/><geom type="mesh" mesh="lower"/></body></body>
      </worldbody></mujoco>"""
    robot = dk.load_robot(mjcf)
    geom = dk.collision.load(mjcf, robot, meshes="hulls")
    world = World(Sphere(jnp.array([[0.0, 0.0, 1.0]]), jnp.array([0.1])))
    avoid = dk.ik.Avoid(geom, world, MARGIN)
    searched = _optimize._searched(avoid)
    assert geom.convexes.vertices.shape[-2] > _optimize.SEARCH_VERTICES == searched.geom.convexes.vertices.shape[-2]
    traj = jax.jit(lambda s, g: dk.traj.optimize(robot, s, g, avoid=avoid, limits=LIMITS, knots=10, num_seeds=3))(
        START[:1], GOAL[:1]
    )
    assert bool(traj.success[0])
    _, q = _dense(traj)
    sampled = np.asarray(jax.jit(lambda q: dk.collision.clearance(robot, geom, q, world))(q)).min()
    assert float(traj.clearance[0]) <= sampled + 1e-6 and sampled >= MARGIN
    straight = jnp.linspace(0.0, 1.0, 201)[:, None] * (GOAL[0] - START[0]) + START[0]
    assert float(dk.collision.clearance(robot, geom, straight, world).min()) < 0
