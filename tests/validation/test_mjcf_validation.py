"""The MJCF reader against MuJoCo itself: body and site poses, world-aligned Jacobians and joint
limits of MJCF snippets (one per feature) and of published dm_control models, in float64 (what needs no
MuJoCo, deep nesting, include bombs and bad input: ``tests/unit/test_mjcf.py``)."""

import os
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
from _mjcf import ARM, HEAD, mjcf
from _mjcf import nested_mjcf as _nested
from _models import random_q
from _paths import DATA

import diffkin as dk
import diffkin.cli

TOL = 1e-10
DM_CONTROL = os.path.join(os.path.dirname(os.path.dirname(mujoco.__file__)), "dm_control")
# ------------------------------------------------------------------------------------- MuJoCo reference


def _name(model, kind: str, i: int) -> str:
    return getattr(model, kind)(i).name or f"{kind}{i}"


def _apply_equalities(model, qpos: np.ndarray, dq: np.ndarray) -> None:
    """Set the joints that MuJoCo's active linear joint and tendon equalities drive (positions and their
    derivatives ``dq`` with respect to diffkin's ``q``), from MuJoCo's compiled ``eq_data``. A tendon
    equality drives the last joint of ``tendon1`` (diffkin's choice), solved by hand so that MuJoCo's residual
    ``L1 - tendon_length0[1] - c0 - c1 (L2 - tendon_length0[2])`` is zero (``L = wrap_prm @ qpos``)."""
    kinds = (int(mujoco.mjtEq.mjEQ_JOINT), int(mujoco.mjtEq.mjEQ_TENDON))
    eqs = [e for e in range(model.neq) if model.eq_type[e] in kinds and model.eq_active0[e]]
    for _ in range(len(eqs)):  # chains of equalities settle in as many sweeps
        for e in eqs:
            c0, c1 = model.eq_data[e, :2]
            if model.eq_type[e] == mujoco.mjtEq.mjEQ_TENDON:
                t1, t2 = model.eq_obj1id[e], model.eq_obj2id[e]
                g, r = _tendon_row(model, t1), -model.tendon_length0[t1] - c0  # residual r + g @ qpos
                if t2 >= 0:
                    g, r = g - c1 * _tendon_row(model, t2), r + c1 * model.tendon_length0[t2]
                a = model.jnt_qposadr[model.wrap_objid[model.tendon_adr[t1] + model.tendon_num[t1] - 1]]
                qpos[a] = -(r + g @ qpos - g[a] * qpos[a]) / g[a]
                dq[a] = -(g @ dq - g[a] * dq[a]) / g[a]
                continue
            a1, j2 = model.jnt_qposadr[model.eq_obj1id[e]], model.eq_obj2id[e]
            if j2 < 0:
                qpos[a1], dq[a1] = model.qpos0[a1] + c0, 0.0
            else:
                a2 = model.jnt_qposadr[j2]
                qpos[a1] = model.qpos0[a1] + c0 + c1 * (qpos[a2] - model.qpos0[a2])
                dq[a1] = c1 * dq[a2]


def _tendon_row(model, t: int) -> np.ndarray:
    """``(nq,)``: a fixed tendon's length is this row times ``qpos`` (MuJoCo's ``wrap_prm`` coefficients)."""
    row = np.zeros(model.nq)
    for w in range(model.tendon_adr[t], model.tendon_adr[t] + model.tendon_num[t]):
        assert model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT
        row[model.jnt_qposadr[model.wrap_objid[w]]] += model.wrap_prm[w]
    return row


