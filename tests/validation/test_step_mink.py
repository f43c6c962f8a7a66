"""dk.ik.step against mink (MuJoCo's Jacobian, the daqp active-set QP solver) on the Panda arm of
example-robot-data: the hand's position tracked with damping (so that the step is unique), position
limits over the step (mink's ``ConfigurationLimit`` with gain 1) and the URDF's velocity limits (diffkin
reads them from the file, mink is given them), in float64.

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
    """The hand's world position: error ``p - p_t``, MuJoCo's body Jacobian."""

    def __init__(self, target):
        super().__init__(cost=np.ones(3), gain=1.0, lm_damping=0.0)
        self.target, self.body = np.asarray(target), MODEL.body("panda_hand").id

    def compute_error(self, configuration):
        return configuration.data.xpos[self.body] - self.target

    def compute_jacobian(self, configuration):
        jacp = np.zeros((3, MODEL.nv))
        mujoco.mj_jacBody(MODEL, configuration.data, jacp, None, self.body)
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
