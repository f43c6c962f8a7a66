"""Robots with long serial paths (snakes, cables, discretised continuum robots): the scanned forward pass
(``diffkin/models/_scanned.py``) against a NumPy product of the joints' transforms and finite differences
at 1,000 joints, and against the unrolled pass on trees with mimic joints and floating roots."""

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference import PANDA, random_robot_q, robot_poses, snake_robot

import diffkin as dk
from diffkin import se3
from diffkin.models import _scanned

N = 1000


@pytest.fixture(scope="module")
def snake():
    return snake_robot(N)


def _timed(fn, *args):
    """``(result, first call's seconds, second call's seconds)``."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, first, time.perf_counter() - start


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_a_thousand_joints_compile_in_seconds_and_match_numpy(snake, dtype):
    """FK, link poses and the Jacobian of a 1,000-joint snake. Before the scanned pass a 200-joint snake
    took 14 s to compile its FK and 74 s its Jacobian (1,000 joints: hours); now each compiles in about
    a second at any length and runs in milliseconds. float32 accumulates rounding along the chain: its
    poses are compared with the float64 product at 1e-5 relative to the chain's 10 m."""
    q = np.random.default_rng(0).uniform(-1, 1, (3, N))
    end = f"l{N}"
    T, fk_first, fk_run = _timed(jax.jit(lambda q: dk.fk(snake, q, end)), q.astype(dtype))
    poses, lp_first, lp_run = _timed(jax.jit(lambda q: dk.link_poses(snake, q)), q.astype(dtype))
    J, jac_first, jac_run = _timed(jax.jit(lambda q: dk.jacobian(snake, q, end)), q.astype(dtype))
    assert T.dtype == poses.dtype == J.dtype == dtype
    assert max(fk_first, lp_first, jac_first) < 20.0 and max(fk_run, lp_run, jac_run) < 0.5

    tol = 1e-10 if dtype == np.float64 else 1e-5 * N * 0.01
    for k in range(len(q)):
        expected = robot_poses(snake, q[k])
        np.testing.assert_allclose(poses[k], expected, atol=tol)
        np.testing.assert_allclose(T[k], expected[snake.frame_index(end)], atol=tol)
    if dtype == np.float32:
        np.testing.assert_allclose(J, dk.jacobian(snake, q, end), atol=tol)
        return
    eps = 1e-6  # central differences of the jitted float64 FK, every joint at once (a batch of 2 N)
    bumped = q[0] + eps * np.concatenate([np.eye(N), -np.eye(N)])[:, None, :]
    plus, minus = np.split(np.asarray(jax.jit(lambda q: dk.fk(snake, q, end))(bumped[:, 0])), 2)
    dT = (plus - minus) / (2 * eps)
    R = np.asarray(T[0, :3, :3])
    fd = np.concatenate([dT[:, :3, 3].T, np.stack([se3.vee(d[:3, :3] @ R.T) for d in dT], axis=1)])
    np.testing.assert_allclose(J[0], fd, atol=1e-7)


def test_the_run_time_grows_linearly():
    """4x the joints (1,000 and 4,000), at most 8x the run time of FK (a quadratic pass: 16x). The fastest of
    nine runs each: the least disturbed by other work on the machine."""
    times = []
    for n in (N, 4 * N):
        robot = snake_robot(n)
        fk = jax.jit(lambda q, robot=robot, n=n: dk.fk(robot, q, f"l{n}"))
        q = np.zeros((4, n))
        jax.block_until_ready(fk(q))
        runs = []
        for _ in range(9):
            start = time.perf_counter()
            jax.block_until_ready(fk(q))
            runs.append(time.perf_counter() - start)
        times.append(min(runs))
    assert times[1] < 8 * times[0]


@pytest.fixture(scope="module")
def scanned_and_unrolled():
    """The Panda (a tree, one mimic joint) on a floating root, taken once by each pass."""
    robot = dk.load_robot(PANDA, floating=True)
    return robot, lambda fn, *args: _with_long(0, fn, *args), lambda fn, *args: _with_long(10**9, fn, *args)


def _with_long(long: int, fn, *args):
    """``fn(*args)``, jitted and traced afresh, with every robot deeper than ``long`` joints scanned."""
    saved = _scanned.LONG
    _scanned.LONG = long
    try:
        return jax.jit(lambda *a: fn(*a))(*args)
    finally:
        _scanned.LONG = saved


def test_the_scanned_pass_equals_the_unrolled_pass_on_a_tree(scanned_and_unrolled):
    """Every frame, two frames' Jacobians in each reference frame (base columns included), the centre of
    mass and its Jacobian: the scanned pass equals the unrolled one (float64, 1e-12)."""
    dtype = np.float64
    robot, scanned, unrolled = scanned_and_unrolled
    rng = np.random.default_rng(1)
    q = random_robot_q(robot, 5, seed=1).astype(dtype)
    base = np.stack([np.eye(4)] * 5)
    base[:, :3, :3] = np.asarray(jax.vmap(lambda w: jax.scipy.linalg.expm(se3.skew(w)))(rng.normal(size=(5, 3))))
    base[:, :3, 3] = rng.normal(size=(5, 3))
    base = base.astype(dtype)
    tol = 1e-12
    frames = ("panda_rightfinger", "panda_link3")

    def everything(q, base):
        return {
            "link_poses": dk.link_poses(robot, q, base=base),
            "fk": dk.fk(robot, q, ["panda_hand_tcp", "panda_rightfinger"], base=base),
            "com": dk.com(robot, q),
            "com_jacobian": dk.com_jacobian(robot, q, include_base=True),
            **{
                f"jacobian {name} {ref}": dk.jacobian(robot, q, name, ref, base=base, include_base=True)
                for name in frames
                for ref in ("world", "space", "body")
            },
        }

    a, b = scanned(everything, q, base), unrolled(everything, q, base)
    for name in a:
        assert a[name].dtype == b[name].dtype == dtype
        np.testing.assert_allclose(a[name], b[name], atol=tol, err_msg=name)


def test_scanned_gradients_with_respect_to_q_and_the_model(scanned_and_unrolled):
    """Reverse mode through the scan (with respect to ``q`` and to the robot's own arrays, the robot traced
    as a ``jit`` argument) equals the unrolled pass's gradients."""
    robot, scanned, _ = scanned_and_unrolled
    q = jnp.asarray(random_robot_q(robot, 4, seed=2))

    def loss(robot, q):
        T = dk.fk(robot, q, ["panda_hand_tcp", "panda_leftfinger"])
        return jnp.sum(T[..., :3, :] ** 2 * jnp.arange(1.0, 13.0).reshape(3, 4)) + jnp.sum(dk.com(robot, q))

    grad = jax.grad(loss, argnums=(0, 1))
    # The unrolled reference op by op: jitted with the robot traced, XLA takes minutes to compile it.
    (g_robot, g_q), (h_robot, h_q) = scanned(grad, robot, q), grad(robot, q)
    np.testing.assert_allclose(g_q, h_q, atol=1e-11)
    for name in ("joint_poses", "screws", "multipliers", "offsets", "frame_poses", "masses", "body_coms"):
        np.testing.assert_allclose(getattr(g_robot, name), getattr(h_robot, name), atol=1e-11, err_msg=name)