def _equality_residual(model, qpos: np.ndarray) -> float:
    """The largest of MuJoCo's equality-constraint residuals (``efc_pos``) at ``qpos``; every active equality
    gives a row."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    rows = data.efc_type[: data.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert rows.sum() == sum(model.eq_active0)
    return float(np.abs(data.efc_pos[: data.nefc][rows]).max())


def mujoco_reference(robot, model, q: np.ndarray, base: np.ndarray | None, frames: list[str]):
    """Poses ``{frame: (4, 4)}`` of MuJoCo's bodies and named sites, the Jacobians ``(6, nv)``
    (world-aligned: ``[jacp; jacr]``) of ``frames`` mapped to diffkin's columns (base columns first
    for a floating robot), and the centre of mass of the robot (``subtree_com`` of the world, or of
    the floating root) with its Jacobian (``mj_jacSubtreeCom``) mapped alike."""
    data = mujoco.MjData(model)
    qpos = model.qpos0.copy()
    nq_dk = robot.dof + (6 if robot.floating else 0)
    dq = np.zeros((model.nq, nq_dk))  # d qpos / d (base twist, q), for scalar joints only
    M = np.zeros((model.nv, nq_dk))  # d qvel / d (base twist, q)
    for j in range(model.njnt):
        a, name = model.jnt_qposadr[j], _name(model, "joint", j)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            qpos[a : a + 3] = base[:3, 3]
            mujoco.mju_mat2Quat(qpos[a + 3 : a + 7], base[:3, :3].flatten())
            v = model.jnt_dofadr[j]
            M[v : v + 3, 0:3] = base[:3, :3]  # MuJoCo: linear velocity in world axes
            M[v + 3 : v + 6, 3:6] = np.eye(3)  # angular velocity in the body frame
        elif name in robot.joint_names:
            i = robot.joint_names.index(name) + (6 if robot.floating else 0)
            qpos[a], dq[a, i] = q[i - (6 if robot.floating else 0)], 1.0
    _apply_equalities(model, qpos, dq)
    for j in range(model.njnt):
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE:
            M[model.jnt_dofadr[j]] = dq[model.jnt_qposadr[j]]
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    poses, ids = {}, {}
    bodies = {_name(model, "body", b) for b in range(model.nbody)}
    for b in range(model.nbody):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
        poses[_name(model, "body", b)] = T
        ids[_name(model, "body", b)] = ("body", b)
    for s in range(model.nsite):
        if model.site(s).name:
            name = model.site(s).name
            name = f"site:{name}" if name in bodies else name
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = data.site_xmat[s].reshape(3, 3), data.site_xpos[s]
            poses[name], ids[name] = T, ("site", s)
    jacobians = {}
    for frame in frames:
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        kind, i = ids[frame]
        (mujoco.mj_jacBody if kind == "body" else mujoco.mj_jacSite)(model, data, jacp, jacr, i)
        jacobians[frame] = np.vstack([jacp, jacr]) @ M
    root = model.jnt_bodyid[0] if robot.floating else 0
    jac_com = np.zeros((3, model.nv))
    mujoco.mj_jacSubtreeCom(model, data, jac_com, root)
    return poses, jacobians, (data.subtree_com[root].copy(), jac_com @ M)


def random_base(rng) -> np.ndarray:
    T = np.eye(4)
    quat = rng.normal(size=4)
    mujoco.mju_quat2Mat(R := np.zeros(9), quat / np.linalg.norm(quat))
    T[:3, :3], T[:3, 3] = R.reshape(3, 3), rng.uniform(-1, 1, 3)
    return T


def against_mujoco(robot, model, n: int = 3, seed: int = 0, frames=None) -> tuple[float, float]:
    """Max errors of every frame's pose and of the Jacobians of ``frames`` (default: all) vs MuJoCo,
    over ``n`` random in-range configurations (and random base poses for a floating robot); also
    checks that the robot has exactly MuJoCo's bodies (below the free body) and named sites."""
    rng = np.random.default_rng(seed)
    Q = random_q(robot, n, seed)
    B = np.stack([random_base(rng) for _ in range(n)]) if robot.floating else None
    frames = list(robot.frame_names) if frames is None else frames
    poses = np.asarray(dk.link_poses(robot, Q, base=B))
    J = {f: np.asarray(dk.jacobian(robot, Q, f, frame="world", base=B, include_base=robot.floating)) for f in frames}
    massive = not robot.unknown_masses and np.sum(robot.masses) > 0
    if massive:  # the centre of mass: every body's mass and centre as MuJoCo compiles them
        com = dk.com(robot, Q, base=B), dk.com_jacobian(robot, Q, base=B, include_base=robot.floating)
    pose_err = jac_err = 0.0
    for k in range(n):
        ref, ref_J, ref_com = mujoco_reference(robot, model, Q[k], None if B is None else B[k], frames)
        if massive:
            jac_err = max(jac_err, np.abs(com[0][k] - ref_com[0]).max(), np.abs(com[1][k] - ref_com[1]).max())
        expected = set(ref) - ({"world"} if robot.floating else set())
        if robot.floating:  # static world bodies are not part of a floating robot
            expected = {f for f in expected if f not in _static_world_frames(model)}
        assert set(robot.frame_names) == expected
        for f, name in enumerate(robot.frame_names):
            pose_err = max(pose_err, np.abs(poses[k, f] - ref[name]).max())
        for name in frames:
            jac_err = max(jac_err, np.abs(J[name][k] - ref_J[name]).max(initial=0.0))
    assert pose_err < TOL and jac_err < TOL, (pose_err, jac_err)
    return pose_err, jac_err


