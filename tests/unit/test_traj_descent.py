"""dk.traj's descent (:mod:`diffkin.traj._descent`): where it stops.

A problem stops once its curves have converged (a step lowers the cost by less than ``CONVERGED`` of
it), not at the iteration cap: more iterations allowed change nothing. Without obstacles the residual
is the control polygon's weighted differences, linear in the free control points, so the curve it
stops at is checked against numpy's least squares; among obstacles, it is pushed away from them. A descent
resumed from its state runs the iterations of one uninterrupted.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import planar_capsule_arm

import diffkin as dk
from diffkin.collision import Sphere, World
from diffkin.traj import _rows, _spline
from diffkin.traj._descent import W_BEND, W_LENGTH, Curves

URDF = planar_capsule_arm()
ROBOT = dk.load_robot(URDF)
GEOM = dk.collision.load(URDF, ROBOT)
LOCKED = (False, False)
FREE = 6
START, GOAL = jnp.array([[-0.6, 0.0]], jnp.float32), jnp.array([[0.6, 0.0]], jnp.float32)
# a zigzag between the two: far from the smoothest curve
X = jnp.asarray(np.stack([np.linspace(-0.5, 0.5, FREE), 0.4 * (-1.0) ** np.arange(FREE)], axis=-1)[None], jnp.float32)


def _curves(avoid) -> Curves:
    lower, upper = jnp.asarray(ROBOT.lower, jnp.float32), jnp.asarray(ROBOT.upper, jnp.float32)
    return Curves(ROBOT, START, GOAL, lower, upper, LOCKED, None, avoid, None, 1)


def _descend(curves: Curves, iters: int) -> np.ndarray:
    return np.asarray(jax.jit(lambda X: curves.descend(curves.start(X), iters).X)(X))


def _smoothest() -> np.ndarray:
    """``(FREE, dof)``: the free control points of least weighted first and second differences (float64)."""
    N = FREE + 2 * _spline.ENDS
    D = np.concatenate([W_LENGTH * np.diff(np.eye(N), axis=0), W_BEND * np.diff(np.eye(N), n=2, axis=0)])
    free = slice(_spline.ENDS, _spline.ENDS + FREE)
    ends = np.asarray(_spline.control_points(START, jnp.zeros((1, FREE, 2)), GOAL)[0], np.float64)
    return np.linalg.lstsq(D[:, free], -(D @ ends), rcond=None)[0]


def test_without_obstacles_it_stops_converged_at_the_smoothest_curve():
    curves = _curves(None)
    out = _descend(curves, 30)
    np.testing.assert_array_equal(out, _descend(curves, 300))  # stopped before the cap
    np.testing.assert_allclose(out[0], _smoothest(), atol=1e-3)


def _smallest(curves: Curves, X) -> float:
    """The smallest distance at the descent's samples of the curve ``X`` ``(1, FREE, dof)``."""
    P = curves.control(jnp.asarray(X))
    q = jnp.einsum("qk,ckj->cqj", curves.samples(P.shape[1], P.dtype), P)
    d_self, d_world = _rows.distances(ROBOT, curves.avoid, LOCKED, None, 1, q)
    return float(jnp.min(_rows.smallest(d_self, d_world, q.shape[:2], P.dtype)))


@pytest.mark.parametrize("radius", [0.3, 0.33])
def test_among_obstacles_it_stops_converged_clearer(radius):
    # a sphere over the arm, which swings upright through the middle of the motion
    world = World(Sphere(jnp.array([[(0.0, 0.0, 1.3)]], jnp.float32), jnp.array([[radius]], jnp.float32)))
    curves = _curves(dk.ik.Avoid(GEOM, world, 0.01).cast(jnp.float32).flat((1,)))
    out = _descend(curves, 30)
    np.testing.assert_array_equal(out, _descend(curves, 300))
    assert _smallest(curves, out) > max(_smallest(curves, X), 0.0) + 0.01


def test_a_descent_goes_on_from_where_it_stopped():
    # dk.traj certifies its curves at checks and resumes the descent after a failed one: the iterations in
    # two calls are those of one
    world = World(Sphere(jnp.array([[(0.0, 0.0, 1.3)]], jnp.float32), jnp.array([[0.3]], jnp.float32)))
    curves = _curves(dk.ik.Avoid(GEOM, world, 0.01).cast(jnp.float32).flat((1,)))

    @jax.jit
    def both(X):
        whole = curves.descend(curves.start(X), 30)
        parts = curves.descend(curves.descend(curves.start(X), 4), 30)
        return whole, parts

    whole, parts = both(X)
    assert 4 < int(whole.it) <= 31
    for a, b in zip(whole, parts, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
