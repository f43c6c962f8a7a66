"""dk.ik.step takes the file's velocity limits by default: the Panda of example-robot-data (with its finger
and the finger's mimic) stepping towards targets far out of reach never moves a joint faster than its
URDF ``<limit velocity=>`` (float32 and float64), a velocity given replaces them, and the same Panda
without velocity limits in its file moves unconstrained.

One compiled step per dtype and kind of call (module level).
"""

from __future__ import annotations

import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import ERD
from _reference import rodrigues

import diffkin as dk

PANDA = os.path.join(ERD or "", "panda_description/urdf/panda.urdf")
pytestmark = pytest.mark.skipif(not ERD or not os.path.exists(PANDA), reason="example-robot-data is not installed")
DT = 0.01

if ERD and os.path.exists(PANDA):
    with open(PANDA) as f:
        TEXT = f.read()
    ROBOT = dk.load_robot(TEXT)
    NONE = dk.load_robot(re.sub(r'velocity="[^"]*"', 'velocity="0"', TEXT))  # 0: none


@jax.jit
def _step(q, target):
    return dk.ik.step(ROBOT, q, {"panda_hand": target}, dt=DT)


@jax.jit
def _step_given(q, target, velocity):
    return dk.ik.step(ROBOT, q, {"panda_hand": target}, dt=DT, velocity=velocity)


@jax.jit
def _step_none(q, target):
    return dk.ik.step(NONE, q, {"panda_hand": target}, dt=DT)


def _far(dtype):
    """16 configurations within the limits and hand targets 1 m away, turned by about 2 rad."""
    rng = np.random.default_rng(5)
    lower, upper = np.asarray(ROBOT.lower), np.asarray(ROBOT.upper)
    q = rng.uniform(lower, upper, (16, ROBOT.dof))
    T = np.array(dk.fk(ROBOT, jnp.asarray(q), "panda_hand"))
    move = rng.normal(size=(16, 3))
    T[:, :3, 3] += move / np.linalg.norm(move, axis=1, keepdims=True)
    axis = rng.normal(size=(16, 3))
    R = np.stack([rodrigues(2.0 * a / np.linalg.norm(a)) for a in axis])
    T[:, :3, :3] = R @ T[:, :3, :3]
    return jnp.asarray(q, dtype), jnp.asarray(T, dtype)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_a_far_target_never_exceeds_the_file_s_velocity_limits(dtype):
    limit = np.asarray(ROBOT.velocity)
    assert np.all(np.isfinite(limit))  # every joint of the Panda has one (2.175, 2.61 rad/s; 0.2 m/s)
    q, T = _far(dtype)
    out = _step(q, T)
    v = np.abs(np.asarray(out.v, np.float64))
    assert out.v.dtype == dtype and bool(jnp.all(out.feasible))
    assert np.all(v <= limit * (1 + 4 * np.finfo(dtype).eps)), (v / limit).max() - 1
    assert np.mean(np.isclose(v, limit, rtol=1e-4)) > 0.3  # the limits bind
    lower, upper = np.asarray(ROBOT.lower), np.asarray(ROBOT.upper)
    assert np.all(np.asarray(out.q) >= lower.astype(dtype)) and np.all(np.asarray(out.q) <= upper.astype(dtype))


def test_a_velocity_given_replaces_the_file_s_and_a_file_without_them_leaves_the_step_unconstrained():
    q, T = _far(jnp.float64)
    none = _step_none(q, T)
    assert np.all(np.isposinf(np.asarray(NONE.velocity)))
    unlimited = _step_given(q, T, jnp.full(ROBOT.dof, jnp.inf))
    np.testing.assert_allclose(np.asarray(none.v), np.asarray(unlimited.v), rtol=1e-9, atol=1e-9)
    assert np.mean(np.abs(np.asarray(none.v)) > np.asarray(ROBOT.velocity)) > 0.3  # far beyond the file's
    slower = _step_given(q, T, jnp.asarray(ROBOT.velocity) / 2)
    assert np.all(np.abs(np.asarray(slower.v)) <= np.asarray(ROBOT.velocity) / 2 * (1 + 4e-16))