def _static_world_frames(model) -> set[str]:
    """Names of the bodies and sites that no joint moves (fixed to the world)."""
    moving = {b for b in range(model.nbody) if _moves(model, b)}
    bodies = {_name(model, "body", b) for b in range(model.nbody)}
    names = {_name(model, "body", b) for b in range(model.nbody) if b not in moving}
    for s in range(model.nsite):
        if model.site(s).name and model.site_bodyid[s] not in moving:
            names.add(f"site:{model.site(s).name}" if model.site(s).name in bodies else model.site(s).name)
    return names


def _moves(model, b: int) -> bool:
    while b > 0:
        if model.body_jntnum[b]:
            return True
        b = model.body_parentid[b]
    return False


def check_limits(robot, model) -> None:
    ids = {_name(model, "joint", j): j for j in range(model.njnt)}
    for i, name in enumerate(robot.joint_names):
        j = ids[name]
        expected = model.jnt_range[j] if model.jnt_limited[j] else (-np.inf, np.inf)
        np.testing.assert_allclose([robot.lower[i], robot.upper[i]], expected, rtol=0, atol=1e-15)


def check(xml: str, **kw) -> tuple[float, float]:
    robot, model = dk.load_robot(xml), mujoco.MjModel.from_xml_string(xml)
    check_limits(robot, model)
    return against_mujoco(robot, model, **kw)


# --------------------------------------------------------------------------------------------- snippets

ORIENTATIONS = {
    "identity": ("", ""),
    "quat": ('quat="0.3 -0.2 0.5 0.4"', ""),
    "axisangle_degree": ('axisangle="1 -2 .5 70"', ""),
    "axisangle_radian": ('axisangle="1 -2 .5 1.2"', '<compiler angle="radian"/>'),
    "euler_default_xyz": ('euler="30 -45 120"', ""),
    "euler_radian": ('euler=".5 -.7 2.1"', '<compiler angle="radian"/>'),
    "eulerseq_zyx": ('euler="30 -45 120"', '<compiler eulerseq="zyx"/>'),
    "eulerseq_XYZ": ('euler="30 -45 120"', '<compiler eulerseq="XYZ"/>'),
    "eulerseq_ZYX_radian": ('euler=".5 -.7 2.1"', '<compiler angle="radian" eulerseq="ZYX"/>'),
    "eulerseq_mixed_zYx": ('euler="30 -45 120"', '<compiler eulerseq="zYx"/>'),
    "eulerseq_repeated_zxz": ('euler="30 -45 120"', '<compiler eulerseq="zxz"/>'),
    "xyaxes": ('xyaxes="1 1 0 -1 2 .5"', ""),
    "zaxis": ('zaxis="1 -2 .3"', ""),
    "zaxis_up": ('zaxis="0 0 3"', ""),
    "zaxis_down": ('zaxis="0 0 -1"', ""),
}


@pytest.mark.parametrize("form", ORIENTATIONS)
def test_orientation_forms(form):
    o, head = ORIENTATIONS[form]
    check(mjcf(f'<body name="a" pos=".1 .2 .3" {o}>{ARM.format(o=o)}</body>', head))


def test_defaults_nested_classes_and_childclass():
    head = """<default>
      <joint axis="1 0 0" range="-30 30"/>
      <site pos=".1 0 0" euler="0 30 0"/>
      <default class="leg">
        <joint axis="0 1 0"/>
        <default class="knee"><joint pos="0 0 .1" range="-100 5"/><site zaxis="1 1 0"/></default>
      </default>
      <default class="slider"><joint type="slide" axis="0 0 1" range="-.2 .3"/></default>
    </default>"""
    body = """<body name="root" childclass="leg">
      <joint name="hip"/><site name="hip_site"/>
      <body name="shin" pos="0 0 -.4">
        <joint name="knee" class="knee"/><site name="knee_site" class="knee"/>
        <body name="foot" pos="0 .1 -.4" childclass="knee">
          <joint name="ankle"/><joint name="toe" class="main"/><joint name="lift" class="slider"/>
          <site name="toe_site" pos="0 0 -.1"/>
        </body>
      </body>
    </body>"""
    robot = dk.load_robot(mjcf(body, head))
    assert robot.joint_names == ("hip", "knee", "ankle", "toe", "lift")
    assert robot.joint_types == "RRRRP"
    check(mjcf(body, head))


