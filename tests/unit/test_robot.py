"""Whole robots (trees, mimic joints, floating roots): finite differences, chains cut from trees, the centre
of mass's gradients, and bad input (every frame and Jacobian against Pinocchio on the URDFs of
example-robot-data: ``tests/validation/test_robot_validation.py``)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import PANDA
from _models import random_robot_q as _random_q

import diffkin as dk
from diffkin import se3


@pytest.fixture(scope="module")
def panda():
    """The Panda with its gripper: a tree (two fingers), one mimic joint (finger 2 follows finger 1)."""
    return dk.load_robot(PANDA)


def test_panda_tree_structure(panda):
    assert panda.dof == 8 and panda.joint_names[-1] == "panda_finger_joint1"
    assert panda.mimic == {"panda_finger_joint2": ("panda_finger_joint1", 1.0, 0.0)}
    assert panda.frame_names[0] == "panda_link0" and "panda_hand_tcp" in panda.frame_names
    assert not panda.floating and dk.load_robot(PANDA, floating=True).floating


def test_chain_of_a_tree_is_the_path(panda):
    """``robot.chain(end, base)`` (product of exponentials) against the tree's own forward pass."""
    q = _random_q(panda, 16, seed=3)
    names = panda.frame_names
    poses = np.asarray(dk.link_poses(panda, q))
    for end, base in (
        ("panda_hand_tcp", None),
        ("panda_link8", "panda_link2"),
        ("panda_leftfinger", "panda_hand"),
        ("panda_rightfinger", None),
    ):
        chain = panda.chain(end, base)
        cols = [panda.joint_names.index(n) for n in chain.joint_names]
        T_base = poses[:, names.index(base or names[0])]
        expected = np.linalg.inv(T_base) @ poses[:, names.index(end)]
        np.testing.assert_allclose(dk.fk(chain, q[:, cols]), expected, atol=1e-12)
        assert chain.dof == len(cols)
    right = panda.chain("panda_rightfinger", "panda_hand")  # the mimic joint, folded into its source
    assert right.joint_names == ("panda_finger_joint1",) and right.joint_types == "P"


def test_fk_of_several_frames_and_batches(panda):
    q = _random_q(panda, 6, seed=4).reshape(2, 3, 8)
    both = dk.fk(panda, q, ["panda_leftfinger", "panda_link3"])
    assert both.shape == (2, 3, 2, 4, 4)
    np.testing.assert_allclose(both[..., 1, :, :], dk.fk(panda, q, "panda_link3"), atol=1e-15)
    assert dk.link_poses(panda, q).shape == (2, 3, len(panda.frame_names), 4, 4)
    assert dk.jacobian(panda, q, "panda_hand_tcp").shape == (2, 3, 6, 8)
    assert dk.manipulability(panda, q, "panda_hand_tcp").shape == (2, 3)


def _fd_columns(pose_of, x, eps=1e-6):
    """Central differences of a pose function of a vector ``x``: world-aligned ``[dp; w]`` columns."""
    cols = []
    T = pose_of(x)
    for i in range(len(x)):
        dx = np.zeros(len(x))
        dx[i] = eps
        dT = (pose_of(x + dx) - pose_of(x - dx)) / (2 * eps)
        cols.append(np.concatenate([dT[:3, 3], se3.vee(dT[:3, :3] @ T[:3, :3].T)]))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("method", ["analytic", "autodiff"])
def test_mimic_columns_match_finite_differences(panda, method):
    """Finger 2 follows finger 1: the Jacobian of the right finger moves with joint 1's column."""
    q = _random_q(panda, 1, seed=5)[0]
    for name in ("panda_rightfinger", "panda_leftfinger", "panda_link5"):
        J = np.asarray(dk.jacobian(panda, q, name, method=method))
        fd = _fd_columns(lambda x, name=name: np.asarray(dk.fk(panda, x, name)), q)
        np.testing.assert_allclose(J, fd, atol=1e-8)
    assert np.abs(np.asarray(dk.jacobian(panda, q, "panda_link5"))[:, 5:]).max() == 0.0  # joints off the path


