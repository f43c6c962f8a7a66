"""dk.traj.optimize with a pose goal among obstacles: the goal solved by collision-aware IK (the arm of
tests/unit/test_traj.py; its own module: that IK's program takes long to compile)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import diffkin as dk
from diffkin.collision import Sphere, World

URDF = """<robot name="arm">
  <link name="base"><collision><geometry><box size="0.4 0.4 0.1"/></geometry></collision></link>
  <link name="upper"><collision><origin xyz="0 0 0.25"/>
    <geometry><capsule radius="0.05" length="0.5"/></geometry></collision></link>
  <link name="lower"><collision><origin xyz="0 0 0.2"/>
    <geometry><capsule radius="0.04" length="0.4"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="upper"/><child link="lower"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
</robot>"""
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