def test_several_joints_in_one_body_slides_and_ref():
    body = """<body name="cart" pos=".2 0 0" euler="10 20 30">
      <joint name="x" type="slide" axis="1 0 0" ref=".4" range="-.5 .5"/>
      <joint name="z" type="slide" axis="0 .3 1" ref="-.1"/>
      <joint name="pitch" axis="0 1 0" pos=".1 .2 0" ref="30" range="-60 60"/>
      <joint name="roll" axis="1 1 0" pos="0 0 .3"/>
      <site name="tip" pos=".3 0 0" euler="0 0 45"/>
      <body name="pole" pos="0 0 .5"><joint name="swing" ref="-20" axis="0 1 0"/></body>
    </body>"""
    robot = dk.load_robot(mjcf(body))
    assert robot.frame_names == ("world", "cart", "pole", "tip")  # no frames for the intermediate bodies
    np.testing.assert_allclose(robot.offsets, [-0.4, 0.1, -np.deg2rad(30), 0.0, np.deg2rad(20)], atol=1e-15)
    check(mjcf(body))


def test_sites_frames_and_names():
    head = (
        '<default><site type="box" size=".1 .1 .1" quat="0 1 0 0"/>'
        '<default class="m"><site pos="0 1 0"/></default></default>'
    )
    body = """<site name="in_world" pos="1 2 3" axisangle="0 0 1 30"/>
    <body pos="0 0 .1"><joint/>
      <site name="a" class="m"/><site name="b" euler="0 90 0" class="m"/><site pos="9 9 9"/>
      <site name="capsule" type="capsule" size=".01" fromto=".1 .2 .3 -.4 .5 .6"/>
      <body name="a"><joint type="slide"/><site name="c" type="capsule" size=".1" fromto="0 0 0 0 0 -1"/></body>
    </body>"""
    robot = dk.load_robot(mjcf(body, head))
    # an unnamed body is body{id}, an unnamed joint joint{id}; a site named like a body is site:{name}
    assert robot.frame_names == ("world", "body1", "a", "in_world", "site:a", "b", "capsule", "c")
    assert robot.joint_names == ("joint0", "joint1")
    check(mjcf(body, head))


def test_frame_elements():
    body = """<frame pos="1 0 0" euler="0 0 90">
      <site name="world_site" pos="0 1 0"/>
      <body name="a" pos=".1 0 0"><joint name="j0"/>
        <frame pos="0 0 .5" axisangle="1 0 0 90" childclass="c">
          <joint name="j1"/><site name="s"/><body name="b" pos="0 .2 0"><joint name="j2"/></body>
        </frame>
        <joint name="j3" type="slide"/>
      </body>
    </frame>"""
    head = '<default><default class="c"><joint axis="0 1 0" pos=".1 0 0"/></default></default>'
    assert dk.load_robot(mjcf(body, head)).joint_names == ("j0", "j1", "j3", "j2")
    check(mjcf(body, head))


MASS_BODY = """
  <body name="torso" pos="0 0 1"><joint name="j0" axis="0 1 0"/>
    <geom type="capsule" fromto="0 0 0 .3 .1 0" size=".05"/>
    <geom class="heavy" type="box" pos=".1 .2 0" size=".1 .05 .02"/>
    <geom type="sphere" pos="0 0 .3" size=".04" group="4"/><geom type="cylinder" pos="0 .1 0" size=".03 .1" mass="2"/>
    <body name="arm" pos=".3 0 0"><joint name="j1" axis="0 0 1"/>
      <inertial pos=".1 .02 0" mass="1.5" diaginertia=".1 .1 .1"/>
      <geom type="ellipsoid" pos=".2 0 0" size=".1 .05 .04"/>
      <frame pos="0 .1 0">
        <body name="hand" pos=".4 0 0"><joint name="j2"/><geom type="sphere" pos=".05 0 0" size=".03"/></body>
      </frame>
    </body>
    <body name="empty" pos="0 0 .2"><joint name="j3" axis="1 0 0"/></body>
  </body>"""


