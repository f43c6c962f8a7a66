"""dk.ik.solve: warm starts, honest failure, the 2R closed form, implicit gradients, input checks (round
trips of 1,000 poses checked by pytorch-kinematics / NumPy DH and the optax method:
``tests/validation/test_ik_validation.py``; a fresh interpreter without optax:
``tests/integration/test_ik_subprocess.py``)."""

import sys

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from _reference import dh_fk, random_q

import diffkin as dk
import diffkin.ik as ik


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
    res = jax.jit(lambda t: ik.solve(chain, t, key=jax.random.key(0), num_seeds=4, max_iters=30))(targets)
    assert list(np.asarray(res.success)) == [False, False, True]
    for x in (res.q, res.pos_err, res.rot_err):
        assert np.all(np.isfinite(np.asarray(x)))
    assert float(res.pos_err[0]) > 3.0 - 0.95 - 1e-3  # the UR5 reaches < 0.95 m from its shoulder
    pos_nan = jnp.full((3,), jnp.nan, jnp.float32)
    res = jax.jit(lambda t: ik.solve(chain, t, num_seeds=2, max_iters=5))(pos_nan)
    assert not bool(res.success) and np.isfinite(float(res.pos_err)) and np.all(np.isfinite(res.q))


def test_planar_2r_matches_closed_form():
    """Textbook 2R: theta2 = +-acos(D), D = (x^2 + y^2 - a1^2 - a2^2) / (2 a1 a2); q0 picks the branch."""
    a1, a2 = 1.0, 0.7
    chain = dk.robots.planar([a1, a2])
    rng = np.random.default_rng(6)
    r = rng.uniform(0.4, 1.6, 100)
    phi = rng.uniform(-np.pi, np.pi, 100)
    x, y = r * np.cos(phi), r * np.sin(phi)
    D = (x**2 + y**2 - a1**2 - a2**2) / (2 * a1 * a2)
    for sign in (1.0, -1.0):
        t2 = sign * np.arccos(D)
        t1 = np.arctan2(y, x) - np.arctan2(a2 * np.sin(t2), a1 + a2 * np.cos(t2))
        q_cf = np.stack([np.angle(np.exp(1j * t1)), t2], -1)
        q0 = q_cf + rng.normal(0, 0.1, q_cf.shape)
        target = jnp.asarray(np.stack([x, y, np.zeros_like(x)], -1))
        res = ik.solve(chain, target, q0=jnp.asarray(q0), num_seeds=4, pos_tol=1e-10)
        assert np.all(res.success)
        np.testing.assert_allclose(np.angle(np.exp(1j * np.asarray(res.q))), q_cf, atol=1e-7)


def test_batch_shapes_vmap_and_independence():
    chain = dk.robots.iiwa7()
    target = jnp.asarray(dh_fk(chain, random_q(chain, 6, seed=8)), jnp.float32)
    solve = jax.jit(lambda t: ik.solve(chain, t, key=jax.random.key(3), num_seeds=16))
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


def test_bad_arguments_raise_before_tracing():
    chain = dk.robots.ur5()
    T = jnp.eye(4)
    cases = [
        (dict(target=jnp.zeros((4, 5))), ValueError, "target"),
        (dict(target=jnp.zeros((3, 4))), ValueError, "target"),
        (dict(q0=jnp.zeros(5)), ValueError, "q0"),
        (dict(q0=jnp.zeros((3, 6))), ValueError, "q0"),
        (dict(method="bfgs"), ValueError, "method"),
        (dict(num_seeds=0), ValueError, "num_seeds"),
        (dict(max_iters=-1), ValueError, "max_iters"),
        (dict(pos_tol=-1e-5), ValueError, "pos_tol"),
        (dict(rot_tol=-1.0), ValueError, "rot_tol"),
        (dict(method="optax", optimizer=lambda g: g), TypeError, "optimizer"),
        (dict(optimizer=optax.adam(1e-2)), ValueError, "optimizer"),
    ]
    for kwargs, error, name in cases:
        kwargs = {"target": T, **kwargs}
        with pytest.raises(error, match=name):
            ik.solve(chain, **kwargs)
    with pytest.raises(TypeError, match="chain"):
        ik.solve("ur5", T)


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
    solve = jax.jit(lambda t: ik.solve(chain, t, key=jax.random.key(0), num_seeds=8, max_iters=30))
    for dtype in (np.float32, np.float64):
        targets = np.stack([T[0], scaled[1], nearly[2], last_row[0]]).astype(dtype)
        res = solve(targets)
        assert list(np.asarray(res.success)) == [True, False, False, False]
        assert all(np.all(np.isfinite(np.asarray(x))) for x in res if x is not None)  # base: None for chains


