"""Whole robots against Pinocchio: every frame and Jacobian of the URDFs of example-robot-data (centre of
mass too), URDF limits (positions and velocities) as urdfdom reads them, the files that are rejected, and
IK of a long serial path."""

import glob
import os

import jax
import numpy as np
import pinocchio as pin
import pytest
from _models import ERD, snake_robot
from _models import random_robot_q as _random_q
from _reference import pin_q as _pin_q
from _reference import robot_poses

import diffkin as dk
from diffkin.models import _scanned

ERD_URDFS = sorted(glob.glob(os.path.join(ERD, "**", "*.urdf"), recursive=True)) if ERD else []
# Files of example-robot-data that are not loadable robots, and why (checked in test_rejected_files).
REJECTED = {
    "alex_description/urdf/alex_psyonic_hands.urdf": "mimics 'index_q1', which is not a joint of the robot",
    "ur_description/urdf/ur3.urdf": "no links",  # an empty <robot> (a xacro stub)
}
LOADABLE = [p for p in ERD_URDFS if os.path.relpath(p, ERD) not in REJECTED]


def _com_error(robot, model, data, q, base=None) -> float:
    """Largest difference between ``dk.com``/``dk.com_jacobian`` and Pinocchio's ``centerOfMass``/
    ``jacobianCenterOfMass``: a fixed root's link mass (Pinocchio's universe inertia, which its centre
    of mass leaves out) added back; with ``base``, Pinocchio's free-flyer model (body-twist columns)."""
    floating = base is not None
    c, J = dk.com(robot, q, base=base), dk.com_jacobian(robot, q, base=base, include_base=floating)
    m0, p0 = model.inertias[0].mass, model.inertias[0].lever
    worst = 0.0
    for k in range(len(q)):
        qp = _pin_q(model, robot, q[k])
        if floating:
            qp[:7] = pin.SE3ToXYZQUAT(pin.SE3(base[k]))
        c_pin, J_pin = pin.centerOfMass(model, data, qp), pin.jacobianCenterOfMass(model, data, qp)
        M = data.mass[0] + m0
        c_ref = (data.mass[0] * c_pin + m0 * p0) / M
        J_joints = _pin_columns(model, robot, np.vstack([J_pin, np.zeros_like(J_pin)]))[:3]
        J_ref = data.mass[0] / M * (np.hstack([J_pin[:, :6], J_joints]) if floating else J_joints)
        worst = max(worst, np.abs(c_ref - c[k]).max(), np.abs(J_ref - J[k]).max())
    return worst


def _pin_columns(model, robot, J):
    """Pinocchio's ``(6, nv)`` Jacobian as ours: each joint's column, times its multiplier, on its source's column."""
    out = np.zeros((6, robot.dof))
    m = np.asarray(robot.multipliers)
    for j, (name, s) in enumerate(zip(robot.tree_joints, robot.sources, strict=True)):
        out[:, s] += m[j] * J[:, model.joints[model.getJointId(name)].idx_v]
    return out