@pytest.mark.parametrize(
    "compiler",
    [
        "",
        '<compiler inertiafromgeom="true"/>',
        '<compiler inertiagrouprange="0 3"/>',
        '<compiler boundmass="0.7" boundinertia="0.1" settotalmass="9"/>',
    ],
    ids=["auto", "from-geoms", "group-range", "bound-and-total"],
)
def test_masses_and_centres_of_mass_as_mujoco_compiles_them(compiler, tmp_path, monkeypatch):
    """Inertials, geom volumes (fromto, every primitive), mass and density from classes, group ranges,
    boundmass and settotalmass: the centre of mass and its Jacobian against MuJoCo's."""
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its deprecation warning to ./MUJOCO_LOG.TXT
    head = compiler + '<default><default class="heavy"><geom density="3000"/></default></default>'
    robot = dk.load_robot(mjcf(MASS_BODY, head))
    assert np.sum(robot.masses) > 0 and not robot.unknown_masses
    check(mjcf(MASS_BODY, head))


def test_include_files_relative_to_the_main_file(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "arm.xml").write_text(
        '<mujoco><include file="parts/defaults.xml"/>'
        '<worldbody><body name="arm" pos="0 0 1"><joint name="shoulder"/>'
        '<include file="parts/hand.xml"/></body></worldbody></mujoco>'
    )
    (tmp_path / "parts" / "defaults.xml").write_text(
        '<mujoco><default><joint axis="0 1 0" range="-10 10"/></default></mujoco>'
    )
    (tmp_path / "parts" / "hand.xml").write_text(
        '<mujoco><body name="hand" pos=".3 0 0" euler="0 0 20"><joint name="wrist"/><site name="grip"/></body></mujoco>'
    )
    main = tmp_path / "robot.xml"
    main.write_text(f'<mujoco model="m">{HEAD}<include file="parts/arm.xml"/></mujoco>')
    robot = dk.load_robot(str(main))
    assert robot.frame_names == ("world", "arm", "hand", "grip")
    model = mujoco.MjModel.from_xml_path(str(main))
    check_limits(robot, model)
    against_mujoco(robot, model)


def test_free_joint_fk_and_jacobian_against_mujoco():
    body = """<geom name="floor" type="plane" size="1 1 1"/><site name="origin"/><body name="table" pos="1 0 0"/>
    <body name="torso" pos="0 0 1.5" euler="10 0 0"><freejoint name="root"/><site name="chest" pos=".1 0 .2"/>
      <body name="arm" pos="0 .2 0"><joint name="shoulder" axis="0 1 0"/><joint name="twist" axis="1 0 0"/>
        <body name="hand" pos=".3 0 0"><joint name="wrist" type="slide" axis="1 0 0"/></body>
      </body>
      <body name="head" pos="0 0 .3"/>
    </body>"""
    robot = dk.load_robot(mjcf(body))
    assert robot.floating and robot.frame_names == ("torso", "arm", "hand", "head", "chest")
    check(mjcf(body), n=4)
    same = dk.load_robot(mjcf(body.replace('<freejoint name="root"/>', '<joint name="root" type="free"/>')))
    assert same.floating and same.frame_names == robot.frame_names


def test_free_joint_base_columns_match_finite_differences():
    robot = dk.load_robot(
        mjcf(
            '<body name="t"><freejoint/><body name="a" pos="0 .2 0"><joint axis="0 1 0"/>'
            '<site name="tip" pos=".3 .1 0"/></body></body>'
        )
    )
    rng = np.random.default_rng(3)
    B, q, eps = random_base(rng), np.array([0.4]), 1e-6
    J = np.asarray(dk.jacobian(robot, q, "tip", frame="world", base=B, include_base=True))
    T0 = np.asarray(dk.fk(robot, q, "tip", base=B))
    for k in range(6):
        twist = np.zeros(6)
        twist[k] = eps
        step = np.asarray(dk.fk(robot, q, "tip", base=B @ _exp_twist(twist)))
        dp = (step[:3, 3] - T0[:3, 3]) / eps
        dR = (step[:3, :3] @ T0[:3, :3].T - np.eye(3)) / eps
        w = np.array([dR[2, 1], dR[0, 2], dR[1, 0]])
        np.testing.assert_allclose(J[:, k], np.concatenate([dp, w]), atol=1e-5)


def _exp_twist(twist: np.ndarray) -> np.ndarray:
    """``exp([v; w])`` in SE(3) (series; for tiny steps)."""
    X = np.zeros((4, 4))
    X[:3, 3] = twist[:3]
    X[:3, :3] = [[0, -twist[5], twist[4]], [twist[5], 0, -twist[3]], [-twist[4], twist[3], 0]]
    return np.eye(4) + X + X @ X / 2 + X @ X @ X / 6


