"""The MJCF reader without MuJoCo: degrees and radians, unknown masses, 5,000 levels of nesting, include
bombs and chains, and every bad input named (against MuJoCo itself:
``tests/validation/test_mjcf_validation.py``)."""

import numpy as np
import pytest
from _fuzzing import time_limit
from _mjcf import ARM, mjcf
from _mjcf import nested_mjcf as _nested

import diffkin as dk
import diffkin.cli


def test_degrees_vs_radians_give_the_same_robot():
    deg = dk.load_robot(mjcf(f'<body name="a" euler="90 0 0">{ARM.format(o="")}</body>'))
    rad = dk.load_robot(
        mjcf(f'<body name="a" euler="{np.pi / 2} 0 0">{ARM.format(o="")}</body>', '<compiler angle="radian"/>')
    )
    q = np.array([0.3, -0.2])
    np.testing.assert_allclose(dk.link_poses(deg, q), dk.link_poses(rad, q), atol=1e-15)
    np.testing.assert_allclose(deg.lower[0], -np.pi / 2, rtol=1e-15)  # the hinge range in degrees
    np.testing.assert_allclose(rad.lower[0], -90.0, rtol=1e-15)  # ... read as radians


def test_a_mesh_geom_without_inertial_has_an_unknown_mass():
    body = '<body name="b"><joint name="j"/><geom type="mesh" mesh="m"/></body>'
    robot = dk.load_robot(
        mjcf(body, tail="").replace(
            "<worldbody>", '<asset><mesh name="m" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset><worldbody>'
        )
    )
    assert dk.fk(robot, np.zeros(1), "b").shape == (4, 4)  # the kinematics load
    with pytest.raises(
        ValueError, match=r"unknown masses: body 'b': the mass of its mesh geom \(give the body an <inertial>\)"
    ):
        dk.com(robot, np.zeros(1))


def test_include_bomb_is_rejected_at_once(tmp_path):
    """26 files that each include the next twice (2**25 copies if expanded) are rejected at the first repeat."""
    for k in range(25):
        (tmp_path / f"f{k}.xml").write_text(
            f'<mujoco><include file="f{k + 1}.xml"/><include file="f{k + 1}.xml"/></mujoco>'
        )
    (tmp_path / "f25.xml").write_text("<mujoco><body/></mujoco>")
    (tmp_path / "main.xml").write_text('<mujoco><worldbody><include file="f0.xml"/></worldbody></mujoco>')
    with (
        time_limit(10, "loading an include bomb"),
        pytest.raises(ValueError, match="f25.xml' is included more than once"),
    ):
        dk.load_robot(str(tmp_path / "main.xml"))


@pytest.mark.parametrize("kind", ["bodies", "frames", "default_classes"])
def test_nesting_5000_deep_loads(kind, tmp_path, capsys):
    """5,000 levels of bodies, frames or default classes load (no RecursionError), as the closed form says;
    ``diffkin info`` prints the tree (the bodies' tree has two branches: info stops there, the
    chain of 5,000 joints is not built)."""
    depth = 5000
    xml = _nested(kind, depth)
    robot = dk.load_robot(xml)

    def about_z(degrees: float, height: float) -> np.ndarray:
        c, s = np.cos(np.deg2rad(degrees)), np.sin(np.deg2rad(degrees))
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, height], [0, 0, 0, 1]])

    step = about_z(3, 0.01)
    if kind == "bodies":
        assert robot.frame_names == ("world", *(f"b{k}" for k in range(depth)), "side", "tip")
        assert robot.parents == (*range(depth), 0) and robot.frame_bodies[-1] == depth
        np.testing.assert_allclose(robot.joint_poses[:-1], np.broadcast_to(step, (depth, 4, 4)), rtol=0, atol=1e-15)
        np.testing.assert_allclose(robot.lower[:-1], np.full(depth, -np.deg2rad(1)), rtol=0, atol=1e-15)
    elif kind == "frames":
        T_b_tip = about_z(3 * depth, 0.01 * depth)  # rotations about z, offsets along z: they commute
        np.testing.assert_allclose(robot.frame_poses[robot.frame_index("tip")], T_b_tip, rtol=0, atol=1e-10)
        np.testing.assert_allclose(robot.joint_poses[1], T_b_tip, rtol=0, atol=1e-10)
    else:
        np.testing.assert_array_equal(robot.screws, [[0, 0, 0, 0, 1, 0]] * 2)
        np.testing.assert_allclose(robot.lower, np.deg2rad([-30, -np.inf]), rtol=0, atol=1e-15)
        np.testing.assert_allclose(robot.upper, np.deg2rad([60, np.inf]), rtol=0, atol=1e-15)
    path = tmp_path / "deep.xml"
    path.write_text(xml)
    assert dk.cli.main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("m: Robot (tree)")


def test_includes_nested_1500_deep(tmp_path):
    """A chain of 1,500 files, each including the next, loads (the expansion recursed once per file)."""
    depth = 1500
    for k in range(depth):
        (tmp_path / f"f{k}.xml").write_text(f'<mujoco><include file="f{k + 1}.xml"/></mujoco>')
    (tmp_path / f"f{depth}.xml").write_text('<mujoco><body name="b"><joint name="j"/></body></mujoco>')
    (tmp_path / "main.xml").write_text('<mujoco><worldbody><include file="f0.xml"/></worldbody></mujoco>')
    assert dk.load_robot(str(tmp_path / "main.xml")).joint_names == ("j",)


