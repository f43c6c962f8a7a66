"""Collision-aware IK (``dk.ik.solve(..., avoid=dk.ik.Avoid(...))``).

A small arm of capsules for the term's Jacobian (against finite differences of its residual), its
solutions (every success clear by the margin, re-checked by forward kinematics and the distance
functions) and the failures that must be reported; the Panda of example-robot-data among a table,
a shelf and spheres, every success re-checked by coal on the real meshes (marked slow).
"""

from __future__ import annotations

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import BAXTER, ERD, HANDS
from _paths import EXPERIMENTS
from _reference import robot_poses
from _shapes import CAPSULE_ARM as ARM

import diffkin as dk
from diffkin import _rigid as rg
from diffkin.collision import Box, Plane, Sphere, World
from diffkin.ik._problem import Problem
from diffkin.ik._terms.avoid import BAND, AvoidTerm


def _box(center, half, angle=0.0):
    T = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = center
    return Box(T, np.asarray(half, float))


@pytest.fixture(scope="module")
def arm():
    robot = dk.load_robot(ARM)
    geom = dk.collision.load(ARM, robot)
    world = World(
        Sphere(np.array([[0.35, 0.25, 0.55]]), np.array([0.08])),
        _box([0.45, -0.1, 0.25], [0.12, 0.08, 0.1], 0.4),
        Plane(np.array([0.0, 0.0, 1.0]), -0.1),
    )
    return robot, geom, world


def test_rows_match_finite_differences(arm):
    """The term's residual rows and ``J = d(-r)/dq`` against central differences (float64), at 40
    random configurations with a margin wide enough that self, sphere, box and plane rows are active."""
    robot, geom, world = arm
    avoid = dk.ik.Avoid(geom, world, margin=0.25)
    term = AvoidTerm.of(avoid)
    dof = robot.dof
    lower, upper = np.asarray(robot.lower), np.asarray(robot.upper)
    problem = Problem(
        robot, (term,), (avoid.cast(jnp.float64),), lower, upper, np.zeros(dof, bool), False, (False,) * dof,
        jnp.zeros((dof, 1)), rg.IDENTITY, False,
    )  # fmt: skip
    x = np.random.default_rng(3).uniform(lower, upper, (40, dof)).T
    ev = jax.jit(problem.evaluate)(x)
    r = jax.jit(lambda x: problem.evaluate(x, jacobian=False).r)
    assert ev.r.shape == (len(geom.pairs) + len(geom.shape_names), 40)
    active = np.asarray(ev.r) > 0
    assert active[: len(geom.pairs)].any() and active[len(geom.pairs) :].mean() > 0.3
    h = 1e-6
    for c in range(dof):
        e = np.zeros((dof, 1))
        e[c] = h
        fd = -(np.asarray(r(x + e)) - np.asarray(r(x - e))) / (2 * h)
        np.testing.assert_allclose(np.asarray(ev.J[:, c]), fd, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(ev.cost), np.sum(np.asarray(ev.r) ** 2, axis=0), rtol=1e-12)