@pytest.mark.skipif(not ERD, reason="example-robot-data is not installed (pip install -e '.[test]')")
@pytest.mark.parametrize("path", LOADABLE, ids=lambda p: os.path.relpath(p, ERD))
def test_every_frame_and_jacobian_matches_pinocchio(path):
    robot = dk.load_robot(path)
    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    q = _random_q(robot, 3, seed=len(robot.frame_names))
    poses = np.asarray(dk.link_poses(robot, q))
    # Jacobians of the frames farthest down the tree (hands, feet, fingertips, flanges): at most 3.
    depth = [len(robot.ancestors(b)) for b in robot.frame_bodies]
    ends = sorted(range(len(depth)), key=lambda f: -depth[f])[:3] if robot.dof else []  # (Pinocchio: nv > 0)
    jacobians = {
        (f, ref): np.asarray(dk.jacobian(robot, q, robot.frame_names[f], ref))
        for f in ends
        for ref in ("world", "space", "body")
    }
    ref_frames = {"world": pin.LOCAL_WORLD_ALIGNED, "space": pin.WORLD, "body": pin.LOCAL}
    worst_pose = worst_jac = 0.0
    for k in range(len(q)):
        qp = _pin_q(model, robot, q[k])
        pin.framesForwardKinematics(model, data, qp)
        if ends:
            pin.computeJointJacobians(model, data, qp)
        for f, name in enumerate(robot.frame_names):
            M = data.oMf[model.getFrameId(name, pin.BODY)].homogeneous
            worst_pose = max(worst_pose, np.abs(M - poses[k, f]).max())
        for (f, ref), J in jacobians.items():
            J_pin = pin.getFrameJacobian(model, data, model.getFrameId(robot.frame_names[f], pin.BODY), ref_frames[ref])
            worst_jac = max(worst_jac, np.abs(_pin_columns(model, robot, J_pin) - J[k]).max())
    assert worst_pose < 1e-10 and worst_jac < 1e-10, (worst_pose, worst_jac)
    if robot.dof and np.sum(robot.masses) > 0:  # the centre of mass (eager: no compile per robot)
        assert _com_error(robot, model, data, q) < 1e-10
    # the limits of the revolute and prismatic joints (continuous ones: (cos, sin) in Pinocchio), and the
    # velocity limits of every joint (a file's 0: Pinocchio's 0, none for diffkin)
    for i, name in enumerate(robot.joint_names):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 1:
            limits = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
            assert (float(robot.lower[i]), float(robot.upper[i])) == limits, name
        velocity = model.velocityLimit[joint.idx_v]
        assert float(robot.velocity[i]) == (np.inf if velocity == 0 else velocity), name


@pytest.mark.skipif(not ERD, reason="example-robot-data is not installed")
@pytest.mark.parametrize(
    "name",
    ["talos_data/robots/talos_full_v2.urdf", "g1_description/urdf/g1_29dof_with_hand_rev_1_0.urdf", "solo12"],
)
def test_com_of_floating_robots_matches_pinocchio(name):
    path = os.path.join(ERD, "solo_description/robots/solo12.urdf" if name == "solo12" else name)
    robot = dk.load_robot(path, floating=True)
    model = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())
    q = _random_q(robot, 3, seed=7)
    base = np.stack([pin.exp6(v).homogeneous for v in np.random.default_rng(7).normal(size=(3, 6))])
    assert _com_error(robot, model, model.createData(), q, np.asarray(base)) < 1e-10


@pytest.mark.parametrize("kind", ["revolute", "prismatic"])
@pytest.mark.parametrize(
    "attributes", ['upper="1.5"', 'lower="-0.5"', "", 'lower="-2" upper="0.25"', 'upper="1e-3" lower="-1e-3"']
)
def test_urdf_limit_attributes_as_pinocchio_reads_them(kind, attributes):
    """``<limit>``'s ``lower`` and ``upper`` default to 0 each (urdfdom's reading, which Pinocchio uses)."""
    urdf = f"""<robot name="r"><link name="a"/><link name="b"/>
      <joint name="j" type="{kind}"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
        <limit {attributes} effort="1" velocity="1"/></joint></robot>"""
    robot, model = dk.load_robot(urdf), pin.buildModelFromXML(urdf)
    assert (float(robot.lower[0]), float(robot.upper[0])) == (model.lowerPositionLimit[0], model.upperPositionLimit[0])
    chain = dk.load_urdf(urdf)
    assert (float(chain.lower[0]), float(chain.upper[0])) == (model.lowerPositionLimit[0], model.upperPositionLimit[0])


@pytest.mark.skipif(not ERD, reason="example-robot-data is not installed")
def test_panda_velocity_limits_are_pinocchio_s():
    """The Panda's ``<limit velocity=>`` (rad/s, m/s for the finger), exactly Pinocchio's ``velocityLimit``
    by joint name; the finger's mimic joint follows its source (its own limit is not read, as its range)."""
    path = os.path.join(ERD, "panda_description/urdf/panda.urdf")
    robot, model = dk.load_robot(path), pin.buildModelFromUrdf(path)
    assert robot.joint_names[-1] == "panda_finger_joint1" and "panda_finger_joint2" in robot.mimic
    by_name = {name: model.velocityLimit[model.joints[model.getJointId(name)].idx_v] for name in robot.joint_names}
    assert dict(zip(robot.joint_names, np.asarray(robot.velocity).tolist(), strict=True)) == by_name
    assert by_name["panda_joint1"] == 2.175 and by_name["panda_finger_joint1"] == 0.2
    chain = dk.load_urdf(path, "panda_hand")
    assert np.asarray(chain.velocity).tolist() == [by_name[name] for name in chain.joint_names]