def test_rigid_check_on_the_host_equals_the_traced_check():
    """diffkin._checks.rigid_poses: NumPy (the host-side check of a concrete target) and jax.numpy
    (inside the solver) judge the same poses alike: rigid ones, ones perturbed below and above the
    tolerance (rotation, last row), non-finite ones; float32 and float64."""
    from diffkin._checks import rigid_poses, rigid_tol

    chain = dk.robots.ur5()
    rng = np.random.default_rng(4)
    T = dh_fk(chain, random_q(chain, 400, seed=9))
    for dtype in (np.float32, np.float64):
        tol = rigid_tol(dtype)
        poses = T.astype(dtype).copy()
        scale = rng.choice([0.0, 0.1, 10.0], size=(400, 1, 1)) * tol  # exact, below, above the tolerance
        poses[:200, :3, :3] *= 1.0 + scale[:200]
        poses[200:, 3, :3] += scale[200:, 0]
        poses[7, 0, 0] = np.nan
        host = rigid_poses(poses)
        assert isinstance(host, np.ndarray) and host.shape == (400,)
        np.testing.assert_array_equal(host, np.asarray(jax.jit(rigid_poses)(poses)))
        exact, above = scale[:, 0, 0] == 0, scale[:, 0, 0] > tol
        exact[7] = False
        assert not host[7] and host[exact].all() and not host[above].any() and exact.sum() > 50


def test_empty_batch_gives_empty_results():
    chain = dk.robots.ur5()
    for target, batch in ((np.zeros((0, 4, 4)), (0,)), (np.zeros((2, 0, 3), np.float32), (2, 0))):
        res = ik.solve(chain, target)
        assert res.q.shape == batch + (6,) and res.q.dtype == target.dtype
        assert res.success.shape == res.pos_err.shape == res.rot_err.shape == res.iters.shape == batch
        assert res.success.dtype == bool and res.iters.dtype == np.int32
    res = jax.jit(lambda t: ik.solve(chain, t))(np.zeros((0, 4, 4), np.float32))
    assert res.q.shape == (0, 6)


def _compilations(fn) -> list[str]:
    """The programs XLA compiled while running ``fn()`` (from ``jax.log_compiles``)."""
    import logging

    class Collect(logging.Handler):
        def __init__(self):
            super().__init__(logging.DEBUG)
            self.names = []

        def emit(self, record):
            message = record.getMessage()
            if message.startswith("Compiling "):
                self.names.append(message.split(" with ")[0])

    handler, logger = Collect(), logging.getLogger("jax")
    logger.addHandler(handler)
    try:
        with jax.log_compiles():
            jax.block_until_ready(fn())
    finally:
        logger.removeHandler(handler)
    return handler.names


def test_eager_solve_compiles_once_per_shape():
    """A second eager call with new values of the same shapes (and an equal, new chain) compiles nothing;
    jitted, the same. (Each eager call used to rebuild its loop closures and recompile them.)"""
    chain = dk.robots.planar([1.0, 1.0])
    T = np.asarray(dk.fk(chain, jnp.array([[0.3, 0.5], [0.1, -0.4], [1.0, 1.0]])))
    first = ik.solve(chain, T, key=jax.random.key(0), num_seeds=4)
    assert np.all(first.success)
    T2 = np.asarray(dk.fk(chain, jnp.array([[0.2, 0.6], [-0.3, 0.9], [0.7, -1.1]])))  # new values, before counting
    key2 = jax.random.key(1)
    again = dk.robots.planar([1.0, 1.0])
    assert _compilations(lambda: ik.solve(again, T2, key=key2, num_seeds=4, pos_tol=2e-5)) == []
    solve = jax.jit(lambda t, k: ik.solve(chain, t, key=k, num_seeds=4))
    solve(T, key2)
    assert _compilations(lambda: solve(T2, key2)) == []
    # a different chain (by value) or shape compiles anew
    assert _compilations(lambda: ik.solve(dk.robots.planar([1.0, 0.5]), T2, key=key2, num_seeds=4)) != []


