"""dk.srs: closed-form iiwa IK over the arm angle, against fk, published vectors, finite differences and brute force."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference import ALL_GC, dh_fk, pose

import diffkin as dk
import diffkin.srs as srs

ARMS = {"iiwa7": srs.iiwa7(), "iiwa14": srs.iiwa14()}
TABLE = {"iiwa7": (0.34, 0.40, 0.40, 0.126), "iiwa14": (0.36, 0.42, 0.40, 0.126)}
LIMITS = np.deg2rad([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])

# Each function is compiled once, for one flat chunk of CHUNK problems (the arm is a traced argument);
# `batched` broadcasts, flattens and pads the inputs and runs them chunk by chunk.
CHUNK = 4096
_ik = jax.jit(srs.ik)
_arm_angle = jax.jit(srs.arm_angle)
_feasible = jax.jit(srs.feasible_arm_angles)
_fk = jax.jit(lambda arm, q: (dk.fk(arm.chain(), q),))
_ik_jacobians = jax.jit(
    lambda arm, T, psi, gc: jax.vmap(jax.jacfwd(lambda T, psi, gc: srs.ik(arm, T, psi, gc)[0], argnums=(0, 1)))(
        T, psi, gc
    )
)
_sample = jax.jit(srs.sample_self_motion, static_argnums=2)
SAMPLES = 2000
N32 = 2000  # float32 ik problems per call of `ik32`
# Eager dk.fk, dk.link_poses and dk.jacobian (the DH references) compile a few dozen small programs per
# batch shape, mostly shared among the three: the tests call them on REF configurations, dk.jacobian on
# REF_JACOBIAN (dq/dpsi against finite differences is checked on 200: more reach ill-conditioned ones).
REF = 500
REF_JACOBIAN = 200


def sample(arm, T, *, key=None, gc=None):
    """``SAMPLES`` samples, every keyword given (jit's cache keys on the keywords given): one compilation
    per dtype and per ``key``, ``gc`` or neither (~7 s each)."""
    return _sample(arm, T, SAMPLES, key=key, gc=gc)


def batched(fn, arm, *args, core):
    """``fn(arm, *args)`` over the broadcast batch of ``args``; ``core[i]`` trailing dims of ``args[i]`` per problem."""
    args = [np.asarray(a, np.float64) for a in args]
    tails = [a.shape[a.ndim - c :] for a, c in zip(args, core, strict=True)]
    batch = np.broadcast_shapes(*(a.shape[: a.ndim - c] for a, c in zip(args, core, strict=True)))
    flat = [np.broadcast_to(a, batch + t).reshape((-1,) + t) for a, t in zip(args, tails, strict=True)]
    n = flat[0].shape[0]
    flat = [np.concatenate([f, np.repeat(f[:1], -n % CHUNK, 0)]) for f in flat]
    outs = [fn(arm, *(f[i : i + CHUNK] for f in flat)) for i in range(0, len(flat[0]), CHUNK)]
    return tuple(
        np.concatenate([np.asarray(o[k]) for o in outs])[:n].reshape(batch + outs[0][k].shape[1:])
        for k in range(len(outs[0]))
    )


def ik(arm, T, psi, gc):
    return batched(_ik, arm, T, psi, gc, core=(2, 0, 1))


def arm_angle(arm, q):
    return batched(_arm_angle, arm, q, core=(1,))


def feasible(arm, T, gc):
    return batched(_feasible, arm, T, gc, core=(2, 1))


def fk(arm, q):
    return batched(_fk, arm, q, core=(1,))[0]


def ik32(arm, T, psi, gc):
    """``_ik`` of float32 ``T (n, 4, 4)`` and ``psi (n,)`` with float64 ``gc (n, 3)``, ``n <= N32``, padded to
    ``N32`` problems: one float32 compilation."""
    pad = lambda x, dtype: np.resize(np.asarray(x, dtype), (N32,) + np.shape(x)[1:])  # noqa: E731
    q, valid = _ik(arm, pad(T, np.float32), pad(psi, np.float32), pad(gc, np.float64))
    n = len(psi)
    return q[:n], valid[:n]


def ik_jacobians(arm, T, psi, gc):
    """``dq/dT (..., 7, 4, 4)`` and ``dq/dpsi (..., 7)``."""
    return batched(_ik_jacobians, arm, T, psi, gc, core=(2, 0, 1))


def random_q(arm, n, seed):
    return np.random.default_rng(seed).uniform(np.asarray(arm.lower), np.asarray(arm.upper), (n, 7))


def pose_error(T, target):
    """Largest entry-wise difference of the 3x4 parts (metres / rotation-matrix units)."""
    return np.abs(np.asarray(T)[..., :3, :] - np.asarray(target)[..., :3, :]).max(axis=(-1, -2))


def in_limits(arm, q):
    return np.all((q >= np.asarray(arm.lower)) & (q <= np.asarray(arm.upper)), axis=-1)


# ----- model ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(ARMS))
def test_model_matches_table_robots_and_shipped_urdf(name):
    arm = ARMS[name]
    lengths = [float(getattr(arm, f)) for f in ("d_bs", "d_se", "d_ew", "d_wf")]
    np.testing.assert_allclose(lengths, TABLE[name], atol=1e-15)
    np.testing.assert_allclose(arm.upper, LIMITS, atol=1e-15)
    np.testing.assert_allclose(arm.lower, -LIMITS, atol=1e-15)
    q = random_q(arm, REF, seed=1)
    T = np.asarray(fk(arm, q))
    urdf = dk.load_urdf(dk.robots.urdf_path(name), f"{name}_link_ee")
    np.testing.assert_allclose(T, dk.fk(getattr(dk.robots, name)(), q), atol=1e-14)
    np.testing.assert_allclose(T, dk.fk(urdf, q), atol=1e-12)


def test_chain_is_differentiable_in_the_lengths():
    q = jnp.full(7, 0.3)
    grad = jax.jit(jax.grad(lambda arm: dk.fk(arm.chain(), q)[2, 3]))(ARMS["iiwa14"])
    # z of the flange is linear in d_bs with slope 1.
    assert float(grad.d_bs) == pytest.approx(1.0, abs=1e-14)


# ----- published vectors ---------------------------------------------------------------------------


def test_iiwa_published_vectors():
    q = np.full(7, 0.5)
    for name, p, psi_ref in (
        ("iiwa14", (0.264615, 0.065211, 1.234181), 0.863513),
        ("iiwa7", (0.256201, 0.060614, 1.196629), 0.878637),
    ):
        arm = ARMS[name]
        T = np.asarray(fk(arm, q))
        np.testing.assert_allclose(T[:3, 3], p, atol=6e-7)
        psi, gc = arm_angle(arm, q)
        np.testing.assert_allclose(gc, [1, 1, 1])
        assert float(psi) == pytest.approx(psi_ref, abs=6e-7)
    arm = ARMS["iiwa7"]
    T = fk(arm, q)
    q0, ok0 = ik(arm, T, 0.0, [1, 1, 1])
    q90, ok90 = ik(arm, T, np.pi / 2, [1, 1, 1])
    assert ok0 and ok90
    np.testing.assert_allclose(q0, [0.091443, 0.553179, 0, 0.5, 1.014339, 0.352777, 0.871964], atol=6e-7)
    np.testing.assert_allclose(q90, [0.798982, 0.390490, 0.901644, 0.5, 0.105970, 0.550737, 0.179205], atol=6e-7)


PA10 = (0.317, 0.45, 0.48, 0.07)  # Shimizu et al. 2008: theta4 of the PA-10 is -theta4 of the iiwa convention


def test_shimizu_pa10_inverse_kinematics():
    arm = srs.SRSArm.from_lengths(*PA10)
    T = pose([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], [0.65, 0.0, 0.5])
    flip4 = np.array([1, 1, 1, -1, 1, 1, 1])
    for psi_deg, q_deg in (
        (0.0, [0, 25.666, 0, 82.872, 0, 71.463, -90]),
        (25.017, [-32.325, 32.687, 46.864, 82.872, -24.101, 74.814, -73.709]),
    ):
        q, ok = ik(arm, T, np.deg2rad(psi_deg), [1, -1, 1])
        assert ok
        # Published to 3 decimals (and psi to 3 decimals, which moves theta1 by up to 1e-3 deg).
        np.testing.assert_allclose(np.rad2deg(q) * flip4, q_deg, atol=1.5e-3)
        np.testing.assert_allclose(pose_error(fk(arm, q), T), 0, atol=1e-12)


def test_shimizu_feasible_arm_angles():
    a, b, e = (1 - np.sqrt(3) / 2) / 2, (1 + np.sqrt(3) / 2) / 2, 1 / (2 * np.sqrt(2))
    T = pose([[a, b, e], [b, a, -e], [-e, e, -np.sqrt(3) / 2]], [0.5, 0.2, 0.7])
    lower = np.deg2rad([-90, -45, -120, -135, -90, -90, -120])
    upper = np.deg2rad([90, 45, 120, 0, 90, 90, 120])
    arm = srs.SRSArm.from_lengths(*PA10, lower=lower, upper=upper)
    intervals, mask = feasible(arm, T, [1, -1, 1])
    assert int(mask.sum()) == 2
    np.testing.assert_allclose(np.rad2deg(intervals[mask]), [[-62.733, -44.629], [-27.875, 3.472]], atol=6e-4)


def test_arm_angle_matches_elbow_definition():
    """psi = signed angle between the elbow planes n_ref, n (SRS.md), from the DH link frames."""
    arm = ARMS["iiwa14"]
    q = random_q(arm, REF, seed=3)
    links = np.asarray(dk.link_poses(arm.chain(), q))
    x_s, x_e, x_w = links[:, 1, :3, 3], links[:, 3, :3, 3], links[:, 5, :3, 3]
    x_sw = x_w - x_s
    u = x_sw / np.linalg.norm(x_sw, axis=1, keepdims=True)
    gc4 = np.where(q[:, 3] >= 0, 1.0, -1.0)
    d_se, d_ew = TABLE["iiwa14"][1:3]
    length = np.linalg.norm(x_sw, axis=1)
    phi = np.arccos((d_se**2 + length**2 - d_ew**2) / (2 * d_se * length))
    # Reference elbow: u turned by gc4 * phi away from the base z axis in the vertical plane through u.
    k = np.cross([0.0, 0.0, 1.0], u)
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    ang = (gc4 * phi)[:, None]
    e_ref = u * np.cos(ang) + np.cross(k, u) * np.sin(ang)
    unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)  # noqa: E731
    n_ref, n = unit(np.cross(e_ref, u)), unit(np.cross(x_e - x_s, u))
    psi_ref = np.sign(np.einsum("ij,ij->i", np.cross(n_ref, n), x_sw)) * np.arccos(
        np.clip(np.einsum("ij,ij->i", n_ref, n), -1, 1)
    )
    psi, _ = arm_angle(arm, q)
    diff = np.angle(np.exp(1j * (np.asarray(psi) - psi_ref)))
    np.testing.assert_allclose(diff, 0, atol=1e-7)  # acos of the reference formula: ~sqrt(eps) near psi = 0, pi


def test_theta3_zero_is_not_always_psi_zero():
    psi, gc = arm_angle(ARMS["iiwa14"], np.deg2rad([0, -45, 0, 90, 0, -45, 0]))
    assert abs(abs(float(psi)) - np.pi) < 1e-12
    np.testing.assert_array_equal(gc, [-1, 1, -1])


# ----- round trips over the solution set -------------------------------------------------------------


@pytest.mark.parametrize("name", list(ARMS))
def test_round_trip_random_configurations(name):
    arm = ARMS[name]
    q = random_q(arm, 4000, seed=4)
    T = fk(arm, q)
    psi, gc = arm_angle(arm, q)
    assert len(np.unique(np.asarray(gc), axis=0)) == 8
    q2, valid = ik(arm, T, psi, gc)
    assert np.all(valid)
    np.testing.assert_allclose(q2, q, atol=1e-9)


@pytest.mark.parametrize("name", list(ARMS))
def test_every_valid_solution_reaches_the_pose_over_the_full_circle(name):
    arm = ARMS[name]
    T = fk(arm, random_q(arm, 60, seed=5))[:, None, None]  # (60, 1, 1, 4, 4)
    psi = np.linspace(-np.pi, np.pi, 181)  # both ends included
    q, valid = ik(arm, T, psi, ALL_GC[:, None])  # (60, 8, 181, 7)
    q, valid = np.asarray(q), np.asarray(valid)
    assert q.shape == (60, 8, 181, 7) and np.all(np.isfinite(q))
    assert 0.3 < valid.mean() < 1.0
    np.testing.assert_array_equal(valid, in_limits(arm, q))  # every pose here is in reach
    err = pose_error(fk(arm, q[valid]), np.broadcast_to(T, q.shape[:-1] + (4, 4))[valid])
    assert err.max() < 1e-9
    # The solution has the requested global configuration (signs of joints 2, 4, 6).
    signs = np.where(q[..., 1::2] >= 0, 1.0, -1.0)
    clear = np.abs(q[..., 1::2]) > 1e-9
    assert np.all((signs == ALL_GC[:, None])[clear])


def test_global_configuration_symmetries():
    arm = ARMS["iiwa14"]
    T = fk(arm, random_q(arm, REF, seed=6))[:, None]
    psi = np.random.default_rng(7).uniform(-np.pi, np.pi, (REF, 1))
    q, _ = ik(arm, T, psi, ALL_GC)  # (REF, 8, 7)
    q = np.asarray(q)
    wrap = lambda x: np.angle(np.exp(1j * x))  # noqa: E731
    # gc2 -> -gc2 (rows 0 and 4): (q1, q2, q3) -> (q1 + pi, -q2, q3 + pi); gc6 likewise (rows 0 and 1).
    np.testing.assert_allclose(wrap(q[:, 4, [0, 2]] - q[:, 0, [0, 2]] - np.pi), 0, atol=1e-9)
    np.testing.assert_allclose(q[:, 4, 1], -q[:, 0, 1], atol=1e-9)
    np.testing.assert_allclose(wrap(q[:, 1, [4, 6]] - q[:, 0, [4, 6]] - np.pi), 0, atol=1e-9)
    np.testing.assert_allclose(q[:, 1, 5], -q[:, 0, 5], atol=1e-9)
    # (gc4, psi) and (-gc4, psi + pi) put the elbow (DH frame 3 origin) at the same point.
    q_flip, _ = ik(arm, T[:, 0], psi[:, 0] + np.pi, [1, -1, 1])
    elbow = lambda q: np.asarray(dk.link_poses(arm.chain(), q))[..., 3, :3, 3]  # noqa: E731
    np.testing.assert_allclose(elbow(q_flip), elbow(q[:, 0]), atol=1e-12)


# ----- derivatives -----------------------------------------------------------------------------------


def test_dq_dpsi_matches_finite_differences_and_keeps_the_pose():
    arm = ARMS["iiwa14"]
    q0 = random_q(arm, REF_JACOBIAN, seed=8)
    T = fk(arm, q0)
    psi, gc = arm_angle(arm, q0)
    _, J = ik_jacobians(arm, T, psi, gc)
    h = 1e-6
    fd = (ik(arm, T, psi + h, gc)[0] - ik(arm, T, psi - h, gc)[0]) / (2 * h)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6)
    # Self-motion: the flange does not move, d fk(ik(psi)) / dpsi = (dfk/dq) (dq/dpsi) = 0.
    Jfk = np.asarray(dk.jacobian(arm.chain(), q0, method="analytic"))
    assert np.abs(np.einsum("nij,nj->ni", Jfk, J)).max() < 1e-10


def test_derivative_with_respect_to_the_target_inverts_fk():
    """Moving the target position by dp moves the solution by dq with J_fk dq = [dp; 0]."""
    arm = ARMS["iiwa7"]
    q0 = random_q(arm, REF_JACOBIAN, seed=9)
    T = fk(arm, q0)
    psi, gc = arm_angle(arm, q0)
    dq_dT, _ = ik_jacobians(arm, T, psi, gc)
    dq_dp = dq_dT[..., :3, 3]  # (REF_JACOBIAN, 7, 3)
    Jfk = np.asarray(dk.jacobian(arm.chain(), q0, method="analytic"))
    expected = np.concatenate([np.eye(3), np.zeros((3, 3))])
    moved = np.einsum("nij,njk->nik", Jfk, dq_dp)
    np.testing.assert_allclose(moved, np.broadcast_to(expected, moved.shape), atol=1e-10)


def test_gradient_with_respect_to_arm_lengths():
    arm = ARMS["iiwa14"]
    T = fk(arm, np.full(7, 0.5))

    @jax.jit
    @jax.value_and_grad
    def loss(d_se):
        return jnp.sum(jnp.sin(srs.ik(arm.replace(d_se=d_se), T, 0.3, jnp.ones(3))[0]))

    _, g = loss(arm.d_se)
    h = 1e-6
    fd = (loss(arm.d_se + h)[0] - loss(arm.d_se - h)[0]) / (2 * h)
    assert float(g) == pytest.approx(float(fd), rel=1e-6)


# ----- dtypes, batching, transformations --------------------------------------------------------------


def test_float32():
    arm = ARMS["iiwa14"]
    q = random_q(arm, N32, seed=10)
    T = np.asarray(fk(arm, q))
    psi, gc = arm_angle(arm, q)  # float64 gc: ik casts it to the dtype of T and psi
    q32, valid = ik32(arm, T, psi, gc)
    assert q32.dtype == jnp.float32 and valid.dtype == jnp.bool_
    q32 = np.asarray(q32, np.float64)
    assert np.all(valid) and np.all(np.isfinite(q32))
    assert pose_error(fk(arm, q32), T).max() < 1e-5
    # Away from theta2, theta4, theta6 = 0 (where q1, q3 or q5, q7 are ill-conditioned: their float32
    # error grows like 1e-7 / |sin theta2|, though the pose stays exact) the angles agree to rounding.
    clear = np.all(np.abs(np.sin(q[:, 1:6:2])) > 0.1, axis=1)
    assert clear.mean() > 0.8
    assert np.abs(q32 - q)[clear].max() < 2e-5
    psi32, gc32 = _arm_angle(arm, q.astype(np.float32))
    assert psi32.dtype == jnp.float32 and gc32.dtype == jnp.float32
    assert np.abs(np.asarray(psi32) - np.asarray(psi))[clear].max() < 2e-5


def test_broadcasting_and_vmap_agree_with_flat_batches():
    arm = ARMS["iiwa7"]
    T = np.asarray(fk(arm, random_q(arm, 5, seed=11)))[:, None]  # (5, 1, 4, 4)
    psi = np.linspace(-3.0, 3.0, 3)
    gc = ALL_GC[:2, None, None]  # (2, 1, 1, 3)
    shapes = jax.eval_shape(srs.ik, arm, T, psi, gc)
    assert shapes[0].shape == (2, 5, 3, 7) and shapes[1].shape == (2, 5, 3)
    shapes = jax.eval_shape(srs.feasible_arm_angles, arm, T, gc)
    assert shapes[0].shape == (2, 5, 1, 13, 2) and shapes[1].shape == (2, 5, 1, 13)
    assert jax.eval_shape(srs.arm_angle, arm, np.zeros((4, 1, 7)))[1].shape == (4, 1, 3)

    # vmap over the global configurations of ik broadcasting poses (5, 1) against arm angles (3,).
    q, valid = jax.jit(jax.vmap(lambda g: srs.ik(arm, T, psi, g)))(gc)
    q_flat, valid_flat = ik(arm, T, psi, gc)  # one problem at a time, in a padded flat chunk
    np.testing.assert_allclose(q, q_flat, atol=1e-14)
    np.testing.assert_array_equal(valid, valid_flat)


def test_large_batches_in_overlapping_steps_agree_with_single_steps():
    """Batches above ``CHUNK`` go through a loop whose last step overlaps the one before it."""
    from diffkin.srs._closed_form import CHUNK

    arm = ARMS["iiwa14"]
    n = 2 * CHUNK + 123
    q0 = random_q(arm, n, seed=13)
    T = fk(arm, q0)
    psi, gc = arm_angle(arm, q0)
    q, valid = _ik(arm, T, psi, gc)  # one call: three steps
    q_flat, valid_flat = ik(arm, T, psi, gc)  # CHUNK problems per call: one step each
    assert q.shape == (n, 7) and valid.shape == (n,)
    np.testing.assert_allclose(q, q_flat, atol=1e-12)
    np.testing.assert_array_equal(valid, valid_flat)
    # One pose broadcast against many arm angles, batch (2, n // 2 + 1) in float32.
    psi = np.linspace(-np.pi, np.pi, n // 2 + 1, dtype=np.float32)
    q, valid = _ik(arm, T[0].astype(np.float32), psi, ALL_GC[:2, None])
    q_flat, valid_flat = ik(arm, T[0], psi, ALL_GC[:2, None])
    assert q.dtype == jnp.float32 and q.shape == (2, n // 2 + 1, 7)
    assert np.abs(np.asarray(q, np.float64) - q_flat)[valid_flat].max() < 1e-4


# ----- singular and degenerate cases --------------------------------------------------------------


def _singular_targets(arm):
    """Wrist on the joint-1 axis (twice), stretched elbow, theta2 = 0, theta6 = 0, out of reach."""
    d_bs, d_se, d_ew, d_wf = (float(getattr(arm, f)) for f in ("d_bs", "d_se", "d_ew", "d_wf"))
    R = np.asarray(fk(arm, np.array([0.3, -0.4, 0.5, 1.0, -0.6, 0.7, 0.8])))[:3, :3]
    on_axis = [pose(R, [0, 0, d_bs + z] + R[:, 2] * d_wf) for z in (0.5, 0.7)]
    q = random_q(arm, 3, seed=12)
    q[0, 3] = 0.0  # stretched
    q[1, 1] = 0.0
    q[2, 5] = 0.0
    far = pose(R, [0.0, 0.0, d_bs + d_se + d_ew + d_wf + 0.5])
    return np.concatenate([np.stack(on_axis), np.asarray(fk(arm, q)), far[None]])


def test_singular_cases_are_finite_and_exact():
    arm = ARMS["iiwa14"]
    T = _singular_targets(arm)[:, None, None]  # (6, 1, 1, 4, 4)
    psi = np.concatenate([np.linspace(-np.pi, np.pi, 73), [0.0, np.pi]])
    q, valid = ik(arm, T, psi, ALL_GC[:, None])
    q, valid = np.asarray(q), np.asarray(valid)
    assert np.all(np.isfinite(q))
    assert not valid[-1].any()  # out of reach
    assert valid[:-1].any(axis=(1, 2)).all()  # every reachable singular pose has solutions
    Ts = np.broadcast_to(T, q.shape[:-1] + (4, 4))
    assert pose_error(fk(arm, q[valid]), Ts[valid]).max() < 1e-9
    # Derivatives stay finite, including exactly at the singular psi.
    dq_dT, dq_dpsi = ik_jacobians(arm, T, psi, ALL_GC[:, None])
    assert np.all(np.isfinite(dq_dT)) and np.all(np.isfinite(dq_dpsi))
    psi_q, _ = arm_angle(arm, q.reshape(-1, 7))
    assert np.all(np.isfinite(np.asarray(psi_q)))
    intervals, mask = feasible(arm, T[:, 0, 0], ALL_GC[:, None])
    assert np.all(np.isfinite(np.asarray(intervals))) and not np.asarray(mask)[:, -1].any()


def test_degenerate_wrist_at_the_shoulder_is_finite():
    arm = ARMS["iiwa7"]  # d_se = d_ew: the wrist can fold onto the shoulder
    T = pose(np.eye(3), [0, 0, float(arm.d_bs) + float(arm.d_wf)])
    q, valid = ik(arm, T, np.linspace(-3, 3, 7), ALL_GC[:, None])
    psi, _ = arm_angle(arm, np.array([0.0, 0.5, 0.0, np.pi, 0.0, 0.0, 0.0]))
    assert np.all(np.isfinite(np.asarray(q))) and not np.asarray(valid).any() and np.isfinite(float(psi))


# ----- feasible arm angles -----------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(ARMS))
def test_feasible_arm_angles_match_a_brute_force_scan(name):
    arm = ARMS[name]
    q = random_q(arm, 120, seed=13)
    q[:10, 1] = 0.0  # theta2 = 0 at some psi: tangent-type joints 1, 3 jump by pi there
    q[10:20, 5] = 0.0
    q[20:25, 3] = 0.0
    T = np.asarray(fk(arm, q))[:, None]
    intervals, mask = feasible(arm, T, ALL_GC)  # (120, 8, K, 2)
    intervals, mask = np.asarray(intervals), np.asarray(mask)
    lo, hi = intervals[..., 0], intervals[..., 1]
    # Well-formed: in [-pi, pi], lo <= hi, sorted and disjoint, used slots first.
    assert np.all((lo >= -np.pi) & (hi <= np.pi) & (lo <= hi))
    assert np.all(mask[..., 1:] <= mask[..., :-1])
    assert np.all((lo[..., 1:] > hi[..., :-1])[mask[..., 1:]])
    assert 1 < mask.sum(-1).max() <= 13
    psi = np.linspace(-np.pi, np.pi, 2048, endpoint=False) + 1e-4
    qs, valid = ik(arm, T[..., None, :, :], psi, ALL_GC[:, None])  # (120, 8, 2048)
    qs, valid = np.asarray(qs), np.asarray(valid)
    inside = np.zeros(valid.shape, bool)
    near = np.zeros(valid.shape, bool)
    for k in range(intervals.shape[-2]):
        m = mask[..., k, None]
        inside |= m & (psi >= lo[..., k, None]) & (psi <= hi[..., k, None])
        near |= m & (np.minimum(np.abs(psi - lo[..., k, None]), np.abs(psi - hi[..., k, None])) < 1e-7)
    # Exactly at a singular psi (theta2 or theta6 = 0) ik's split of q1 + q3 is arbitrary: not a border.
    singular = np.any(np.abs(np.sin(qs[..., 1::4])) < 1e-9, axis=-1)
    checked = ~near & ~singular
    assert checked.mean() > 0.999
    np.testing.assert_array_equal(inside[checked], valid[checked])


def test_feasible_arm_angles_out_of_reach_and_elbow_limit():
    arm = ARMS["iiwa14"]
    far = pose(np.eye(3), [0.0, 0.0, 2.0])
    near = pose(np.eye(3), [0.0, 0.0, float(arm.d_bs) + float(arm.d_wf) + 0.3])  # |x_sw| = 0.3: |theta4| > 120 deg
    _, mask = feasible(arm, np.stack([far, near])[:, None], ALL_GC)
    assert not np.asarray(mask).any()


# ----- sampling the self-motion ---------------------------------------------------------------------------


@pytest.mark.parametrize("jitter", [False, True])
def test_sample_self_motion_is_exact_and_covers_the_feasible_set(jitter):
    arm = ARMS["iiwa14"]
    n = SAMPLES
    T = np.asarray(fk(arm, np.array([0.4, 0.7, -0.3, -1.1, 0.6, 0.9, -0.2])))
    key = jax.random.PRNGKey(0) if jitter else None
    q, valid = sample(arm, T, key=key)
    q, valid = np.asarray(q), np.asarray(valid)
    assert q.shape == (n, 7) and np.all(valid) and np.all(in_limits(arm, q))
    assert pose_error(fk(arm, q), T).max() < 1e-9
    psi, gc = (np.asarray(x) for x in arm_angle(arm, q))
    intervals, mask = (np.asarray(x) for x in feasible(arm, T, ALL_GC))
    lengths = np.where(mask, intervals[..., 1] - intervals[..., 0], 0.0)
    step = lengths.sum() / n
    assert len({tuple(g) for g in gc}) > 1
    slack = 2.0 if jitter else 1.0  # one sample per step of the stratification, jittered or centred
    for g in range(8):
        mine = psi[np.all(gc == ALL_GC[g], axis=1)]
        for k in np.flatnonzero(mask[g]):
            a, b = intervals[g, k]
            inside = np.sort(mine[(mine >= a - 1e-12) & (mine <= b + 1e-12)])
            assert abs(len(inside) - (b - a) / step) <= slack
            if len(inside):
                gaps = np.diff(np.concatenate([[a], inside, [b]]))
                assert gaps.max() <= slack * step + 1e-9
        assert len(mine) == sum(np.sum((mine >= a - 1e-12) & (mine <= b + 1e-12)) for a, b in intervals[g][mask[g]])


def test_sample_self_motion_one_configuration_and_unreachable():
    arm = ARMS["iiwa7"]
    T = np.asarray(fk(arm, np.full(7, 0.5)))
    q, valid = sample(arm, T, gc=np.array([1.0, 1.0, 1.0]))
    assert np.all(valid)
    np.testing.assert_array_equal(np.asarray(arm_angle(arm, q)[1]), np.ones((SAMPLES, 3)))
    q, valid = sample(arm, pose(np.eye(3), [2.0, 0.0, 0.0]))
    assert np.all(np.isfinite(np.asarray(q))) and not np.asarray(valid).any()


# ----- bad input -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call, error, words",
    [
        (lambda a: srs.ik(a, np.eye(3), 0.0, [1, 1, 1]), ValueError, "target"),
        (lambda a: srs.ik(a, np.eye(4), 0.0, [1, 1]), ValueError, "gc"),
        (lambda a: srs.ik(a, np.eye(4), 0.0, [1, 0, 1]), ValueError, "+1 or -1"),
        (lambda a: srs.ik(a, np.eye(4), np.zeros(3), np.ones((2, 3))), ValueError, "broadcast"),
        (lambda a: srs.ik(a.chain(), np.eye(4), 0.0, [1, 1, 1]), TypeError, "arm"),
        (lambda a: srs.ik(a, np.eye(4), "x", [1, 1, 1]), TypeError, "psi"),
        (lambda a: srs.arm_angle(a, np.zeros(6)), ValueError, "q"),
        (lambda a: srs.feasible_arm_angles(a, np.eye(4), [2, 1, 1]), ValueError, "gc"),
        (lambda a: srs.sample_self_motion(a, np.eye(4), 0), ValueError, "n"),
        (lambda a: srs.sample_self_motion(a, np.eye(4), 2.5), TypeError, "n"),
        (lambda a: srs.sample_self_motion(a, np.stack([np.eye(4)] * 2), 5), ValueError, "target"),
        (lambda a: srs.sample_self_motion(a, np.eye(4), 5, gc=np.ones((2, 3))), ValueError, "gc"),
        (lambda a: srs.SRSArm.from_lengths(0.36, -0.42, 0.4, 0.126), ValueError, "d_se"),
        (
            lambda a: srs.SRSArm.from_lengths(0.36, 0.42, 0.4, 0.126, lower=np.ones(7), upper=np.zeros(7)),
            ValueError,
            "lower",
        ),
        (lambda a: srs.SRSArm.from_lengths(0.36, 0.42, 0.4, 0.126, lower=np.ones(6)), ValueError, "lower"),
        (lambda a: srs.SRSArm.from_chain(dk.robots.panda()), ValueError, "chain"),
        (lambda a: srs.SRSArm.from_chain(dk.robots.ur5()), ValueError, "chain"),
        (lambda a: srs.SRSArm.from_chain(a), TypeError, "chain"),
    ],
)
def test_bad_input_is_rejected_on_the_host(call, error, words):
    with pytest.raises(error, match=words.replace("+", r"\+")):
        call(ARMS["iiwa14"])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_valid_means_valid(dtype):
    """Issue 18: traced gc not +-1, non-rigid or non-finite targets, huge or non-finite psi."""
    arm = ARMS["iiwa14"]
    q_true = np.array([0.4, 0.7, -0.3, -1.1, 0.5, 0.9, 0.2])
    T = fk(arm, q_true)
    psi, gc = arm_angle(arm, q_true)
    scaled, skew = T.copy(), T.copy()
    scaled[:3, :3] *= 1.001
    skew[3, :3] = [0.0, 0.1, 0.0]
    nan_T = np.full((4, 4), np.nan)
    cases = [  # (target, psi, gc, expected valid or None: valid only if reached)
        (T, psi, gc, True),
        (T, psi, gc * [0, 1, 1], False),
        (T, psi, gc * [1, 0.5, 1], False),
        (T, psi, gc * [1, 1, 2], False),
        (scaled, psi, gc, False),
        (skew, psi, gc, False),
        (nan_T, psi, gc, False),
        (np.where(np.eye(4) > 0, np.inf, T), psi, gc, False),
        (T, np.nan, gc, False),
        (T, np.inf, gc, False),
        (T, psi, gc * [np.nan, 1, 1], False),
        (T, 1e17, gc, None),
        (T, psi + 2e6 * np.pi, gc, None),
    ]
    targets = np.stack([c[0] for c in cases]).astype(dtype)
    psis = np.array([c[1] for c in cases], dtype)
    gcs = np.stack([np.broadcast_to(c[2], (3,)) for c in cases])  # float64: ik casts gc to the dtype of T and psi
    # jitted: gc, target and psi are traced (in the module's padded batches, compiled once per dtype)
    q, valid = ik(arm, targets, psis, gcs) if dtype == np.float64 else ik32(arm, targets, psis, gcs)
    q, valid = np.asarray(q), np.asarray(valid)
    assert np.all(np.isfinite(q))
    for i, (_, _, _, expected) in enumerate(cases):
        if expected is not None:
            assert valid[i] == expected, (i, cases[i][1:])
        if valid[i]:  # valid means the arm reaches the pose (independent float64 FK)
            reached = dh_fk(dk.robots.iiwa14(), q[i].astype(np.float64))
            np.testing.assert_allclose(reached, T, atol=1e-4 if dtype == np.float32 else 1e-9)
    # Eager (concrete) calls check gc on the host.
    with pytest.raises(ValueError, match=r"^gc: expected entries \+1 or -1, got 0.5"):
        srs.ik(arm, T, psi, [1.0, 0.5, 1.0])
    # The self-motion of a non-rigid, or non-finite, pose: nothing valid, everything finite.
    for bad in (scaled, nan_T):
        qs, ok = sample(arm, bad.astype(dtype))
        assert not np.any(np.asarray(ok)) and np.all(np.isfinite(np.asarray(qs)))
    # jitted: gc is traced
    qs, ok = sample(arm, T.astype(dtype), gc=(gc * [1, 0.5, 1]).astype(dtype))
    assert not np.any(np.asarray(ok)) and np.all(np.isfinite(np.asarray(qs)))
    qs, ok = sample(arm, T.astype(dtype), gc=gc.astype(dtype))
    assert np.all(np.asarray(ok))