def test_solutions_are_clear_on_target_and_a_target_inside_an_obstacle_fails(arm):
    """60 hand targets from random configurations that clear everything by the margin + band, and one
    inside the box, each solved with and without ``avoid`` (float64; one test, so that one process
    compiles both solvers): every success clear and on target, the one inside failing with finite
    values, and without ``avoid`` some solved through an obstacle. The worlds are per target: a 62nd
    target, inside the box again, has a world of its own whose box is elsewhere, and is solved."""
    robot, geom, world = arm
    margin = 0.02
    rng = np.random.default_rng(0)
    q = rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (600, robot.dof))
    clear = np.asarray(dk.collision.clearance(robot, geom, q, world))
    q = q[clear > margin + BAND][:60]
    targets = np.asarray(dk.fk(robot, q, "hand"))[:, :3, 3]
    inside = np.array([[0.45, -0.1, 0.25]])  # the box's centre
    targets = np.concatenate([targets, inside, inside])
    sphere, box, floor = world.spheres, world.boxes, world.planes
    poses = np.repeat(np.asarray(box.pose)[None], 62, axis=0)
    poses[-1, :, :3, 3] += [0.0, 0.0, 2.0]  # the last target's box, 2 m higher
    per_target = World(
        Sphere(np.broadcast_to(sphere.center, (62, 1, 3)), np.broadcast_to(sphere.radius, (62, 1))),
        Box(poses, np.broadcast_to(box.half_extents, (62, 1, 3))),
        Plane(floor.normal[0], floor.offset[0]),
    )
    res = dk.ik.solve(robot, {"hand": targets}, avoid=dk.ik.Avoid(geom, per_target, margin=margin))
    plain = dk.ik.solve(robot, {"hand": targets})

    ok = np.asarray(res.success[:-2])
    assert ok.mean() >= 0.95
    q = np.asarray(res.q)
    clearance = np.asarray(dk.collision.clearance(robot, geom, q, per_target))
    np.testing.assert_allclose(np.asarray(res.clearance), clearance, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        clearance[:-1], np.asarray(dk.collision.clearance(robot, geom, q[:-1], world)), atol=1e-15
    )
    assert np.all(clearance[:-2][ok] >= margin)
    reached = np.stack([robot_poses(robot, qk)[robot.frame_names.index("hand"), :3, 3] for qk in q])
    assert np.all(np.linalg.norm(reached - targets, axis=-1)[:-2][ok] <= 1e-5)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    assert np.all((q >= lo) & (q <= hi))
    # without avoid, some of the same targets (the one inside the box too) are solved through an obstacle
    plain_clear = np.asarray(dk.collision.clearance(robot, geom, np.asarray(plain.q), world))
    assert np.sum(np.asarray(plain.success) & (plain_clear < margin)) >= 2

    # the target inside the box: reachable (through the box), not solved with avoid, finite
    assert bool(plain.success[-2])
    assert not bool(res.success[-2])
    for field in (res.q[-2], res.pos_err[-2], res.clearance[-2]):
        assert np.all(np.isfinite(np.asarray(field)))
    assert float(res.clearance[-2]) < margin
    # the same point with its own world, whose box is elsewhere: solved, clear of that world
    assert bool(res.success[-1]) and clearance[-1] >= margin
    with pytest.raises(ValueError, match="Avoid.world: its problem axes"):
        dk.ik.solve(robot, {"hand": targets[:-1]}, avoid=dk.ik.Avoid(geom, per_target, margin=margin))


def test_the_clearance_has_the_derivative_of_measuring_it_at_the_solution(arm):
    """``IKResult.clearance`` is measured inside the search (one loop serves the first round's check and
    the final value) and given the derivative of measuring it at ``q``: along ``q``'s implicit tangent,
    the central difference of the clearance (float64)."""
    robot, geom, world = arm
    rng = np.random.default_rng(2)
    q = rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (200, robot.dof))
    q = q[np.asarray(dk.collision.clearance(robot, geom, q, world)) > 0.05][:4]
    targets = jnp.asarray(np.asarray(dk.fk(robot, q, "hand"))[:, :3, 3])
    avoid = dk.ik.Avoid(geom, world, margin=0.01)

    def solved(p):
        res = dk.ik.solve(robot, {"hand": p}, avoid=avoid)
        return res.q, res.clearance, res.success

    (q, c, ok), (dq, dc, _) = jax.jvp(solved, (targets,), (jnp.ones_like(targets),))
    assert np.all(np.asarray(ok))
    eps = 1e-6
    ahead, behind = (dk.collision.clearance(robot, geom, q + s * eps * dq, world) for s in (1, -1))
    np.testing.assert_allclose(np.asarray(dc), np.asarray((ahead - behind) / (2 * eps)), rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(np.asarray(c), np.asarray(dk.collision.clearance(robot, geom, q, world)), atol=1e-12)


def test_floating_locked_secondary_with_avoid(arm):
    """A floating root solved with ``avoid``, a locked joint and the rest objective: successes clear,
    on target, the locked joint unmoved (float32)."""
    robot = dk.load_robot(ARM, floating=True)
    geom = dk.collision.load(ARM, robot)
    _, _, world = arm
    rng = np.random.default_rng(1)
    q = rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (200, robot.dof))
    clear = np.asarray(dk.collision.clearance(robot, geom, q, world))
    q = q[clear > 0.05][:16]
    T = np.asarray(dk.fk(robot, q, "hand"))
    res = dk.ik.solve(
        robot,
        {"hand": jnp.asarray(T, jnp.float32)},
        avoid=dk.ik.Avoid(geom, world, margin=0.01),
        solve_base=True,
        locked={"j1": jnp.asarray(q[:, 0], jnp.float32)},
        rest=jnp.zeros(robot.dof, jnp.float32),
    )
    ok = np.asarray(res.success)
    assert ok.mean() >= 0.9
    base = np.asarray(res.base, np.float64)
    clearance = np.asarray(dk.collision.clearance(robot, geom, np.asarray(res.q, np.float64), world, base=base))
    assert np.all(clearance[ok] >= 0.01 - 1e-6)
    reached = np.asarray(dk.fk(robot, np.asarray(res.q, np.float64), "hand", base=base))
    assert np.all(np.linalg.norm(reached[:, :3, 3] - T[:, :3, 3], axis=-1)[ok] <= 1e-5)
    np.testing.assert_allclose(np.asarray(res.q)[:, 0], q[:, 0], atol=1e-6)