def test_joint_equalities_are_mimic_couplings():
    body = """<body name="a"><joint name="drive" ref="10" range="-90 90"/>
      <body name="b" pos=".2 0 0"><joint name="follow" ref="-20" axis="0 1 0"/>
        <body name="c" pos=".2 0 0"><joint name="chain" type="slide" ref=".1"/>
          <body name="d" pos="0 .1 0"><joint name="locked" ref="5"/><joint name="free_one" axis="1 0 0"/>
            <joint name="ignored" axis="0 1 0"/><site name="tip" pos=".1 0 0"/>
          </body>
        </body>
      </body>
    </body>"""
    tail = """<equality>
      <joint joint1="follow" joint2="drive" polycoef=".1 -2 0 0 0"/>
      <joint joint1="chain" joint2="follow" polycoef="-.05 .5 0 0 0"/>
      <joint joint1="locked" polycoef=".3 0 0 0 0"/>
      <joint joint1="ignored" joint2="drive" active="false"/>
    </equality>"""
    robot = dk.load_robot(mjcf(body, tail=tail))
    assert robot.joint_names == ("drive", "free_one", "ignored")
    assert set(robot.mimic) == {"follow", "chain"}
    check(mjcf(body, tail=tail), n=4)
    # the couplings satisfy MuJoCo's own equality constraints
    model = mujoco.MjModel.from_xml_string(mjcf(body, tail=tail))
    qpos, dq = model.qpos0.copy(), np.zeros((model.nq, 3))
    qpos[model.joint("drive").qposadr[0]] = 0.7
    _apply_equalities(model, qpos, dq)
    assert _equality_residual(model, qpos) < 1e-14


TENDONS = mjcf(
    """<body name="a"><joint name="h1" ref="10" axis="0 0 1"/>
      <body name="b" pos=".3 0 0"><joint name="h2" ref="-20" axis="0 1 0" range="-60 60"/>
        <body name="c" pos=".3 0 0"><joint name="s1" type="slide" ref=".05" axis="1 0 0" range="-.1 .1"/>
          <body name="d" pos="0 .2 0" euler="10 20 30"><joint name="h3" ref="5" axis="1 0 0" pos=".1 0 0"/>
            <joint name="h4" axis="0 0 1"/>
            <body name="e" pos=".1 0 0"><joint name="h5" ref="7" axis="0 1 0"/><joint name="h6" ref="-3"/>
              <site name="tip" pos=".1 .05 0"/>
            </body>
          </body>
        </body>
      </body>
    </body>""",
    tail="""<tendon>
      <fixed name="t1"><joint joint="h1" coef=".5"/><joint joint="h2" coef="-1.5"/><joint joint="h3" coef="2"/></fixed>
      <fixed name="t2"><joint joint="s1" coef="3"/><joint joint="h4" coef="1"/></fixed>
      <fixed name="t3"><joint joint="h5" coef="-2"/></fixed>
      <fixed name="unused"><joint joint="h6" coef="1"/></fixed>
    </tendon>
    <equality>
      <tendon name="coupled" tendon1="t1" tendon2="t2" polycoef=".1 -.7 0 0 0"/>
      <tendon name="held" tendon1="t3" polycoef=".2 5 1 1 1"/>
      <joint joint1="h6" joint2="h3" polycoef=".05 2 0 0 0"/>
    </equality>""",
)


def test_tendon_equalities_couple_joints_as_mujoco():
    """Fixed-tendon equalities: ``h3`` (the last joint of t1) follows h1, h2, s1 and h4 through
    ``L1 - L1_0 = c0 + c1 (L2 - L2_0)``; ``h5`` is held by a one-tendon equality (``L - L_0 = c0``, MuJoCo
    ignores c1 ... c4); ``h6`` follows h3 by a joint equality, so all four. Poses and Jacobians match
    MuJoCo's at configurations where its equality residuals vanish (hand-solved from its compiled tendons)."""
    robot = dk.load_robot(TENDONS)
    assert robot.joint_names == ("h1", "h2", "s1", "h4")
    assert set(robot.mimic) == {f"{j}{s}" for j in ("h3", "h6") for s in ("", ":h2", ":s1", ":h4")}
    assert check(TENDONS, n=4)[0] < 1e-12
    model = mujoco.MjModel.from_xml_string(TENDONS)
    rng = np.random.default_rng(3)
    for _ in range(3):
        qpos, dq = model.qpos0.copy(), np.zeros((model.nq, 4))
        for name in robot.joint_names:
            qpos[model.joint(name).qposadr[0]] = rng.uniform(-1, 1)
        _apply_equalities(model, qpos, dq)
        assert _equality_residual(model, qpos) < 1e-12
        data = mujoco.MjData(model)
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        mujoco.mj_tendon(model, data)
        L, L0, (c0, c1) = data.ten_length, model.tendon_length0, model.eq_data[0, :2]
        assert abs(L[0] - L0[0] - c0 - c1 * (L[1] - L0[1])) < 1e-12 and abs(L[2] - L0[2] - 0.2) < 1e-12
        q = np.array([qpos[model.joint(n).qposadr[0]] for n in robot.joint_names])
        T = np.asarray(dk.link_poses(robot, q))
        for body in ("d", "e"):
            np.testing.assert_allclose(T[robot.frame_index(body), :3, 3], data.xpos[model.body(body).id], atol=1e-12)
            np.testing.assert_allclose(
                T[robot.frame_index(body), :3, :3], data.xmat[model.body(body).id].reshape(3, 3), atol=1e-12
            )