def test_lm_needs_no_optax(monkeypatch):
    """Without optax, LM works and method='optax' names the extra to install."""
    monkeypatch.setitem(sys.modules, "optax", None)  # import optax raises ImportError
    monkeypatch.delitem(sys.modules, "diffkin.ik._optax", raising=False)
    chain = dk.robots.planar([1.0, 1.0])
    T = np.asarray(dk.fk(chain, jnp.array([[0.3, 0.5], [0.1, -0.4], [1.0, 1.0]])))
    assert np.all(ik.solve(chain, T, key=jax.random.key(0), num_seeds=4).success)
    with pytest.raises(ImportError, match=r"diffkin\[ik\]"):
        ik.solve(chain, T, method="optax")


def test_tolerances_are_traced():
    """New tolerances reuse the compiled solver (the shapes and settings of the test above), and a traced
    tolerance (a jit argument) is accepted."""
    chain = dk.robots.planar([1.0, 1.0])
    T = np.asarray(dk.fk(chain, jnp.array([[0.3, 0.5], [0.1, -0.4], [1.0, 1.0]])))
    loose = ik.solve(chain, T, key=jax.random.key(0), num_seeds=4, pos_tol=1e-3, rot_tol=1e-3)
    assert np.all(loose.success)
    key = jax.random.key(0)
    tight = []
    assert (
        _compilations(
            lambda: tight.append(ik.solve(chain, T, key=key, num_seeds=4, pos_tol=1e-12, rot_tol=1e-12)) or tight[0].q
        )
        == []
    )
    assert np.all(tight[0].iters >= loose.iters) and np.any(tight[0].iters > loose.iters)  # the value is used
    jaxpr = jax.make_jaxpr(lambda tol: ik.solve(chain, T, num_seeds=4, pos_tol=tol, rot_tol=tol).q)(1e-3)
    assert jaxpr.out_avals[0].shape == (3, 2)


def test_seed_draws_are_uniform_independent_and_per_target():
    """The seeds' hash (diffkin.ik._uniform): 24-bit values in [0, 1) whose moments, histogram per
    joint and joint-pair grid match a uniform law, uncorrelated across joints, draws and targets; a
    target's draws depend on its own index and round only (not on the rest of the batch), and on the key."""
    from diffkin.ik import _uniform

    key = jax.random.key(3)
    targets, rounds = jnp.arange(2000), jnp.zeros(2000, jnp.int32)
    u = np.asarray(_uniform.uniform(key, targets, rounds, 8, 7, jnp.float64))
    assert u.shape == (8, 2000, 7) and u.min() >= 0.0 and u.max() < 1.0
    assert np.all(u * 2**24 == np.round(u * 2**24))  # 24 bits, exact
    flat = u.reshape(-1, 7)  # 16,000 draws of 7 joints
    assert abs(flat.mean() - 0.5) < 0.005 and abs(flat.var() - 1 / 12) < 0.002
    for j in range(7):  # Kolmogorov-Smirnov distance of each joint: 1.63 / sqrt(n) is the 1 % level
        x = np.sort(flat[:, j])
        ks = np.max(np.abs(x - np.arange(1, x.size + 1) / x.size))
        assert ks < 1.63 / np.sqrt(x.size)
    # joint pairs on a 10 x 10 grid: chi-square with 99 degrees of freedom (1e-3 level: 148)
    counts = np.histogram2d(flat[:, 0], flat[:, 1], bins=10, range=[[0, 1], [0, 1]])[0]
    expected = flat.shape[0] / 100
    assert np.sum((counts - expected) ** 2 / expected) < 148
    # joints, draws 0 and 1, neighbouring targets: |r| < 0.1 (n = 2,000: 4.5 standard deviations)
    corr = np.corrcoef(np.concatenate([u[0], u[1], np.roll(u[0], 1, axis=0)], axis=1).T)
    assert np.max(np.abs(corr - np.eye(21))) < 0.1
    # per target: targets 5 and 1999 alone give the same draws as inside the batch; another round or key differs
    alone = np.asarray(_uniform.uniform(key, jnp.asarray([1999, 5]), jnp.zeros(2, jnp.int32), 8, 7, jnp.float64))
    np.testing.assert_array_equal(alone[:, 0], u[:, 1999])
    np.testing.assert_array_equal(alone[:, 1], u[:, 5])
    other_round = np.asarray(_uniform.uniform(key, targets, rounds + 1, 8, 7, jnp.float64))
    other_key = np.asarray(_uniform.uniform(jax.random.key(4), targets, rounds, 8, 7, jnp.float64))
    raw_key = np.asarray(_uniform.uniform(jax.random.PRNGKey(3), targets, rounds, 8, 7, jnp.float64))
    for v in (other_round, other_key):
        assert np.mean(v == u) < 1e-3
    np.testing.assert_array_equal(raw_key, u)  # a raw key holds the same words as the typed one