def test_path_with_avoid(arm):
    """``solve_path(..., avoid=)``: 6 paths of 8 hand positions along joint-space lines between clear
    configurations (every state on the line clear by 5 cm): every successful waypoint is clear by the
    margin (recomputed), on target and within the step; ``clearance`` is the exact one."""
    robot, geom, world = arm
    margin, T = 0.01, 8
    rng = np.random.default_rng(5)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    s = np.linspace(0, 1, T)[:, None]
    paths = []
    while len(paths) < 6:
        qa, qb = rng.uniform(lo, hi, (2, robot.dof))
        line = qa + s * (qb - qa)
        if np.linalg.norm(qb - qa) < 1.5 and np.all(
            np.asarray(dk.collision.clearance(robot, geom, line, world)) > 0.05
        ):
            paths.append(line)
    q_path = np.stack(paths)  # (6, T, dof)
    targets = np.asarray(dk.fk(robot, q_path, "hand"))[..., :3, 3]
    res = dk.ik.solve_path(
        robot, {"hand": targets}, q0=q_path[:, 0], max_step=0.5, avoid=dk.ik.Avoid(geom, world, margin=margin)
    )
    ok = np.asarray(res.success)
    assert ok.mean() >= 0.9 and res.clearance.shape == (6, T)
    q = np.asarray(res.q)
    clearance = np.asarray(dk.collision.clearance(robot, geom, q, world))
    np.testing.assert_allclose(np.asarray(res.clearance), clearance, rtol=0, atol=1e-12)
    assert np.all(clearance[ok] >= margin)
    reached = np.asarray(dk.fk(robot, q, "hand"))[..., :3, 3]
    assert np.all(np.linalg.norm(reached - targets, axis=-1)[ok] <= 1e-5)
    assert np.all(np.abs(np.diff(q, axis=1)) <= 0.5 + 1e-12)


def test_bad_avoid_arguments(arm):
    robot, geom, world = arm
    target = {"hand": np.array([0.3, 0.0, 0.5])}
    with pytest.raises(ValueError, match="Avoid.margin"):
        dk.ik.Avoid(geom, world, margin=-0.1)
    with pytest.raises(ValueError, match="Avoid.margin"):
        dk.ik.Avoid(geom, world, margin=np.zeros(2))
    with pytest.raises(TypeError, match="Avoid.world"):
        dk.ik.Avoid(geom, [Sphere(np.zeros(3), 0.1)])
    with pytest.raises(TypeError, match="Avoid.geom"):
        dk.ik.Avoid(world)
    with pytest.raises(ValueError, match="nothing to keep clear"):
        dk.ik.Avoid(geom, None, self_collision=False)
    with pytest.raises(ValueError, match="nothing to keep clear"):
        dk.ik.Avoid(geom, World(), self_collision=False)
    empty = dk.ik.Avoid(geom, World())  # no obstacles: the self pairs only
    q = np.array([0.0, 2.4, 2.4])
    assert float(empty.clearance(robot, q)) == float(np.min(dk.collision.self_distances(robot, geom, q)))
    with pytest.raises(TypeError, match="avoid"):
        dk.ik.solve(robot, target, avoid=geom)
    chain = dk.load_urdf(ARM, "hand")
    with pytest.raises(ValueError, match="avoid: only for a Robot"):
        dk.ik.solve(chain, target["hand"], avoid=dk.ik.Avoid(geom, world))
    other = dk.load_robot(
        ARM.replace('name="l3"', 'name="l3x"')
        .replace('<child link="l3"/>', '<child link="l3x"/>')
        .replace('<parent link="l3"/>', '<parent link="l3x"/>')
    )
    with pytest.raises(ValueError, match="geom"):
        dk.ik.solve(other, target, avoid=dk.ik.Avoid(dk.collision.load(ARM, robot).replace_pairs([]), world))