def test_a_nested_include_is_found_next_to_the_file_that_includes_it(tmp_path):
    """MuJoCo's rule (MS-Human-700 of Menagerie relies on it): the main file's folder first, then the including
    file's."""
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "arm.xml").write_text('<mujoco><body name="arm"><include file="hand.xml"/></body></mujoco>')
    (tmp_path / "parts" / "hand.xml").write_text(
        '<mujoco><body name="hand" pos="1 0 0"><joint name="j"/></body></mujoco>'
    )
    (tmp_path / "main.xml").write_text('<mujoco><worldbody><include file="parts/arm.xml"/></worldbody></mujoco>')
    assert dk.load_robot(str(tmp_path / "main.xml")).joint_names == ("j",)
    (tmp_path / "parts" / "hand.xml").unlink()
    with pytest.raises(ValueError, match="MJCF <include file='hand.xml'>: file not found"):
        dk.load_robot(str(tmp_path / "main.xml"))


# --------------------------------------------------------------------------------------------- bad input

BODY = '<body name="a"><joint name="j"/><body name="b"><joint name="k"/></body></body>'


@pytest.mark.parametrize(
    ("xml", "message"),
    [
        (
            mjcf('<body><joint name="sphere" type="spherical"/></body>'),
            r"MJCF <joint name='sphere' type='spherical'>: joint type 'spherical' is not supported",
        ),
        (
            mjcf(BODY, tail='<equality><joint joint1="k" joint2="j" polycoef="0 1 .5 0 0"/></equality>'),
            r"MJCF <equality><joint joint1='k' joint2='j'>: polycoef \[0.0, 1.0, 0.5, 0.0, 0.0\] is not linear",
        ),
        (
            mjcf(BODY, tail='<equality><weld site1="s" site2="t"/></equality>'),
            r"MJCF <equality><weld>: <equality><weld> constraints are not supported",
        ),
        (
            mjcf(BODY, tail='<equality><connect site1="s"/></equality>'),
            r"MJCF <equality><connect>: expected body1 \(and body2, anchor\) or site1 and site2",
        ),
        (
            mjcf(BODY, tail='<equality><joint joint1="k" joint2="nope"/></equality>'),
            r"MJCF <equality><joint joint1='k' joint2='nope'>: 'nope' is not a hinge or slide joint",
        ),
        (
            mjcf('<body><joint name="j" class="nope"/></body>'),
            r"MJCF <joint name='j' class='nope'>: unknown default "
            r"class 'nope'",
        ),
        (mjcf('<body name="b" childclass="nope"/>'), r"MJCF <body name='b'>: unknown default class 'nope'"),
        (
            mjcf("", '<include file="/nonexistent/part.xml"/>'),
            r"MJCF <include file='/nonexistent/part.xml'>: file not found: '/nonexistent/part.xml'",
        ),
        (mjcf('<body><replicate count="2"/></body>'), r"MJCF <replicate>: <replicate> is not supported"),
        (mjcf('<body><attach model="m"/></body>'), r"MJCF <attach>: <attach> is not supported"),
        (
            mjcf('<body name="a"><freejoint name="f1"/></body><body name="b"><freejoint name="f2"/></body>'),
            r"MJCF <freejoint name='f2'>: several bodies have free joints \(\['a', 'b'\]\)",
        ),
        (
            mjcf('<body name="a"><body><freejoint name="f"/></body></body>'),
            r"MJCF <freejoint name='f'>: a free joint must be the only joint of a top-level body",
        ),
        (
            mjcf('<body name="a"><freejoint name="f"/><joint name="j"/></body>'),
            r"MJCF <freejoint name='f'>: a free joint must be the only joint of a top-level body",
        ),
        (
            mjcf('<body name="a"><freejoint/></body><body name="door"><joint name="hinge"/></body>'),
            r"MJCF <body name='door'>: its joints \['hinge'\] move a second tree beside the floating root 'a'",
        ),
        (
            mjcf('<body><joint name="j" range="0 1"/></body>', '<compiler autolimits="false"/>'),
            r"MJCF <joint name='j'>: 'range' without 'limited' needs",
        ),
        (mjcf('<body name="b" euler="0 0 0" quat="1 0 0 0"/>'), r"MJCF <body name='b'>: several orientations"),
        (mjcf('<body name="b" quat="0 0 0 0"/>'), r"MJCF <body name='b'> quat: expected a nonzero vector"),
        (
            mjcf('<body><site name="s" fromto="0 0 0 1 0 0"/></body>'),
            r"MJCF <site name='s'>: fromto needs a site of type",
        ),
        (
            mjcf('<body><site name="s" type="box" pos="1 0 0" fromto="0 0 0 1 0 0"/></body>'),
            r"MJCF <site name='s' type='box'>: both pos and fromto given",
        ),
        (mjcf("", '<compiler angle="grad"/>'), r"MJCF <compiler>: angle must be 'degree' or 'radian'"),
        ("<sdf/>", r"expected a <robot> \(URDF\) or <mujoco> \(MJCF\) root element, got <sdf>"),
    ],
    ids=[
        "unknown_type",
        "nonlinear",
        "weld",
        "connect",
        "unknown_joint",
        "unknown_class",
        "unknown_childclass",
        "missing_include",
        "replicate",
        "attach",
        "two_free",
        "nested_free",
        "free_and_hinge",
        "second_tree",
        "autolimits",
        "two_orientations",
        "zero_quat",
        "fromto_sphere",
        "pos_and_fromto",
        "compiler_angle",
        "root_element",
    ],
)
def test_bad_input_names_the_element(xml, message):
    with pytest.raises(ValueError, match=message):
        dk.load_robot(xml)
