"""dk.traj.optimize with a pose goal among obstacles: the goal solved by collision-aware IK (the arm of
tests/unit/test_traj.py; its own module: that IK's program takes long to compile)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from _shapes import planar_capsule_arm

import diffkin as dk
from diffkin.collision import Sphere, World

URDF = planar_capsule_arm()
ROBOT = dk.load_robot(URDF)
GEOM = dk.collision.load(URDF, ROBOT)
MARGIN = 0.01


@jax.jit
def _plan_pose(q_start, target, world):
    avoid = dk.ik.Avoid(GEOM, world, MARGIN)
    return dk.traj.optimize(ROBOT, q_start, {"lower": target}, avoid=avoid, knots=8, num_seeds=2, max_iters=15)


def test_pose_goal_among_obstacles():
    # two problems, each in its own world: the goal pose reached, the motion clear (dense sampling)
    q_goal = jnp.array([[0.9, -0.6], [-0.7, 0.5]])
    T = dk.fk(ROBOT, q_goal, "lower")
    far = (5.0, 0.0, 5.0)
    world = World(Sphere(jnp.array([[(0.0, 0.0, 1.0)], [far]]), jnp.array([[0.1], [0.1]])))
    traj = _plan_pose(jnp.array([[-0.5, 0.3], [0.4, 0.0]]), T, world)
    assert np.asarray(traj.goal_ok).all() and np.asarray(traj.success).all()
    reached = dk.fk(ROBOT, traj.at(traj.duration), "lower")
    np.testing.assert_allclose(np.asarray(reached[..., :3, 3]), np.asarray(T[..., :3, 3]), atol=2e-5)
    q = traj.at(jnp.linspace(0.0, 1.0, 1001)[:, None] * traj.duration)
    sampled = np.asarray(dk.collision.clearance(ROBOT, GEOM, q, world)).min(axis=0)
    assert np.all(np.asarray(traj.clearance) <= sampled + 1e-6) and np.all(sampled >= MARGIN)