_P = np.array([0.3, 0.0, 0.5])
_GRID = {"voxel_size": 0.1, "key": jax.random.key(0)}
#: Every function that takes ``avoid=dk.ik.Avoid(...)`` of a robot, called with ``(robot, avoid)``.
_TAKING_AVOID = {
    "ik.solve": lambda r, a: dk.ik.solve(r, {"hand": _P}, avoid=a),
    "ik.solve_path": lambda r, a: dk.ik.solve_path(r, {"hand": np.stack([_P, _P])}, avoid=a),
    "ik.step": lambda r, a: dk.ik.step(r, np.zeros(r.dof), {"hand": _P}, dt=0.1, avoid=a),
    "traj.optimize": lambda r, a: dk.traj.optimize(r, np.zeros(r.dof), np.full(r.dof, 0.1), avoid=a),
    "workspace.reachability": lambda r, a: dk.workspace.reachability((r, "hand"), 8, avoid=a, **_GRID),
    "workspace.capability": lambda r, a: dk.workspace.capability((r, "hand"), 8, avoid=a, **_GRID),
}


@pytest.mark.parametrize("name", sorted(_TAKING_AVOID))
def test_every_avoid_keyword_is_checked_alike(arm, name):
    """One host-side check of ``avoid=`` (``diffkin.ik.interface.check_avoid``): IK, paths, velocity IK,
    trajectories and the workspace maps raise the same errors for a value that is not an ``Avoid`` and for
    the geometry of another robot, before anything is compiled."""
    robot, geom, world = arm
    other = dk.load_robot(
        ARM.replace('name="l3"', 'name="l3x"')
        .replace('<child link="l3"/>', '<child link="l3x"/>')
        .replace('<parent link="l3"/>', '<parent link="l3x"/>')
    )
    call = _TAKING_AVOID[name]
    with pytest.raises(TypeError, match=r"^avoid: expected a dk\.ik\.Avoid\(geom, world, margin\), got World$"):
        call(robot, world)
    with pytest.raises(ValueError, match="^geom: its shape on 'l3' is not on a frame of robot"):
        call(other, dk.ik.Avoid(geom, world))


def test_reachability_counts_only_clear_samples(arm):
    """A map with ``avoid`` against a brute-force count of the same samples (one chunk: key
    ``fold_in(key, 0)``) that clear the obstacles and the robot itself by the margin, float64."""
    robot, geom, world = arm
    key, n = jax.random.key(4), 3000
    avoid = dk.ik.Avoid(geom, world, margin=0.02)
    kw = dict(key=key, voxel_size=0.1, bounds=[[-1.3, -1.3, -0.9], [1.3, 1.3, 1.7]], chunk=n, dtype=jnp.float64)
    clear_map = dk.workspace.reachability((robot, "hand"), n, avoid=avoid, **kw)
    full_map = dk.workspace.reachability((robot, "hand"), n, **kw)
    q = np.asarray(dk.workspace.sample_configs(robot.chain("hand"), n, jax.random.fold_in(key, 0), dtype=jnp.float64))
    clear = np.asarray(dk.collision.clearance(robot, geom, q, world)) >= 0.02
    p = np.asarray(dk.fk(robot, q, "hand"))[:, :3, 3]
    cells = np.floor((p - clear_map.origin) * (1.0 / clear_map.voxel_size)).astype(int)
    expected = np.zeros(clear_map.counts.shape, np.int64)
    np.add.at(expected, tuple(cells[clear].T), 1)
    np.testing.assert_array_equal(clear_map.counts, expected)
    assert 0.05 < 1 - clear.mean() < 0.95  # the obstacles remove some samples, not all
    assert full_map.counts.sum() == n and clear_map.n_outside == n - clear.sum()
    assert np.all(clear_map.dexterity <= full_map.dexterity)
    with pytest.raises(ValueError, match="avoid: needs a"):
        dk.workspace.reachability(robot.chain("hand"), n, avoid=avoid, key=key)


