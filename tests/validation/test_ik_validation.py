"""dk.ik.solve on the robots (each compiles an arm's solver): round trips of 1,000 poses checked by
independent FK (pytorch-kinematics / NumPy DH, float64), position targets, warm starts, honest failure,
batches, implicit gradients, non-rigid targets, and the optax method."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
import pytorch_kinematics as pk
import torch
from _models import URDF_ROBOTS, random_q
from _reference import dh_fk, pose_errors

import diffkin as dk
import diffkin.ik as ik
from diffkin._xla import solver_jit  # compiled as dk.ik.solve compiles itself

ROBOTS = ("iiwa7", "iiwa14", "panda", "ur5")


def _pk_fk(name):
    path, end = URDF_ROBOTS[name]
    with open(path, "rb") as f:
        chain = pk.build_serial_chain_from_urdf(f.read(), end).to(dtype=torch.float64)
    return lambda q: chain.forward_kinematics(torch.as_tensor(q, dtype=torch.float64)).get_matrix().numpy()


_solve32 = {}


def _solver(chain, key_name, **kw):
    """One jitted solver per (robot, settings): each configuration compiles once per module."""
    k = (key_name, tuple(sorted(kw.items())))
    if k not in _solve32:
        _solve32[k] = solver_jit(lambda target, key, q0=None: ik.solve(chain, target, key=key, q0=q0, **kw))
    return _solve32[k]


def _case(kind, name, urdf_chains):
    if kind == "builtin":
        chain = getattr(dk.robots, name)()
        return chain, lambda q: dh_fk(chain, q)
    return urdf_chains[name], _pk_fk(name)


@pytest.mark.parametrize("kind", ["builtin", "urdf"])  # urdf: vs pk
@pytest.mark.parametrize("name", ROBOTS)
def test_round_trip_success_rate_float32(kind, name, urdf_chains):
    """1,000 poses of random in-limit configurations, float32, default settings: >= 99.5 % success,
    every success confirmed by an independent float64 FK, every q within limits."""
    chain, fk64 = _case(kind, name, urdf_chains)
    q_true = random_q(chain, 1000, seed=1)
    target = fk64(q_true)
    res = _solver(chain, f"{kind}-{name}")(jnp.asarray(target, jnp.float32), jax.random.key(7))
    q = np.asarray(res.q, np.float64)
    success = np.asarray(res.success)
    assert res.q.dtype == jnp.float32 and res.q.shape == (1000, chain.dof) and success.shape == (1000,)
    assert np.all(q >= np.asarray(chain.lower)) and np.all(q <= np.asarray(chain.upper))
    pos, rot = pose_errors(fk64(q), target)
    # float32 FK rounding (~1e-7 m) separates diffkin's error from the float64 one; allow that margin only.
    assert np.all(pos[success] <= 1e-5 + 1e-6) and np.all(rot[success] <= 1e-4 + 5e-6)
    # the solver's float32 error vs float64 FK: each float32 pose is off by up to ~5e-7 m at 1 m reach
    np.testing.assert_allclose(np.asarray(res.pos_err)[success], pos[success], atol=1e-6)
    assert success.mean() >= 0.995, f"{kind} {name}: success {success.mean():.4f}"


def test_position_only_targets(urdf_chains):
    chain, fk64 = urdf_chains["iiwa14"], _pk_fk("iiwa14")
    target = fk64(random_q(chain, 200, seed=2))[:, :3, 3]
    res = solver_jit(lambda t: ik.solve(chain, t, key=jax.random.key(0), num_seeds=4))(jnp.asarray(target, jnp.float32))
    pos = np.linalg.norm(fk64(np.asarray(res.q, np.float64))[:, :3, 3] - target, axis=-1)
    assert np.all(np.asarray(res.rot_err) == 0)
    assert np.all(pos[np.asarray(res.success)] <= 1e-5 + 5e-7)
    assert np.asarray(res.success).mean() >= 0.995


def test_optax_method_reaches_loose_tolerance(urdf_chains):
    """Default Adam, 1,000 steps: a first-order method settles to ~1e-3 m (see the bench for the trade-off)."""
    chain, fk64 = urdf_chains["iiwa14"], _pk_fk("iiwa14")
    target = fk64(random_q(chain, 100, seed=11))
    res = solver_jit(lambda t: ik.solve(chain, t, method="optax", num_seeds=4, pos_tol=5e-3, rot_tol=5e-2))(
        jnp.asarray(target, jnp.float32)
    )
    success = np.asarray(res.success)
    pos, rot = pose_errors(fk64(np.asarray(res.q, np.float64)), target)
    assert np.all(pos[success] <= 5e-3 + 1e-6) and np.all(rot[success] <= 5e-2 + 1e-6)
    np.testing.assert_allclose(np.asarray(res.pos_err), pos, atol=1e-6)
    assert success.mean() >= 0.7  # measured 0.74; LM reaches 1e-5 m on all of these (see test above)
    sgd = ik.solve(chain, jnp.asarray(target[0]), method="optax", optimizer=optax.sgd(0.5), num_seeds=2, max_iters=5)
    assert sgd.q.shape == (7,) and np.isfinite(float(sgd.pos_err))


@pytest.mark.parametrize("name", ["ur5", "iiwa14"])
def test_warm_start_returns_nearby_solution(name):
    """q0 near a known solution: a 6-joint arm (isolated solutions) returns that solution; a redundant
    arm returns a solution of the same self-motion about as near q0 as the known one (not another branch)."""
    chain = getattr(dk.robots, name)()
    q_true = random_q(chain, 50, seed=3) * 0.8
    target = dh_fk(chain, q_true)
    q0 = q_true + np.random.default_rng(4).normal(0, 0.02, q_true.shape)
    res = ik.solve(
        chain, jnp.asarray(target), q0=jnp.asarray(q0), key=jax.random.key(1), num_seeds=8, pos_tol=1e-9, rot_tol=1e-9
    )
    assert np.all(res.success)
    if chain.dof == 6:
        np.testing.assert_allclose(res.q, q_true, atol=1e-6)
    else:
        # Minimum-norm LM steps from q0 land near (to first order at) the nearest point of the self-motion.
        dist = np.linalg.norm(np.asarray(res.q) - q0, axis=-1)
        assert np.all(dist <= 1.1 * np.linalg.norm(q_true - q0, axis=-1)), dist
        assert np.all(np.abs(np.asarray(res.q) - q_true) < 0.1)


def test_unreachable_and_nan_targets_fail_honestly():
    chain = dk.robots.ur5()
    T_far = np.eye(4)
    T_far[:3, 3] = [3.0, 0.0, 0.0]
    T_nan = np.full((4, 4), np.nan)
    ok = dh_fk(chain, random_q(chain, 1, seed=5))[0]
    targets = jnp.asarray(np.stack([T_far, T_nan, ok]), jnp.float32)
    res = solver_jit(lambda t: ik.solve(chain, t, key=jax.random.key(0), num_seeds=4, max_iters=30))(targets)
    assert list(np.asarray(res.success)) == [False, False, True]
    for x in (res.q, res.pos_err, res.rot_err):
        assert np.all(np.isfinite(np.asarray(x)))
    assert float(res.pos_err[0]) > 3.0 - 0.95 - 1e-3  # the UR5 reaches < 0.95 m from its shoulder
    pos_nan = jnp.full((3,), jnp.nan, jnp.float32)
    res = solver_jit(lambda t: ik.solve(chain, t, num_seeds=2, max_iters=5))(pos_nan)
    assert not bool(res.success) and np.isfinite(float(res.pos_err)) and np.all(np.isfinite(res.q))


def test_batch_shapes_vmap_and_independence():
    chain = dk.robots.iiwa7()
    target = jnp.asarray(dh_fk(chain, random_q(chain, 6, seed=8)), jnp.float32)
    solve = solver_jit(lambda t: ik.solve(chain, t, key=jax.random.key(3), num_seeds=16))
    res = solve(target.reshape(2, 3, 4, 4))
    assert res.q.shape == (2, 3, 7) and res.success.shape == (2, 3) and res.iters.shape == (2, 3)
    flat = solve(target)
    np.testing.assert_array_equal(res.q.reshape(6, 7), flat.q)
    # Appending an unreachable target (which runs to the cap) does not change the others' results.
    far = jnp.eye(4, dtype=jnp.float32).at[0, 3].set(5.0)
    more = solve(jnp.concatenate([target, far[None]]))
    np.testing.assert_array_equal(more.q[:6], flat.q)
    np.testing.assert_array_equal(more.iters[:6], flat.iters)
    single = jax.vmap(lambda t: ik.solve(chain, t, key=jax.random.key(3), num_seeds=16))(target)
    assert np.all(single.success) and single.q.shape == (6, 7)


def _ur5_solution():
    chain = dk.robots.ur5()
    q_star = np.array([0.3, -1.2, 1.4, -0.7, 1.1, 0.4])  # elbow bent, wrist away from singularity
    return chain, q_star, jnp.asarray(dh_fk(chain, q_star))


def test_implicit_gradient_matches_finite_differences_ur5():
    chain, q_star, T = _ur5_solution()
    assert float(dk.manipulability(chain, jnp.asarray(q_star))) > 1e-3

    def q_of(target):
        return ik.solve(chain, target, q0=jnp.asarray(q_star), num_seeds=1, pos_tol=1e-12, rot_tol=1e-12).q

    rng = np.random.default_rng(9)
    xi = rng.normal(size=6)

    def moved(h):  # T exp-perturbed by the world twist h * xi
        w, v = h * xi[3:], h * xi[:3]
        W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        R = (
            np.eye(3)
            + np.sin(np.linalg.norm(w)) / np.linalg.norm(w) * W
            + (1 - np.cos(np.linalg.norm(w))) / np.linalg.norm(w) ** 2 * W @ W
        )
        out = np.array(T)
        out[:3, :3] = R @ out[:3, :3]
        out[:3, 3] = out[:3, 3] + v
        return jnp.asarray(out)

    h = 1e-5
    fd = (q_of(moved(h)) - q_of(moved(-h))) / (2 * h)
    dT = (moved(h) - moved(-h)) / (2 * h)  # tangent of the same curve
    _, jvp = jax.jvp(q_of, (T,), (dT,))
    np.testing.assert_allclose(jvp, fd, rtol=1e-5, atol=1e-6)
    # Reverse mode agrees with forward mode (the JVP rule is linear in the tangents).
    u = rng.normal(size=6)
    g = jax.grad(lambda t: jnp.dot(q_of(t), u))(T)
    np.testing.assert_allclose(jnp.sum(g * dT), jnp.dot(jvp, u), rtol=1e-8)


def test_implicit_gradient_redundant_arm_moves_the_end_effector_as_the_target():
    chain = dk.robots.iiwa14()
    q_star = np.array([0.2, 0.5, -0.3, -1.2, 0.4, 0.8, 0.1])
    T = jnp.asarray(dh_fk(chain, q_star))
    dT = jnp.asarray(np.random.default_rng(10).normal(size=(4, 4)) * np.r_[1, 1, 1, 0][:, None])
    dT = dT.at[:3, :3].set((dT[:3, :3] - dT[:3, :3].T) @ T[:3, :3])  # a tangent of SE(3) at T
    _, dq = jax.jvp(
        lambda t: ik.solve(chain, t, q0=jnp.asarray(q_star), num_seeds=1, pos_tol=1e-12, rot_tol=1e-12).q, (T,), (dT,)
    )
    _, dT_fk = jax.jvp(lambda q: dk.fk(chain, q), (jnp.asarray(q_star),), (dq,))
    np.testing.assert_allclose(dT_fk, dT, atol=1e-8)
    J = dk.jacobian(chain, jnp.asarray(q_star), method="analytic")
    np.testing.assert_allclose(dq, np.linalg.pinv(np.asarray(J)) @ (np.asarray(J) @ np.asarray(dq)), atol=1e-10)


def test_non_rigid_targets_are_rejected_or_fail():
    """Issue 18: a target whose rotation is not a rotation must not report success."""
    chain = dk.robots.ur5()
    T = dh_fk(chain, random_q(chain, 3, seed=8))
    scaled, nearly, last_row = T.copy(), T.copy(), T.copy()
    scaled[1, :3, :3] *= 2.0
    nearly[2, :3, :3] *= 1.001
    last_row[0, 3] = [0.0, 0.0, 0.1, 1.0]
    for bad, index in ((scaled, "1"), (nearly, "2"), (last_row, "0")):
        for dtype in (np.float32, np.float64):
            with pytest.raises(ValueError, match=rf"^target\[{index}\]: expected a rigid transform"):
                ik.solve(chain, bad.astype(dtype), num_seeds=2, max_iters=2)
    with pytest.raises(ValueError, match=r"^target\[1, 0\]: expected a rigid"):
        ik.solve(chain, np.stack([T[:2], scaled[1:]])[:, :1].reshape(2, 1, 4, 4), num_seeds=2, max_iters=2)
    with pytest.raises(TypeError, match=r"^target: expected real poses or positions, got dtype complex"):
        ik.solve(chain, T.astype(complex))
    with pytest.raises(TypeError, match=r"^target: expected float32 or float64, got float16"):
        ik.solve(chain, T.astype(np.float16))
    # Traced: success=False, finite outputs, for the bad ones; the good one still succeeds.
    solve = solver_jit(lambda t: ik.solve(chain, t, key=jax.random.key(0), num_seeds=8, max_iters=30))
    for dtype in (np.float32, np.float64):
        targets = np.stack([T[0], scaled[1], nearly[2], last_row[0]]).astype(dtype)
        res = solve(targets)
        assert list(np.asarray(res.success)) == [True, False, False, False]
        assert all(np.all(np.isfinite(np.asarray(x))) for x in res if x is not None)  # base: None for chains