def _without_the_ball(tmp_path) -> str:
    """dm_control's quadruped.xml without its free ball (a second floating tree): the copy's path."""
    suite = os.path.join(DM_CONTROL, "suite")
    root = ET.parse(os.path.join(suite, "quadruped.xml")).getroot()
    for include in root.iter("include"):
        include.set("file", os.path.join(suite, include.get("file", "")))
    world = root.find("worldbody")
    assert world is not None
    world.remove(next(b for b in world.findall("body") if b.get("name") == "ball"))
    path = str(tmp_path / "quadruped.xml")
    ET.ElementTree(root).write(path)
    return path


@pytest.mark.skipif(not os.path.isdir(DM_CONTROL), reason="dm_control is not installed (pip install -e '.[test]')")
def test_quadruped_legs_coupled_by_tendons_against_mujoco(tmp_path):
    """dm_control's quadruped (its ball removed): each ankle follows ``-(pitch + knee)``, the tendon
    equality ``pitch + knee + ankle = const``; poses and Jacobians as MuJoCo's."""
    path = _without_the_ball(tmp_path)
    robot, model = dk.load_robot(path), mujoco.MjModel.from_xml_path(path)
    legs = ("front_left", "front_right", "back_right", "back_left")
    assert robot.joint_names == tuple(f"{j}_{leg}" for leg in legs for j in ("yaw", "pitch", "knee"))
    assert robot.mimic[f"ankle_{legs[0]}"] == (f"pitch_{legs[0]}", -1.0, 0.0)
    check_limits(robot, model)
    against_mujoco(robot, model, n=2, frames=["toe_front_left"])  # every pose; one Jacobian (one compile)


def test_limits_follow_mujoco():
    joints = [
        'name="auto_range" range="-10 20"',
        'name="auto_none"',
        'name="auto_empty" range="1 1"',
        'name="off" limited="false" range="-1 1"',
        'name="on" limited="true" range="-1 1"',
        'name="slide" type="slide" range="-.1 .2"',
    ]
    body = "".join(f'<body pos=".1 0 0"><joint {j}/>' for j in joints) + "</body>" * len(joints)
    robot, model = dk.load_robot(mjcf(body)), mujoco.MjModel.from_xml_string(mjcf(body))
    check_limits(robot, model)
    assert np.isfinite(robot.lower).tolist() == [True, False, False, False, True, True]
    strict = mjcf(
        '<body><joint name="j" limited="true" range="-10 20"/><joint name="k" axis="1 0 0"/></body>',
        '<compiler autolimits="false"/>',
    )
    check_limits(dk.load_robot(strict), mujoco.MjModel.from_xml_string(strict))