@pytest.mark.slow
def test_panda_among_obstacles_against_coal_on_the_real_meshes():
    """The Panda of example-robot-data (fitted capsules, finger boxes, SRDF pairs) among a table, a
    shelf, spheres and a floor (``experiments/bench_ik_collision.py``'s scene), float32: 39 hand poses
    from configurations clear by 3 cm all solved at margin 1 cm, and at margin 0; every success
    re-checked in float64 (pose within 1e-5 m / 1e-4 rad) and by coal on the URDF's real meshes (no
    contact); a pose inside the table fails with finite values."""
    for module in ("pinocchio", "coal", "trimesh"):
        pytest.importorskip(module)
    sys.path.insert(0, EXPERIMENTS)
    import bench_ik_collision as bench

    robot, urdf, srdf = bench.panda()
    geom = dk.collision.load(urdf, robot, srdf=srdf)
    scene = bench.scene()
    T = bench.targets_of(robot, geom, bench.world_of(scene, jnp.float64), 39, np.random.default_rng(2))
    inside = T[:1].copy()
    inside[0, :3, 3] = [0.65, 0.0, 0.0]  # the table's centre
    T = np.concatenate([T, inside])
    real = bench.RealGeometry(urdf, robot, geom, scene)
    world = bench.world_of(scene, jnp.float32)
    for margin in (0.01, 0.0):
        res = dk.ik.solve(robot, {bench.EE: jnp.asarray(T, jnp.float32)}, avoid=dk.ik.Avoid(geom, world, margin=margin))
        ok = np.asarray(res.success)
        assert ok[:-1].all() and not ok[-1], margin
        assert np.all(np.isfinite(np.asarray(res.q))) and np.isfinite(float(res.clearance[-1]))
        q = np.asarray(res.q, np.float64)
        judged = bench.judge(robot, real, q[:-1], T[:-1])
        assert judged["tight"] == 1.0 and judged["in collision"] == 0.0, (margin, judged)
        clearance = np.asarray(dk.collision.clearance(robot, geom, q[:-1], bench.world_of(scene, jnp.float64)))
        assert np.all(clearance >= margin - 1e-6)


@pytest.mark.slow
def test_baxter_two_hands_clear_of_itself_against_coal():
    """Baxter of example-robot-data (41 fitted shapes, the SRDF's self pairs), both grippers at the
    poses of configurations whose shapes clear each other by 3 cm, self-collision only, float32: every
    target solved at margin 1 cm; at margin 0 too; every success re-checked in float64 (both hands
    within 1e-5 m / 1e-4 rad) and by coal on the URDF's real collision geometry (no self contact)."""
    for module in ("pinocchio", "coal", "trimesh"):
        pytest.importorskip(module)
    sys.path.insert(0, EXPERIMENTS)
    import bench_ik_collision as bench

    srdf = os.path.join(ERD, "baxter_description", "srdf", "baxter_manipulation.srdf")
    robot = dk.load_robot(BAXTER)
    geom = dk.collision.load(BAXTER, robot, srdf=srdf)
    real = bench.RealGeometry(BAXTER, robot, geom, None)
    rng = np.random.default_rng(5)
    q = rng.uniform(np.asarray(robot.lower), np.asarray(robot.upper), (600, robot.dof))
    q = q[np.asarray(dk.collision.self_distances(robot, geom, q)).min(axis=-1) >= 0.03][:16]
    assert len(q) == 16
    T = np.asarray(dk.fk(robot, q, HANDS))  # (16, 2, 4, 4)
    targets = {h: jnp.asarray(T[:, k], jnp.float32) for k, h in enumerate(HANDS)}
    for margin in (0.01, 0.0):  # one compiled solver: the margin is an array of the Avoid
        res = dk.ik.solve(robot, targets, avoid=dk.ik.Avoid(geom, None, margin=jnp.float32(margin)))
        ok = np.asarray(res.success)
        assert ok.all(), margin
        solved = np.asarray(res.q, np.float64)
        reached = np.asarray(dk.fk(robot, solved, HANDS))
        pos = np.linalg.norm(reached[..., :3, 3] - T[..., :3, 3], axis=-1)
        rot = np.linalg.norm(
            np.asarray(dk.se3.so3_log(np.swapaxes(T[..., :3, :3], -1, -2) @ reached[..., :3, :3])), axis=-1
        )
        assert pos.max() <= 1e-5 and rot.max() <= 1e-4, (margin, pos.max(), rot.max())
        assert not real.colliding(solved).any(), margin
        clearance = np.asarray(dk.collision.self_distances(robot, geom, solved)).min(axis=-1)
        assert np.all(clearance >= margin - 1e-6), margin


