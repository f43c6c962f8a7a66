"""Robots with long serial paths (snakes, cables, discretised continuum robots): the scanned forward pass
(``diffkin/models/_scanned.py``) against a NumPy product of the joints' transforms and finite differences
at 1,000 joints (against the unrolled pass on trees and chains, gradients included:
``tests/validation/test_scanned_validation.py``)."""

import time

import jax
import numpy as np
import pytest
from _models import snake_robot
from _reference import robot_poses

import diffkin as dk
from diffkin import se3

N = 1000


@pytest.fixture(scope="module")
def snake():
    return snake_robot(N)


@pytest.fixture(scope="module")
def jitted(snake):
    """FK of the last link, link poses and the Jacobian of ``snake``, jitted closed over it, once for the
    module: a shape and dtype compiled by one test serves the others."""
    end = f"l{N}"
    return (
        jax.jit(lambda q: dk.fk(snake, q, end)),
        jax.jit(lambda q: dk.link_poses(snake, q)),
        jax.jit(lambda q: dk.jacobian(snake, q, end)),
    )


def _timed(fn, *args):
    """``(result, first call's seconds, second call's seconds)``."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, first, time.perf_counter() - start


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_a_thousand_joints_compile_in_seconds_and_match_numpy(snake, jitted, dtype):
    """FK, link poses and the Jacobian of a 1,000-joint snake. Before the scanned pass a 200-joint snake
    took 14 s to compile its FK and 74 s its Jacobian (1,000 joints: hours); now each compiles in about
    a second at any length and runs in milliseconds. float32 accumulates rounding along the chain: its
    poses are compared with the float64 product at 1e-5 relative to the chain's 10 m."""
    q = np.random.default_rng(0).uniform(-1, 1, (3, N))
    end, (fk, link_poses, jacobian) = f"l{N}", jitted
    T, fk_first, fk_run = _timed(fk, q.astype(dtype))
    poses, lp_first, lp_run = _timed(link_poses, q.astype(dtype))
    J, jac_first, jac_run = _timed(jacobian, q.astype(dtype))
    assert T.dtype == poses.dtype == J.dtype == dtype
    assert max(fk_first, lp_first, jac_first) < 20.0 and max(fk_run, lp_run, jac_run) < 0.5

    tol = 1e-10 if dtype == np.float64 else 1e-5 * N * 0.01
    for k in range(len(q)):
        expected = robot_poses(snake, q[k])
        np.testing.assert_allclose(poses[k], expected, atol=tol)
        np.testing.assert_allclose(T[k], expected[snake.frame_index(end)], atol=tol)
    if dtype == np.float32:
        np.testing.assert_allclose(J, jacobian(q), atol=tol)  # float64 (compiled by the float64 case)
        return
    eps = 1e-6  # central differences of the jitted float64 FK, every joint at once (a batch of 2 N)
    bumped = q[0] + eps * np.concatenate([np.eye(N), -np.eye(N)])[:, None, :]
    plus, minus = np.split(np.asarray(fk(bumped[:, 0])), 2)
    dT = (plus - minus) / (2 * eps)
    R = np.asarray(T[0, :3, :3])
    fd = np.concatenate([dT[:, :3, 3].T, np.stack([se3.vee(d[:3, :3] @ R.T) for d in dT], axis=1)])
    np.testing.assert_allclose(J[0], fd, atol=1e-7)


def test_the_work_grows_linearly(jitted):
    """4x the joints (1,000 and 4,000), 4x the work of FK (a quadratic pass: 16x): the operations and the
    bytes XLA's cost analysis counts in the compiled program, which no load on the machine disturbs. The
    1,000-joint program is the float64 FK of the test above (compiled there, when it ran)."""
    long = snake_robot(4 * N)
    costs = []
    for fk, n in ((jitted[0], N), (jax.jit(lambda q: dk.fk(long, q, f"l{4 * N}")), 4 * N)):
        cost = fk.lower(np.zeros((3, n))).compile().cost_analysis()
        cost = cost[0] if isinstance(cost, list) else cost
        costs.append(np.array([cost["flops"], cost["bytes accessed"]]))
    ratio = costs[1] / costs[0]
    assert np.all((3.5 < ratio) & (ratio < 4.5)), ratio