def test_urdf_and_mjcf_of_the_iiwa14_agree():
    urdf = dk.load_robot(dk.robots.urdf_path("iiwa14"))
    robot = dk.load_robot(os.path.join(DATA, "iiwa14.xml"))
    assert robot.joint_names == urdf.joint_names
    np.testing.assert_allclose(robot.lower, urdf.lower, rtol=0, atol=0)
    np.testing.assert_allclose(robot.upper, urdf.upper, rtol=0, atol=0)
    Q = random_q(urdf, 8, seed=1)
    a, b = np.asarray(dk.link_poses(urdf, Q)), np.asarray(dk.link_poses(robot, Q))
    for f, name in enumerate(urdf.frame_names):
        np.testing.assert_allclose(b[:, robot.frame_index(name)], a[:, f], rtol=0, atol=1e-12)
    against_mujoco(robot, mujoco.MjModel.from_xml_path(os.path.join(DATA, "iiwa14.xml")))
    np.testing.assert_allclose(dk.fk(robot.chain("tool"), Q), dk.fk(robot, Q, "tool"), rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------ published models

PUBLISHED = {  # path, frames whose Jacobians are compared (None: all)
    "humanoid": ("suite/humanoid.xml", ["head", "right_foot", "left_hand", "site:left_hand", "right_knee", "butt"]),
    "humanoid_CMU": ("suite/humanoid_CMU.xml", ["head", "lfoot", "rhand", "rthumb", "lowerback"]),
    "walker": ("suite/walker.xml", None),
    "jaco_arm": ("third_party/kinova/jaco_arm.xml", None),
    "jaco_hand": ("third_party/kinova/jaco_hand.xml", None),
    "hopper": ("suite/hopper.xml", None),
    "finger": ("suite/finger.xml", None),
    "manipulator": ("suite/manipulator.xml", ["thumbtip", "fingertip"]),  # the fingers: a tendon equality
}


@pytest.mark.skipif(not os.path.isdir(DM_CONTROL), reason="dm_control is not installed (pip install -e '.[test]')")
@pytest.mark.parametrize("name", PUBLISHED)
def test_published_models_against_mujoco(name):
    path, frames = PUBLISHED[name]
    path = os.path.join(DM_CONTROL, path)
    robot, model = dk.load_robot(path), mujoco.MjModel.from_xml_path(path)
    check_limits(robot, model)
    against_mujoco(robot, model, n=3, frames=frames)


@pytest.mark.skipif(not os.path.isdir(DM_CONTROL), reason="dm_control is not installed")
@pytest.mark.parametrize(
    ("path", "message"),
    [
        (
            "suite/quadruped.xml",  # a free ball beside the free torso: two trees
            r"MJCF <freejoint name='ball_root'>: body 'ball' is a second free body "
            r"\(free joints on \['torso', 'ball'\]\); one floating root is supported",
        ),
    ],
    ids=["quadruped"],
)
def test_published_models_with_unsupported_elements_are_rejected(path, message):
    with pytest.raises(ValueError, match=message):
        dk.load_robot(os.path.join(DM_CONTROL, path))


def _write(folder, files: dict[str, str]) -> None:
    for name, text in files.items():
        (folder / name).write_text(text)


@pytest.mark.parametrize(
    "files",
    [
        # one file includes the same file twice
        {"main.xml": '<include file="a.xml"/>', "a.xml": '<include file="leaf.xml"/><include file="./leaf.xml"/>'},
        # two files include the same file
        {
            "main.xml": '<include file="a.xml"/><include file="b.xml"/>',
            "a.xml": '<include file="leaf.xml"/>',
            "b.xml": '<include file="leaf.xml"/>',
        },
    ],
    ids=["twice_in_one_file", "from_two_files"],
)
def test_a_file_included_twice_is_rejected_as_mujoco_does(tmp_path, files):
    """MuJoCo rejects a second include of the same file anywhere in the model; so does diffkin, naming it."""
    _write(tmp_path, {name: f"<mujoco>{text}</mujoco>" for name, text in files.items() if name != "main.xml"})
    (tmp_path / "leaf.xml").write_text('<mujoco><body><joint type="hinge"/></body></mujoco>')
    (tmp_path / "main.xml").write_text(f"<mujoco>{HEAD}<worldbody>{files['main.xml']}</worldbody></mujoco>")
    with pytest.raises(ValueError, match="already included"):
        mujoco.MjModel.from_xml_path(str(tmp_path / "main.xml"))
    message = rf"MJCF <include file='(\./)?leaf.xml'>: file '{tmp_path / 'leaf.xml'}' is included more than once"
    with pytest.raises(ValueError, match=message):
        dk.load_robot(str(tmp_path / "main.xml"))


@pytest.mark.parametrize(("kind", "depth"), [("bodies", 12), ("frames", 150), ("default_classes", 150)])
def test_nesting_against_mujoco(kind, depth):
    """Nested bodies, frames and default classes as MuJoCo reads them (its XML parser stops at 500 levels)."""
    robot, model = dk.load_robot(_nested(kind, depth)), mujoco.MjModel.from_xml_string(_nested(kind, depth))
    check_limits(robot, model)
    against_mujoco(robot, model, frames=["tip"] if kind != "default_classes" else None)