def test_self_motion_samples_in_collision_are_not_valid():
    """``srs.sample_self_motion(..., avoid=Avoid, model=robot)`` on the iiwa14 with a capsule per link
    (``experiments/iiwa_self_motion.py``) beside a ball on its elbow circle: ``valid`` is the closed
    form's validity and a clearance of at least the margin, recomputed by ``dk.collision.clearance``.
    The pair ``avoid=(robot, Avoid)`` of 0.1.0 gives the same samples, with a DeprecationWarning."""
    sys.path.insert(0, EXPERIMENTS)
    from iiwa_self_motion import iiwa14_with_capsules

    urdf = iiwa14_with_capsules()
    robot = dk.load_robot(urdf)
    geom = dk.collision.load(urdf, robot)
    home = np.asarray(dk.collision.self_distances(robot, geom, np.zeros(7)))
    geom = geom.replace_pairs([p for p, d in zip(geom.pair_list, home, strict=True) if d > 0])
    arm = dk.srs.iiwa14()
    q_target = np.array([0.4, 0.7, -0.3, -1.1, 0.6, 0.9, -0.2])
    target = np.asarray(dk.fk(robot, q_target, "iiwa14_link_ee"))
    elbow = np.asarray(dk.fk(robot, q_target, "iiwa14_link_4"))[:3, 3]
    world = World(Sphere(elbow[None] + np.array([[0.0, 0.0, 0.12]]), np.array([0.08])))
    avoid = dk.ik.Avoid(geom, world, margin=0.02)
    q, valid = dk.srs.sample_self_motion(arm, target, 300, avoid=avoid, model=robot)
    q_all, valid_all = dk.srs.sample_self_motion(arm, target, 300)
    np.testing.assert_array_equal(np.asarray(q), np.asarray(q_all))
    clear = np.asarray(dk.collision.clearance(robot, geom, np.asarray(q), world)) >= 0.02
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(valid_all) & clear)
    assert 0.05 < np.mean(~clear[np.asarray(valid_all)]) < 0.95
    with pytest.warns(DeprecationWarning, match=r"avoid=\(robot, Avoid\)\) is deprecated"):
        q_pair, valid_pair = dk.srs.sample_self_motion(arm, target, 300, avoid=(robot, avoid))
    np.testing.assert_array_equal(np.asarray(q_pair), np.asarray(q))
    np.testing.assert_array_equal(np.asarray(valid_pair), np.asarray(valid))
    two_joints = dk.load_robot(ARM)
    with pytest.raises(ValueError, match="^model: expected a robot with the arm's 7 joints"):
        dk.srs.sample_self_motion(arm, target, 3, avoid=dk.ik.Avoid(*_arm_geometry()), model=two_joints)
    with pytest.raises(ValueError, match="^avoid: needs model=robot"):
        dk.srs.sample_self_motion(arm, target, 3, avoid=avoid)
    with pytest.raises(ValueError, match="^model: only needed with avoid"):
        dk.srs.sample_self_motion(arm, target, 3, model=robot)
    with pytest.raises(TypeError, match=r"^avoid: expected a dk\.ik\.Avoid\(geom, world, margin\), got World$"):
        dk.srs.sample_self_motion(arm, target, 3, avoid=world, model=robot)
    with pytest.raises(TypeError, match="^model: expected a diffkin.Robot"):
        dk.srs.sample_self_motion(arm, target, 3, avoid=avoid, model=robot.chain("iiwa14_link_ee"))


