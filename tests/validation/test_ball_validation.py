"""Ball joints against MuJoCo (``mj_kinematics``, ``mj_jacBody``/``mj_jacSite``, ``subtree_com``) at random
quaternions, on dm_control's published model with ball joints and on a tree of ball, hinge and slide joints;
IK over ball joints within their cones."""

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from _models import success_rate

import diffkin as dk

pytest.importorskip("dm_control")
import dm_control  # noqa: E402

BALLS = os.path.join(os.path.dirname(dm_control.__file__), "mujoco", "testing", "assets", "model_with_ball_joints.xml")
# The unit tests' arm (tests/unit/test_ball.py), with its ranges in degrees: a limited ball joint about an
# off-origin centre, a hinge, an unlimited ball joint and a slide in one body.
ARM = (
    "<mujoco model='m'><compiler boundmass='1' boundinertia='0.1'/><worldbody>"
    '<body name="upper" pos="0 0 1" euler="10 20 30"><joint name="shoulder" type="ball" pos="0 0 .1" range="0 70"/>'
    '<geom size=".05" mass="1"/><body name="fore" pos="0 .1 -.5"><joint name="elbow" axis="0 1 0" range="-150 0"/>'
    '<geom size=".05" pos="0 0 -.2" mass="1"/><body name="hand" pos="0 0 -.4"><joint name="wrist" type="ball" '
    'pos=".01 0 0"/><joint name="slide" type="slide" axis="0 0 1" range="-.1 .1"/><geom size=".04" mass=".5"/>'
    '<site name="tip" pos="0 .05 -.1"/></body></body></body></worldbody></mujoco>'
)


def _left_jacobian(r: np.ndarray) -> np.ndarray:
    """``J_l(r) = I + (1 - cos t)/t^2 [r] + (t - sin t)/t^3 [r]^2`` (closed form; ``I`` at ``r = 0``)."""
    t = np.linalg.norm(r)
    K = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    if t < 1e-8:
        return np.eye(3) + K / 2
    return np.eye(3) + (1 - np.cos(t)) / t**2 * K + (t - np.sin(t)) / t**3 * K @ K


def _rotation_vector(quat: np.ndarray) -> np.ndarray:
    """The rotation vector (``|r| <= pi``) of a unit quaternion ``(w, x, y, z)``."""
    w, v = (quat[0], quat[1:]) if quat[0] >= 0 else (-quat[0], -quat[1:])
    s = np.linalg.norm(v)
    return np.zeros(3) if s == 0 else 2 * np.arctan2(s, w) * v / s


def _mujoco(robot, model, q: np.ndarray):
    """MuJoCo's poses ``{name: (4, 4)}`` of every body and named site, Jacobians ``{name: (6, dof)}`` mapped to
    diffkin's ``q`` (a ball joint's velocity is ``J_r(r) dr`` in its body, ``J_r = J_l^T``) and centre of mass,
    at the ``qpos`` of ``q`` (quaternions of the rotation vectors)."""
    data = mujoco.MjData(model)
    M = np.zeros((model.nv, robot.dof))  # d qvel / d q
    for j in range(model.njnt):
        name, a, v = model.joint(j).name, model.jnt_qposadr[j], model.jnt_dofadr[j]
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            i = robot.joint_names.index(f"{name}:rx")
            r = q[i : i + 3]
            t = np.linalg.norm(r)
            data.qpos[a : a + 4] = [np.cos(t / 2), *(np.sin(t / 2) * r / t if t > 0 else np.zeros(3))]
            M[v : v + 3, i : i + 3] = _left_jacobian(r).T
        else:
            i = robot.joint_names.index(name)
            data.qpos[a], M[v, i] = q[i], 1.0
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    poses, jacobians = {}, {}
    for kind, count, xpos, xmat, jac in (
        ("body", model.nbody, data.xpos, data.xmat, mujoco.mj_jacBody),
        ("site", model.nsite, data.site_xpos, data.site_xmat, mujoco.mj_jacSite),
    ):
        for k in range(count):
            name = getattr(model, kind)(k).name or (f"body{k}" if kind == "body" else "")
            if not name or (kind == "body" and k == 0):
                continue
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = xmat[k].reshape(3, 3), xpos[k]
            jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
            jac(model, data, jacp, jacr, k)
            poses[name], jacobians[name] = T, np.vstack([jacp, jacr]) @ M
    return poses, jacobians, data.subtree_com[0].copy()


def _random_rotation_vectors(rng, n: int) -> np.ndarray:
    """``(n, 3)`` rotation vectors of uniformly random quaternions (MuJoCo's ``qpos`` of a ball joint)."""
    quats = rng.normal(size=(n, 4))
    return np.stack([_rotation_vector(x / np.linalg.norm(x)) for x in quats])


@pytest.mark.parametrize("source", ["dm_control balls", "arm"])
def test_ball_joints_match_mujoco(source):
    if source == "arm":
        robot, model = dk.load_robot(ARM), mujoco.MjModel.from_xml_string(ARM)
    else:
        robot, model = dk.load_robot(BALLS), mujoco.MjModel.from_xml_path(BALLS)
    rng = np.random.default_rng(0)
    n = 12
    q = rng.uniform(-0.1, 0.1, (n, robot.dof))  # the slide within its range
    for i in (i for i, t in enumerate(robot.actuated_types) if t == "B" and robot.joint_names[i].endswith(":rx")):
        q[:, i : i + 3] = _random_rotation_vectors(rng, n)
    q[0, :] = 0.0  # the identity quaternion
    names = [n for n in robot.frame_names if n != "world"]
    poses = np.asarray(jax.jit(lambda q: dk.fk(robot, q, names))(jnp.asarray(q)))
    J = np.asarray(jax.jit(jax.vmap(lambda q: jnp.stack([dk.jacobian(robot, q, f) for f in names])))(jnp.asarray(q)))
    com = np.asarray(dk.com(robot, q))
    for k in range(n):
        ref_poses, ref_J, ref_com = _mujoco(robot, model, q[k])
        assert set(ref_poses) == set(names)
        for f, name in enumerate(names):
            np.testing.assert_allclose(poses[k, f], ref_poses[name], rtol=0, atol=1e-12, err_msg=name)
            np.testing.assert_allclose(J[k, f], ref_J[name], rtol=0, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(com[k], ref_com, rtol=0, atol=1e-12)


def test_ik_over_ball_joints_keeps_their_cones():
    robot = dk.load_robot(ARM)
    q_true = dk.workspace.sample_configs(robot, 32, jax.random.PRNGKey(5))
    targets = dk.fk(robot, q_true, "tip")
    result = dk.ik.solve(robot, {"tip": targets}, key=jax.random.PRNGKey(6))
    assert success_rate(result.success) >= 0.95
    q = np.asarray(result.q)
    assert np.linalg.norm(q[:, 0:3], axis=1).max() <= np.radians(70) + 1e-12  # the shoulder's cone
    assert np.linalg.norm(q[:, 4:7], axis=1).max() <= np.pi + 1e-12  # the unlimited wrist: one turn
    reached = np.asarray(dk.fk(robot, result.q, "tip"))[np.asarray(result.success)]
    wanted = np.asarray(targets)[np.asarray(result.success)]
    assert np.abs(reached[:, :3, 3] - wanted[:, :3, 3]).max() < 1e-5
