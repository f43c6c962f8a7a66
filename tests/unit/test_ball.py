"""Ball joints (three entries of ``q``: a rotation vector): FK against Rodrigues' formula, Jacobian columns and
the centre of mass's against finite differences, no NaN at ``r = 0``, the cone limits and bad structures
(MuJoCo at random quaternions and IK: ``tests/validation/test_ball_validation.py``)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _mjcf import mjcf
from _reference import robot_poses

import diffkin as dk
from diffkin.models import _ball

# Two ball joints (one limited to a 70 degree cone, about an off-origin centre; one unlimited), a hinge and a
# slide in the same body as a ball joint.
ARM = mjcf(
    '<body name="upper" pos="0 0 1" euler="10 20 30"><joint name="shoulder" type="ball" pos="0 0 .1" range="0 70"/>'
    '<geom size=".05" mass="1"/><body name="fore" pos="0 .1 -.5"><joint name="elbow" axis="0 1 0" range="-150 0"/>'
    '<geom size=".05" pos="0 0 -.2" mass="1"/><body name="hand" pos="0 0 -.4"><joint name="wrist" type="ball" '
    'pos=".01 0 0"/><joint name="slide" type="slide" axis="0 0 1" range="-.1 .1"/><geom size=".04" mass=".5"/>'
    '<site name="tip" pos="0 .05 -.1"/></body></body></body>'
)
SHOULDER, WRIST = slice(0, 3), slice(4, 7)


@pytest.fixture(scope="module")
def arm():
    return dk.load_robot(ARM)


@pytest.fixture(scope="module")
def configurations(arm):
    """Random in-limit configurations, and the rotation vectors that need care: zero, tiny, near a half-turn."""
    q = np.array(dk.workspace.sample_configs(arm, 24, jax.random.PRNGKey(0)), np.float64)
    rng = np.random.default_rng(1)
    for k, length in enumerate([0.0, 1e-9, 1e-5, np.pi - 1e-6]):
        axis = rng.normal(size=3)
        q[k, WRIST] = length * axis / np.linalg.norm(axis)
        q[k + 4, SHOULDER] = 0.0 if k == 0 else min(length, 1.2) * axis / np.linalg.norm(axis)
    return q


@pytest.fixture(scope="module")
def kinematics(arm):
    """Link poses, both Jacobians of the tip and the centre of mass with its Jacobian, compiled once."""

    @jax.jit
    def run(q):
        return (
            dk.link_poses(arm, q),
            dk.jacobian(arm, q, "tip"),
            dk.jacobian(arm, q, "tip", method="autodiff"),
            dk.com(arm, q),
            dk.com_jacobian(arm, q),
        )

    return run


def test_ball_joints_load_as_rotation_vectors(arm):
    shoulder, wrist = (tuple(f"{joint}:{axis}" for axis in ("rx", "ry", "rz")) for joint in ("shoulder", "wrist"))
    assert arm.joint_names == (*shoulder, "elbow", *wrist, "slide")
    assert arm.actuated_types == "BBBRBBBP" and _ball.starts(arm.actuated_types) == (0, 4)
    np.testing.assert_allclose(arm.upper[SHOULDER], np.radians(70), rtol=1e-15)
    np.testing.assert_allclose(arm.lower[SHOULDER], -np.radians(70), rtol=1e-15)
    assert np.all(np.isinf(arm.upper[WRIST])) and np.all(np.isinf(arm.lower[WRIST]))
    with pytest.raises(ValueError, match="ball joint .*'shoulder:rx'"):
        arm.chain("tip")


def test_fk_is_a_rotation_about_the_centre(arm, configurations, kinematics):
    poses = np.asarray(kinematics(jnp.asarray(configurations))[0])
    expected = np.stack([robot_poses(arm, q) for q in configurations])
    np.testing.assert_allclose(poses, expected, rtol=0, atol=1e-13)
    # the shoulder's centre stays where it is, whatever the rotation
    centre = robot_poses(arm, np.zeros(arm.dof))[arm.frame_index("upper")] @ np.array([0, 0, 0.1, 1])
    moved = poses[:, arm.frame_index("upper")] @ np.array([0, 0, 0.1, 1])
    np.testing.assert_allclose(moved, np.broadcast_to(centre, moved.shape), atol=1e-14)


def _central_differences(f, q: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """``(n, ..., dof)`` central differences of ``f`` (a function of ``(m, dof)``) at every row of ``q``, one call."""
    n, dof = q.shape
    shifts = step * np.eye(dof)
    batch = np.concatenate([(q[:, None] + shifts).reshape(-1, dof), (q[:, None] - shifts).reshape(-1, dof)])
    out = np.asarray(f(jnp.asarray(batch)))
    plus, minus = out[: n * dof].reshape((n, dof) + out.shape[1:]), out[n * dof :].reshape((n, dof) + out.shape[1:])
    return np.moveaxis((plus - minus) / (2 * step), 1, -1)


def test_jacobian_columns_are_exact(arm, configurations, kinematics):
    q = configurations
    poses, J, J_auto, com, J_com = (np.asarray(x) for x in kinematics(jnp.asarray(q)))
    np.testing.assert_allclose(J, J_auto, rtol=0, atol=1e-12)
    tip_and_com = jax.jit(lambda q: (dk.fk(arm, q, "tip"), dk.com(arm, q)))  # one compile for both differences
    dT = _central_differences(lambda q: tip_and_com(q)[0], q)  # (n, 4, 4, dof)
    T = poses[:, arm.frame_index("tip")]
    W = np.einsum("nijk,nlj->nilk", dT[:, :3, :3], T[:, :3, :3])  # dR R^T: the angular velocity, skew
    expected = np.concatenate([dT[:, :3, 3], np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)], axis=1)
    np.testing.assert_allclose(J, expected, rtol=0, atol=1e-8)
    np.testing.assert_allclose(J_com, _central_differences(lambda q: tip_and_com(q)[1], q), rtol=0, atol=1e-9)
    masses, body_coms = np.asarray(arm.masses), np.asarray(arm.body_coms)
    frames = [arm.frame_index(n) for n in ("world", "upper", "fore", "hand")]  # a body's frame is the body
    bodies = [arm.frame_bodies[f] for f in frames]
    assert masses[bodies].sum() == pytest.approx(masses.sum())  # the bodies between a ball's axes are massless
    moments = sum(
        masses[b] * (poses[:, f, :3, :3] @ body_coms[b] + poses[:, f, :3, 3])
        for f, b in zip(frames, bodies, strict=True)
    )
    np.testing.assert_allclose(com, moments / masses.sum(), rtol=0, atol=1e-14)


def test_derivatives_are_finite_at_zero_rotation(arm):
    def tip_height(q):
        return dk.fk(arm, q, "tip")[2, 3] + dk.jacobian(arm, q, "tip").sum()

    g = np.asarray(jax.jit(jax.grad(tip_height))(jnp.zeros(arm.dof)))
    assert np.all(np.isfinite(g))
    step = 1e-6
    shifted = np.concatenate([np.eye(arm.dof), -np.eye(arm.dof)]) * step
    values = np.asarray(jax.jit(jax.vmap(tip_height))(jnp.asarray(shifted)))
    np.testing.assert_allclose(g, (values[: arm.dof] - values[arm.dof :]) / (2 * step), rtol=0, atol=1e-7)


def test_cone_projection_and_sampling():
    rng = np.random.default_rng(2)
    r = rng.normal(size=(3, 200)) * rng.uniform(0, 4, 200)
    r[:, 0] = 0.0
    inside = np.asarray(_ball.into_cone(jnp.asarray(r), 1.0))
    n, n_in = np.linalg.norm(r, axis=0), np.linalg.norm(inside, axis=0)
    np.testing.assert_allclose(n_in, np.minimum(n, 1.0), atol=1e-15)
    np.testing.assert_allclose(inside[:, n > 0] * n[n > 0], r[:, n > 0] * n_in[n > 0], atol=1e-14)  # same direction
    wrapped = np.asarray(_ball.into_cone(jnp.asarray(r), np.inf))
    assert np.all(np.linalg.norm(wrapped, axis=0) <= np.pi + 1e-12)
    from _reference import rodrigues

    for k in range(1, 200):  # the same rotation
        np.testing.assert_allclose(rodrigues(wrapped[:, k]), rodrigues(r[:, k]), atol=1e-12)
    grad = jax.grad(lambda r: _ball.into_cone(r, 1.0).sum())(jnp.zeros((3, 1)))
    assert np.all(np.isfinite(np.asarray(grad)))
    s = np.asarray(_ball.sample(jax.random.PRNGKey(3), 0.5, 20000, jnp.float64))
    radii = np.linalg.norm(s, axis=0)
    assert radii.max() <= 0.5 and abs(np.mean((radii / 0.5) ** 3) - 0.5) < 0.01  # uniform in the ball
    assert np.all(np.abs(s.mean(axis=1)) < 0.01)


def test_sampled_configurations_keep_the_cone(arm):
    q = np.array(dk.workspace.sample_configs(arm, 2000, jax.random.PRNGKey(4)), np.float64)
    assert np.linalg.norm(q[:, SHOULDER], axis=1).max() <= np.radians(70) + 1e-12
    assert np.linalg.norm(q[:, WRIST], axis=1).max() <= np.pi + 1e-12
    assert np.linalg.norm(q[:, SHOULDER], axis=1).min() < 0.3  # not pushed onto the cone's surface


def test_bad_ball_structures_are_refused(arm):
    with pytest.raises(ValueError, match="a ball joint is three letters"):
        arm.replace(joint_types="BBRRBBBP")
    with pytest.raises(ValueError, match="joint_types\\[0\\]"):  # a ball letter on a prismatic screw
        dataclasses.replace(arm, joint_types="PPPRBBBP")._check(True)
    shifted = np.asarray(arm.screws).copy()
    shifted[1, :3] += 0.1 * np.cross(shifted[1, 3:], [1.0, 0, 0])  # the second axis moved off the centre
    with pytest.raises(ValueError, match="through one point"):
        arm.replace(screws=jnp.asarray(shifted))
    poses = np.asarray(arm.joint_poses).copy()
    poses[1, :3, 3] = 0.2
    with pytest.raises(ValueError, match="poses are the identity"):
        arm.replace(joint_poses=jnp.asarray(poses))


def test_long_paths_with_ball_joints_are_refused():
    body = "".join(f'<body name="b{i}" pos="0 0 .1"><joint name="j{i}" axis="0 1 0"/>' for i in range(40))
    xml = mjcf(f'<body name="root"><joint name="ball" type="ball"/>{body}{"</body>" * 41}')
    robot = dk.load_robot(xml)
    with pytest.raises(ValueError, match="ball joints is not supported"):
        dk.fk(robot, np.zeros(robot.dof), "b39")


def test_a_wrapped_rotation_vector_gives_the_same_pose(arm):
    """A rotation vector longer than pi (as IK may step to) gives the pose of its wrapped twin."""
    q = np.zeros(arm.dof)
    q[WRIST] = [0.0, 3.5, 0.0]
    twin = q.copy()
    twin[WRIST] = np.asarray(_ball.into_cone(jnp.asarray(q[WRIST, None]), np.inf))[:, 0]
    T, T_twin = (np.asarray(dk.fk(arm, x, "tip")) for x in (q, twin))
    assert np.abs(twin[WRIST]).max() < np.pi
    np.testing.assert_allclose(T_twin, T, rtol=0, atol=1e-14)