def _arm_geometry():
    robot = dk.load_robot(ARM)
    return dk.collision.load(ARM, robot), World(Sphere(np.zeros((1, 3)), np.ones(1)))


def _random_boxes(rng, n, spread, onto=None):
    """``n`` boxes, randomly turned, centred within ``spread`` of the origin; ``onto`` ``(k, 3)``: the first
    ``k`` centred there instead."""
    T = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        w = rng.normal(size=3)
        T[k, :3, :3] = _rotation(w)
    T[:, :3, 3] = rng.uniform(-spread, spread, (n, 3))
    if onto is not None:
        T[: len(onto), :3, 3] = onto
    return Box(T, rng.uniform(0.03, 0.2, (n, 3)))


def _rotation(w):
    """Rodrigues: the rotation by the rotation vector ``w``."""
    angle = np.linalg.norm(w)
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_near_motion_takes_a_reach_per_configuration_and_any_share():
    """:func:`diffkin.collision._near.near_motions` with a reach per configuration (the batches' last axis,
    as a trajectory's descent and certificate give it; ``-inf``: nothing measured there) and a share other
    than the default: exact below each pair's own reach, at least it elsewhere, equal to the scalar reach's
    results where the reaches agree, the general pairs (GJK) and a closed form's alike."""
    from diffkin.collision import Capsule, Convex
    from diffkin.collision._distance import motion
    from diffkin.collision._near import near_motions

    rng = np.random.default_rng(11)
    n, configs = 40, 6  # pairs (n, configs): each configuration's shapes the same, the reach its own
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    ends = rng.uniform(-1.0, 1.0, (n, 1, 3)) + np.zeros((1, configs, 3))
    capsules = Capsule(ends, ends + rng.uniform(-0.2, 0.2, (n, configs, 3)), np.full((n, configs), 0.05))
    boxes = _random_boxes(rng, n * configs, 1.0)
    boxes = jax.tree.map(lambda x: x.reshape((n, configs) + x.shape[1:]), boxes)
    hulls = Convex(boxes.pose, rng.uniform(0.5, 1.0, (n, configs, 8, 1)) * corners * boxes.half_extents[..., None, :])
    pairs = [(capsules, boxes), (capsules, hulls)]
    reach = jnp.asarray([0.0, 0.05, 0.3, 1.0, 3.0, -np.inf])  # (configs,)
    for share in (4, 64):
        for (a, b), (d, Wa, Wb), (d_all, Wa_all, Wb_all) in zip(
            pairs, near_motions(pairs, reach, share), near_motions(pairs, jnp.inf, share), strict=True
        ):
            d, d_all = np.asarray(d), np.asarray(d_all)
            d_exact = np.asarray(motion(a, b)[0])
            close = d_exact < np.asarray(reach)
            np.testing.assert_allclose(d[close], d_all[close], rtol=0, atol=1e-10)
            assert np.all(d[~close] >= np.broadcast_to(reach, d.shape)[~close])
            assert not np.any(np.asarray(Wa)[~close]) and not np.any(np.asarray(Wb)[~close])
            np.testing.assert_allclose(np.asarray(Wa)[close], np.asarray(Wa_all)[close], rtol=0, atol=1e-8)
            np.testing.assert_allclose(np.asarray(Wb)[close], np.asarray(Wb_all)[close], rtol=0, atol=1e-8)
            assert close[:, 0].sum() < close[:, -2].sum() and not close[:, -1].any()