@pytest.mark.parametrize("method", ["analytic", "autodiff"])
@pytest.mark.parametrize("ref", ["world", "space", "body"])
def test_floating_base_columns(panda, method, ref):
    """``include_base``: the root moving as ``T_world_root exp([V] t)``; against finite differences."""
    robot = dk.load_robot(PANDA, floating=True)
    rng = np.random.default_rng(6)
    q = _random_q(robot, 1, seed=6)[0]
    base = np.asarray(jax.scipy.linalg.expm(se3.skew(rng.normal(size=3)) * 1.0))
    T_wr = np.eye(4)
    T_wr[:3, :3], T_wr[:3, 3] = base, rng.normal(size=3)

    def moved(V):
        twist = np.zeros((4, 4))
        twist[:3, :3], twist[:3, 3] = se3.skew(V[3:]), V[:3]
        return np.asarray(dk.fk(robot, q, "panda_hand_tcp", base=T_wr @ np.asarray(jax.scipy.linalg.expm(twist))))

    J = np.asarray(dk.jacobian(robot, q, "panda_hand_tcp", ref, method=method, base=T_wr, include_base=True))
    fd = _fd_columns(moved, np.zeros(6))  # world-aligned columns of the root's body twist
    T = moved(np.zeros(6))
    if ref == "space":
        fd = np.concatenate([fd[:3] + np.cross(fd[3:].T, T[:3, 3]).T * -1, fd[3:]])  # v_s = v_p - w x p
    if ref == "body":
        fd = np.concatenate([T[:3, :3].T @ fd[:3], T[:3, :3].T @ fd[3:]])
    assert J.shape == (6, 6 + robot.dof)
    np.testing.assert_allclose(J[:, :6], fd, atol=1e-8)
    np.testing.assert_allclose(J[:, 6:], dk.jacobian(robot, q, "panda_hand_tcp", ref, base=T_wr), atol=1e-12)
    np.testing.assert_allclose(
        dk.fk(robot, q, "panda_hand_tcp", base=T_wr), T_wr @ np.asarray(dk.fk(robot, q, "panda_hand_tcp")), atol=1e-14
    )


def test_jit_argument_or_closure_and_parameter_gradients(panda):
    """One compiled function serves a robot passed as an argument; gradients reach its arrays."""
    q = jnp.asarray(_random_q(panda, 4, seed=7))
    closed = jax.jit(lambda q: dk.fk(panda, q, "panda_hand_tcp"))(q)
    passed = jax.jit(lambda r, q: dk.fk(r, q, "panda_hand_tcp"))(panda, q)
    np.testing.assert_allclose(closed, passed, atol=1e-14)
    np.testing.assert_allclose(passed, dk.fk(panda, q, "panda_hand_tcp"), atol=1e-14)

    def reach(poses):
        return jnp.sum(dk.fk(panda.replace(joint_poses=poses), q, "panda_hand_tcp")[..., :3, 3])

    g = jax.grad(reach)(panda.joint_poses)
    eps, j = 1e-6, 3
    bumped = panda.joint_poses.at[j, 0, 3].add(eps)
    fd = (reach(bumped) - reach(panda.joint_poses.at[j, 0, 3].add(-eps))) / (2 * eps)
    np.testing.assert_allclose(g[j, 0, 3], fd, rtol=1e-7)


def test_com_gradients_with_respect_to_masses_match_finite_differences(panda):
    """Identification: d com / d masses (and body_coms) against central differences, float64."""
    q = _random_q(panda, 4, seed=3)

    def centre(masses, body_coms):
        return dk.com(dataclasses.replace(panda, masses=masses, body_coms=body_coms), q)

    m, c = panda.masses, panda.body_coms
    dm, dc = jax.jacfwd(centre, argnums=(0, 1))(m, c)
    eps = 1e-6
    for b in range(len(m)):
        step = jnp.zeros_like(m).at[b].set(eps)
        np.testing.assert_allclose(dm[..., b], (centre(m + step, c) - centre(m - step, c)) / (2 * eps), atol=1e-9)
        step = jnp.zeros_like(c).at[b, 1].set(eps)
        np.testing.assert_allclose(dc[..., b, 1], (centre(m, c + step) - centre(m, c - step)) / (2 * eps), atol=1e-9)


