"""dk.ik.step against mink (MuJoCo's Jacobian, the daqp active-set QP solver) on the Panda arm of
example-robot-data: the hand's position tracked with damping (so that the step is unique), position
limits over the step (mink's ``ConfigurationLimit`` with gain 1) and the URDF's velocity limits (diffkin
reads them from the file, mink is given them), in float64; and on the Unitree G1 humanoid with a floating
base (``solve_base``; MuJoCo's free joint), its feet, wrists and torso tracked.

mink's frame task measures its error in the frame's own axes with the SE(3) log's Jacobian; the
position task here is mink's ``Task`` with diffkin's error (world position, ``p - p_t``) and MuJoCo's
body Jacobian, so that both solve the same QP: that compares the Jacobians and the QPs.
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

mink = pytest.importorskip("mink")
mujoco = pytest.importorskip("mujoco")

PANDA = os.path.join(ERD or "", "panda_description/urdf/panda.urdf")
pytestmark = pytest.mark.skipif(not ERD or not os.path.exists(PANDA), reason="example-robot-data is not installed")

DT, DAMPING = 0.01, 1e-3
VELOCITY = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])  # the URDF's (rad/s)


def _arm_urdf() -> str:
    """The Panda without its fingers, meshes and static-body fusion (MuJoCo keeps the hand's body)."""
    with open(PANDA) as f:
        text = f.read()
    for pattern in (
        r"<visual>.*?</visual>",
        r"<collision>.*?</collision>",
        r'<link name="panda_(left|right)finger">.*?</link>',
        r'<joint name="panda_finger_joint[12]".*?</joint>',
    ):
        text = re.sub(pattern, "", text, flags=re.S)
    return text.replace("</robot>", '<mujoco><compiler fusestatic="false"/></mujoco></robot>')


if ERD and os.path.exists(PANDA):
    URDF = _arm_urdf()
    ROBOT = dk.load_robot(URDF)
    MODEL = mujoco.MjModel.from_xml_string(URDF)


class _Position(mink.Task if mink else object):  # type: ignore[misc]
    """A body's world position (the Panda's hand by default): error ``p - p_t``, MuJoCo's body Jacobian."""

    def __init__(self, target, model=None, body="panda_hand"):
        super().__init__(cost=np.ones(3), gain=1.0, lm_damping=0.0)
        self.model = MODEL if model is None else model
        self.target, self.body = np.asarray(target), self.model.body(body).id

    def compute_error(self, configuration):
        return configuration.data.xpos[self.body] - self.target

    def compute_jacobian(self, configuration):
        jacp = np.zeros((3, self.model.nv))
        mujoco.mj_jacBody(self.model, configuration.data, jacp, None, self.body)
        return jacp


def _mink_v(q, target) -> np.ndarray:
    configuration = mink.Configuration(MODEL, np.asarray(q))
    limits = [
        mink.ConfigurationLimit(MODEL, gain=1.0),
        mink.VelocityLimit(MODEL, {f"panda_joint{i + 1}": VELOCITY[i] for i in range(7)}),
    ]
    return mink.solve_ik(configuration, [_Position(target)], DT, "daqp", damping=DAMPING, limits=limits)


@jax.jit
def _step(q, target):  # the velocity limits: the URDF's, read by dk.load_robot (test_matches_mink checks them)
    return dk.ik.step(ROBOT, q, {"panda_hand": target}, dt=DT, damping=DAMPING)


def _cases():
    rng = np.random.default_rng(0)
    lower, upper = np.asarray(MODEL.jnt_range).T
    q = rng.uniform(lower + 0.05, upper - 0.05, (12, 7))
    q[8:] = np.where(rng.uniform(size=(4, 7)) < 0.5, lower + 1e-3, upper - 1e-3)  # near the limits
    hand = np.asarray(dk.fk(ROBOT, jnp.asarray(q), "panda_hand"))[:, :3, 3]
    moves = rng.normal(size=(12, 3))
    size = np.r_[np.full(4, 0.005), np.full(4, 0.2), np.full(4, 0.05)]  # small, then velocity limits bind
    return q, hand + moves / np.linalg.norm(moves, axis=1, keepdims=True) * size[:, None]


def test_matches_mink():
    assert np.asarray(ROBOT.velocity).tolist() == VELOCITY.tolist()  # mink is given the file's limits
    q, targets = _cases()
    out = _step(jnp.asarray(q), jnp.asarray(targets))
    bound = 0
    for k in range(len(q)):
        v_mink = _mink_v(q[k], targets[k])
        np.testing.assert_allclose(np.asarray(out.v[k]), v_mink, atol=1e-9 * (1 + np.abs(v_mink).max()))
        bound += int(np.any(np.isclose(np.abs(v_mink), VELOCITY)))
    assert bound >= 4  # the velocity limits bind in several cases
    assert bool(jnp.all(out.feasible))
    lower, upper = np.asarray(MODEL.jnt_range).T
    assert np.all(np.asarray(out.q) >= lower) and np.all(np.asarray(out.q) <= upper)
    assert np.all(np.abs(np.asarray(out.v)) <= VELOCITY)


G1 = os.path.join(ERD or "", "g1_description/urdf/g1_29dof_rev_1_0.urdf")
G1_FRAMES = (
    "left_ankle_roll_link",
    "right_ankle_roll_link",
    "left_wrist_yaw_link",
    "right_wrist_yaw_link",
    "torso_link",
)


def _g1_urdf() -> str:
    """The G1 with its floating joint (commented out in the file: "uncomment when convert to mujoco"),
    without meshes and static-body fusion."""
    with open(G1) as f:
        text = f.read()
    text = re.sub(r"<!-- (<link name=\"world\"></link>.*?</joint>) -->", r"\1", text, count=1, flags=re.S)
    for pattern in (r"<visual>.*?</visual>", r"<collision>.*?</collision>"):
        text = re.sub(pattern, "", text, flags=re.S)
    return text.replace("</robot>", '<mujoco><compiler fusestatic="false"/></mujoco></robot>')


@pytest.fixture(scope="module")
def g1():
    if not os.path.exists(G1):
        pytest.skip("example-robot-data has no G1")
    text = _g1_urdf()
    robot, model = dk.load_robot(text), mujoco.MjModel.from_xml_string(text)
    assert robot.floating and model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    return robot, model


def _g1_mink_v(robot, model, q, T, targets) -> np.ndarray:
    """mink's step as diffkin's ``v``: the free joint's world linear velocity turned into the root's axes
    (its angular velocity is in the root's axes already), then the joints by name."""
    names = robot.joint_names
    qpos = np.zeros(model.nq)
    qpos[[model.joint(n).qposadr[0] for n in names]] = q
    qpos[:3] = T[:3, 3]
    mujoco.mju_mat2Quat(qpos[3:7], T[:3, :3].flatten())
    configuration = mink.Configuration(model, qpos)
    velocity = np.asarray(robot.velocity)
    limits = [
        mink.ConfigurationLimit(model, gain=1.0),
        mink.VelocityLimit(model, {n: velocity[i] for i, n in enumerate(names)}),
    ]
    tasks = [_Position(targets[i], model, frame) for i, frame in enumerate(G1_FRAMES)]
    v = mink.solve_ik(configuration, tasks, DT, "daqp", damping=DAMPING, limits=limits)
    return np.r_[T[:3, :3].T @ v[:3], v[3:6], v[[model.joint(n).dofadr[0] for n in names]]]


def test_floating_humanoid_matches_mink(g1):
    """The G1's root and 29 joints in one step (``solve_base``): mink's to 1e-8 of the largest velocity
    (the issue's QP accuracy; they agree to 6e-14, velocities up to 73: both QPs are active-set methods,
    exact to rounding), the file's velocity limits binding in several."""
    robot, model = g1
    rng = np.random.default_rng(0)
    lower, upper = np.asarray(robot.lower), np.asarray(robot.upper)
    q = rng.uniform(lower + 0.05, upper - 0.05, (12, robot.dof))
    q[8:] = np.where(rng.uniform(size=(4, robot.dof)) < 0.5, lower + 1e-3, upper - 1e-3)  # near the limits
    axes = rng.normal(size=(12, 3))
    angles = rng.uniform(0, 1, 12)
    T = np.stack([np.eye(4)] * 12)
    T[:, :3, :3] = [rodrigues(a / np.linalg.norm(a) * t) for a, t in zip(axes, angles, strict=True)]
    T[:, :3, 3] = rng.normal(size=(12, 3)) * 0.3
    P = np.asarray(dk.fk(robot, jnp.asarray(q), G1_FRAMES, base=jnp.asarray(T)))[..., :3, 3]
    moves = rng.normal(size=(12, len(G1_FRAMES), 3))
    size = np.r_[np.full(4, 0.005), np.full(4, 0.3), np.full(4, 0.05)]  # small, then velocity limits bind
    targets = P + moves / np.linalg.norm(moves, axis=-1, keepdims=True) * size[:, None, None]
    out = dk.ik.step(
        robot,
        jnp.asarray(q),
        {f: jnp.asarray(targets[:, i]) for i, f in enumerate(G1_FRAMES)},
        dt=DT,
        base=jnp.asarray(T),
        solve_base=True,
        damping=DAMPING,
    )
    assert out.v.shape == (12, 6 + robot.dof) and out.base.shape == (12, 4, 4)
    bound = 0
    for k in range(12):
        v_mink = _g1_mink_v(robot, model, q[k], T[k], targets[k])
        np.testing.assert_allclose(np.asarray(out.v[k]), v_mink, atol=1e-8 * (1 + np.abs(v_mink).max()))
        bound += int(np.any(np.isclose(np.abs(v_mink[6:]), np.asarray(robot.velocity))))
    assert bound >= 4
    assert bool(jnp.all(out.feasible))
    assert np.all(np.asarray(out.q) >= lower) and np.all(np.asarray(out.q) <= upper)
    assert np.all(np.abs(np.asarray(out.v[:, 6:])) <= np.asarray(robot.velocity))