def test_near_motion_is_exact_where_the_reach_is():
    """The term's broad phase (:func:`diffkin.collision._near.near_motions`): where the exact distance is
    below the reach, the distance and the wrenches are :func:`motion`'s; elsewhere the distance is at
    least the reach and the wrenches are zero (a pair whose cheap bound is below the reach but GJK's
    bound is not stops early). Box-box and
    capsule-box alone (their closed forms, gathered per kind), and joined with the general pairs
    capsule-cylinder and polytope-box in one GJK batch (apart: exact to GJK's tolerance; overlapping:
    never shallower than a closed form, in contact where GJK alone is), with no pair near (no step), few
    (one step) and most (several)."""
    from diffkin.collision import Capsule, Convex, Cylinder
    from diffkin.collision._distance import GENERAL, lower_bound, motion
    from diffkin.collision._near import NEAR_SHARE, near_motions

    near = jax.jit(near_motions)
    rng = np.random.default_rng(7)
    n, reach, spread = 200, 0.05, 8.0
    budget = -(-n // NEAR_SHARE)  # pairs per step of the boxes
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    # far apart, but the first `count` pairs of each kind placed near each other: none, a few, most
    for count, steps in ((0, range(0, 1)), (max(1, budget // 2), range(1, 2)), (3 * n // 4, range(2, NEAR_SHARE + 1))):

        def onto(centres, count=count):  # 0.1-0.2 m from the centres: touching, overlapping or near
            offsets = rng.normal(size=(count, 3))
            return (
                centres[:count] + offsets * rng.uniform(0.1, 0.2, (count, 1)) / np.linalg.norm(offsets, axis=1)[:, None]
            )

        ends = rng.uniform(-spread, spread, (n, 3))
        capsules = Capsule(ends, ends + rng.uniform(-0.2, 0.2, (n, 3)), rng.uniform(0.02, 0.1, n))
        cylinders = _random_boxes(rng, n, spread, onto(ends))
        cylinders = Cylinder(cylinders.pose, cylinders.half_extents[:, 0], cylinders.half_extents[:, 1])
        hulls = _random_boxes(rng, n, spread)
        hulls = Convex(hulls.pose, rng.uniform(0.5, 1.0, (n, 8, 1)) * corners * hulls.half_extents[:, None])
        boxes = _random_boxes(rng, n, spread)
        closed = [
            (capsules, _random_boxes(rng, n, spread, onto(ends))),
            (boxes, _random_boxes(rng, n, spread, onto(boxes.pose[:, :3, 3]))),
        ]
        general = [(capsules, cylinders), (hulls, _random_boxes(rng, n, spread, onto(hulls.pose[:, :3, 3])))]
        for pairs, joined in ((closed, False), (closed + general, True)):
            for (a, b), (d, Wa, Wb) in zip(pairs, near(pairs, reach), strict=True):
                d, d_exact, Wa_exact, Wb_exact = (np.asarray(x) for x in (d, *motion(a, b)))
                close, apart = d_exact < reach, d_exact > 0
                measured = np.asarray(lower_bound(a, b)) < reach  # exact there, zero wrenches elsewhere
                if not joined:  # gathered alone: the steps it took
                    assert -(-measured.sum() // budget) in steps and (close.sum() > 0) == (steps.start > 0), count
                # GJK: the distance to its tolerance, the normal (the wrenches) to about its square root
                tol = 1e-10 if joined else 1e-14
                np.testing.assert_allclose(d[close & apart], d_exact[close & apart], rtol=0, atol=tol)
                assert np.all(d[~close] >= reach)
                if (type(a), type(b)) in GENERAL:  # overlapping, `motion` is GJK too: two estimates of the depth
                    assert np.all(d[close & ~apart] < 0)
                else:  # overlapping, never shallower than the closed form
                    assert np.all(d[close & ~apart] <= d_exact[close & ~apart] + tol)
                # (an overlapping GJK pair's witnesses are support points, which may tie: apart ones only)
                same = close & apart if joined else close
                for W, exact in ((Wa, Wa_exact), (Wb, Wb_exact)):
                    np.testing.assert_allclose(
                        np.asarray(W)[same], exact[same], rtol=1e-12, atol=1e-5 if joined else 1e-12
                    )
                    assert np.all(np.asarray(W)[d >= reach] == 0)