_VELOCITY_CASES = [
    ("revolute", 'velocity="2.5"', 2.5),
    ("continuous", 'velocity="2.5"', 2.5),
    ("prismatic", 'velocity="0.25"', 0.25),
    ("revolute", 'velocity="0"', np.inf),  # Pinocchio: 0 (the joint could not move)
    ("continuous", None, np.inf),  # no <limit>: Pinocchio's inf too
]


@pytest.mark.parametrize("kind, attribute, expected", _VELOCITY_CASES)
def test_urdf_velocity_attribute_as_pinocchio_reads_it_but_0_means_none(kind, attribute, expected):
    """``<limit velocity=>`` as urdfdom and Pinocchio read it, except 0: none (``inf``), not a joint held still."""
    limit = "" if attribute is None else f'<limit lower="-1" upper="1" effort="1" {attribute}/>'
    urdf = f"""<robot name="r"><link name="a"/><link name="b"/>
      <joint name="j" type="{kind}"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>{limit}</joint></robot>"""
    robot, model = dk.load_robot(urdf), pin.buildModelFromXML(urdf)
    assert float(robot.velocity[0]) == expected
    assert model.velocityLimit[0] == (0.0 if attribute == 'velocity="0"' else expected)
    assert float(dk.load_urdf(urdf).velocity[0]) == expected


def test_urdf_negative_velocity_limit_is_rejected():
    """A negative ``velocity`` is an error (Pinocchio: "min_velocity greater than max_velocity")."""
    urdf = """<robot name="r"><link name="a"/><link name="b"/>
      <joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="1" velocity="-2"/></joint></robot>"""
    with pytest.raises(ValueError, match=r"URDF joint 'j' <limit> velocity: expected a limit >= 0"):
        dk.load_robot(urdf)
    with pytest.raises(ValueError, match="min_velocity are greater than max_velocity"):
        pin.buildModelFromXML(urdf)


@pytest.mark.parametrize("kind", ["revolute", "prismatic"])
def test_urdf_joint_without_limit_is_unlimited_where_urdfdom_rejects_it(kind):
    """A revolute or prismatic joint without ``<limit>`` loads, unlimited (urdfdom, so Pinocchio, rejects the file)."""
    urdf = f"""<robot name="r"><link name="a"/><link name="b"/>
      <joint name="j" type="{kind}"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>"""
    robot = dk.load_robot(urdf)
    assert (float(robot.lower[0]), float(robot.upper[0]), float(robot.velocity[0])) == (-np.inf, np.inf, np.inf)
    with pytest.raises(ValueError, match="does not contain a valid URDF model"):
        pin.buildModelFromXML(urdf)


@pytest.mark.skipif(not ERD, reason="example-robot-data is not installed")
@pytest.mark.parametrize("name, match", list(REJECTED.items()))
def test_rejected_files(name, match):
    with pytest.raises(ValueError, match=match):
        dk.load_robot(os.path.join(ERD, name))


def test_ik_of_a_long_robot():
    """Inverse kinematics on a scanned robot: a 40-joint snake reaches poses of its own (round trip)."""
    snake = snake_robot(40)
    assert _scanned.longest_path(snake.parents) > _scanned.LONG
    q = np.random.default_rng(3).uniform(-0.5, 0.5, (4, 40))
    targets = np.asarray(dk.fk(snake, q, "l40"))
    result = dk.ik.solve(snake, {"l40": targets}, key=jax.random.PRNGKey(0))
    assert np.all(result.success)
    reached = np.stack([robot_poses(snake, x)[snake.frame_index("l40")] for x in np.asarray(result.q)])
    np.testing.assert_allclose(reached[:, :3, 3], targets[:, :3, 3], atol=1e-5)