def test_com_refuses_what_has_no_masses():
    chain = dk.load_urdf(PANDA, "panda_link8")
    with pytest.raises(TypeError, match="needs a Robot"):
        dk.com(chain, np.zeros(7))
    massless = dk.load_robot(_urdf(_joint("j", "revolute", "a", "b", '<axis xyz="0 0 1"/>')))
    with pytest.raises(ValueError, match="masses sum to 0"):
        dk.com_jacobian(massless, np.zeros(1))
    bad = _urdf("", ["a"]).replace('<link name="a"/>', '<link name="a"><inertial><mass value="-1"/></inertial></link>')
    with pytest.raises(ValueError, match=r"link 'a' <inertial> <mass> value: expected a non-negative mass"):
        dk.load_robot(bad)


def test_com_of_tiny_masses_is_their_centre_not_zero():
    """Masses below 1e-12 kg still weigh: only exact zeros fold away (issue 56)."""
    inertial = '<inertial><origin xyz="0 0 {z}"/><mass value="{m}"/></inertial>'
    urdf = _urdf(_joint("j", REV, "a", "b", '<axis xyz="0 0 1"/>'))
    urdf = urdf.replace('<link name="a"/>', f'<link name="a">{inertial.format(z=0, m=1e-13)}</link>')
    urdf = urdf.replace('<link name="b"/>', f'<link name="b">{inertial.format(z=1, m=1e-13)}</link>')
    robot = dk.load_robot(urdf)
    np.testing.assert_allclose(dk.com(robot, np.zeros(1)), [0.0, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(dk.com_jacobian(robot, np.zeros(1)), np.zeros((3, 1)), atol=1e-12)


def _urdf(joints: str, links=None) -> str:
    import re

    names = links or dict.fromkeys(re.findall(r'link="(\w+)"', joints))
    return '<robot name="r">' + "".join(f'<link name="{n}"/>' for n in names) + joints + "</robot>"


def _joint(name, kind, parent, child, extra=""):
    limit = '<limit lower="-1" upper="1"/>' if kind in ("revolute", "prismatic") else ""
    return f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{limit}{extra}</joint>'


REV, FIX = "revolute", "fixed"


@pytest.mark.parametrize(
    "xml, match",
    [
        (
            _urdf(_joint("j1", REV, "a", "b") + _joint("j2", REV, "b", "c") + _joint("j3", FIX, "c", "b")),
            r"link 'b' is the child of two joints \('j1', 'j3'\)",
        ),
        (
            _urdf(_joint("j1", REV, "a", "b") + _joint("j2", REV, "b", "c") + _joint("j3", FIX, "c", "a")),
            r"no root link",
        ),
        (
            _urdf(
                _joint("j1", REV, "a", "b") + _joint("j2", REV, "c", "d") + _joint("j3", FIX, "d", "c"),
                ["a", "b", "c", "d"],
            ),
            r"link 'c' is the child of two joints|not connected to the root",
        ),
        (_urdf(_joint("j1", REV, "a", "a")), r"joint 'j1' connects link 'a' to itself"),
        (
            _urdf(_joint("j1", REV, "a", "b") + _joint("j2", REV, "c", "d")),
            r"expected one root link, found 2: \['a', 'c'\]",
        ),
        (_urdf(_joint("j1", REV, "a", "b"), ["a", "b", "a"]), r"duplicate link name 'a'"),
        (_urdf(_joint("j1", REV, "a", "b") + _joint("j1", REV, "b", "c")), r"duplicate joint name 'j1'"),
        (
            _urdf(_joint("j1", REV, "a", "b") + _joint("j2", REV, "b", "c", '<mimic joint="nope"/>')),
            r"joint 'j2' mimics 'nope', which is not a joint of the robot",
        ),
        (
            _urdf(
                _joint("j0", REV, "a", "b")
                + _joint("j1", REV, "b", "c", '<mimic joint="j2"/>')
                + _joint("j2", REV, "c", "d", '<mimic joint="j1"/>')
            ),
            r"mimic joints form a cycle: j1 -> j2 -> j1",
        ),
        (
            _urdf(_joint("j1", FIX, "a", "b") + _joint("j2", REV, "b", "c", '<mimic joint="j1"/>')),
            r"joint 'j2' mimics 'j1', a fixed joint",
        ),
    ],
)
def test_bad_trees_are_rejected(xml, match):
    with pytest.raises(ValueError, match=match):
        dk.load_robot(xml)


def test_bad_calls_are_rejected(panda):
    q = np.zeros(8)
    with pytest.raises(
        ValueError,
        match=r"^unknown frame 'hand': the robot has 13 frames, the closest names are 'panda_hand', 'panda_hand_tcp'$",
    ):
        dk.fk(panda, q, "hand")
    with pytest.raises(ValueError, match=r"^unknown frame 'panda_hnd': .* closest names are 'panda_hand', "):
        dk.jacobian(panda, q, "panda_hnd")  # a typo: the most similar name first
    with pytest.raises(ValueError, match=r"13 frames, none named like it \(the first: 'panda_link0', 'panda_link1', "):
        dk.fk(panda, q, ["panda_hand", "qqq"])  # one unknown name in a list
    with pytest.raises(ValueError, match=r"q: expected shape \(\.\.\., 8\) for a 8-joint robot, got \(7,\)"):
        dk.fk(panda, np.zeros(7), "panda_hand")
    with pytest.raises(ValueError, match="frames: name the frame"):
        dk.fk(panda, q)
    with pytest.raises(TypeError, match="frame_name: name the frame of the robot"):
        dk.jacobian(panda, q)
    with pytest.raises(ValueError, match="frame: expected one of"):
        dk.jacobian(panda, q, "panda_hand", "tool")
    with pytest.raises(ValueError, match=r"base: expected a \(\.\.\., 4, 4\) pose"):
        dk.fk(panda, q, "panda_hand", base=np.eye(3))
    with pytest.raises(ValueError, match="include_base: only a Robot"):
        dk.jacobian(dk.robots.iiwa14(), np.zeros(7), include_base=True)
    with pytest.raises(TypeError, match=r"target: for a Robot, expected a non-empty mapping frame name -> target"):
        dk.ik.solve(panda, np.eye(4))
    with pytest.raises(ValueError, match="source: expected a <robot> \\(URDF\\)"):
        dk.load_robot("<model/>")


def test_a_robot_without_joints():
    robot = dk.load_robot(_urdf(_joint("j", "fixed", "a", "b", '<origin xyz="1 2 3"/>')))
    assert robot.dof == 0 and robot.frame_names == ("a", "b")
    np.testing.assert_allclose(dk.fk(robot, np.zeros((2, 0)), "b")[:, :3, 3], [[1, 2, 3]] * 2)
    assert dk.jacobian(robot, np.zeros(0), "b").shape == (6, 0)


def test_a_float32_model_with_float64_q_warns():
    """A model built before x64 was switched on holds float32 numbers: float64 FK is then only ~1e-7 exact."""
    with jax.enable_x64(False):
        chain32, robot32 = dk.robots.iiwa14(), dk.load_robot(PANDA)
    for model, frame in ((chain32, ()), (robot32, ("panda_hand",))):
        with pytest.warns(UserWarning, match="built before jax_enable_x64"):
            dk.fk(model, np.zeros(model.dof), *frame)
    dk.fk(dk.robots.iiwa14(), np.zeros(7))  # float64 model: no warning (warnings are errors in the tests)
    dk.fk(chain32, np.zeros(7, np.float32))  # float32 q: no warning
