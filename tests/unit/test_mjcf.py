"""The MJCF reader without MuJoCo: degrees and radians, unknown masses, 5,000 levels of nesting, include
bombs and chains, and every bad input named (against MuJoCo itself:
``tests/validation/test_mjcf_validation.py``)."""

import re

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
    assert np.all(np.isposinf(np.asarray(deg.velocity)))  # MJCF has no joint velocity limits: none


def test_body_geoms_are_the_model_reader_s_bodies_in_mujoco_s_geom_order():
    """The geoms the collision loader reads (``mjcf.body_geoms``): each on its body as the robot names it
    (unnamed: ``body{id}``), through ``<frame>``s (the frame's pose), numbered as MuJoCo's geom ids, the world
    body's geoms (the environment) counted first and left out."""
    import xml.etree.ElementTree as ET

    from diffkin.models import mjcf as reader

    text = (
        '<mujoco><worldbody><geom size="1"/><body pos="0 0 1"><joint/><frame pos=".1 0 0"><geom name="g" size=".1"/>'
        '</frame><body name="b"><joint/><geom size=".2"/></body><geom size=".3"/></body>'
        '<frame><geom size="2"/></frame><body pos="1 0 0"><geom size=".4"/></body></worldbody></mujoco>'
    )
    robot = dk.load_robot(text)
    _, geoms = reader.body_geoms(ET.fromstring(text))
    assert [(g.element.get("size"), g.body, g.id) for g in geoms] == [
        (".1", "body1", 2),
        (".3", "body1", 3),
        (".2", "b", 4),
        (".4", "body3", 5),
    ]
    assert {g.body for g in geoms} <= set(robot.frame_names)
    np.testing.assert_array_equal(geoms[0].T_body_container[:3, 3], [0.1, 0.0, 0.0])


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
            r"^MJCF <freejoint name='f2'>: body 'b' is a second free body \(free joints on \['a', 'b'\]\); one "
            r"floating root is supported \(a single top-level body with a free joint\)$",
        ),
        (
            mjcf('<body name="a"><freejoint/></body><body name="b"><joint type="free"/></body>'),
            r"^MJCF <joint type='free'>: body 'b' is a second free body \(free joints on \['a', 'b'\]\)",
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
        "two_free_unnamed",
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


# ------------------------------------------------------------------------------------ tendon equalities

LEG = (
    '<body name="a"><joint name="j" ref="10"/><body name="b" pos=".3 0 0"><joint name="k" axis="0 1 0"/>'
    '<body name="c" pos=".3 0 0"><joint name="l" ref="-5" axis="1 0 0"/><joint name="s" type="slide"/>'
    '<site name="tip" pos=".2 .1 0"/></body></body></body>'
)


def _tendons(fixed: dict[str, str], equality: str, extra: str = "") -> str:
    """``LEG`` with fixed tendons ``{name: "joint coef joint coef ..."}`` and the ``<equality>`` contents."""
    tendons = "".join(
        f'<fixed name="{name}">'
        + "".join(
            f'<joint joint="{j}" coef="{c}"/>' for j, c in zip(spec.split()[::2], spec.split()[1::2], strict=True)
        )
        + "</fixed>"
        for name, spec in fixed.items()
    )
    return mjcf(LEG, tail=f"<tendon>{tendons}{extra}</tendon><equality>{equality}</equality>")


def test_a_tendon_equality_makes_the_last_joint_of_tendon1_follow_the_others():
    """``.5 (j - ref_j) - (k - ref_k) + 2 (l - ref_l) = .1 + 3 * .7 (s - ref_s)`` solved for ``l``: the poses are
    those of the model without the equality with ``l`` set by hand."""
    coupled = dk.load_robot(
        _tendons({"t": "j .5 k -1 l 2", "u": "s .7"}, '<tendon tendon1="t" tendon2="u" polycoef=".1 3 0 0 0"/>')
    )
    free = dk.load_robot(mjcf(LEG))
    assert coupled.joint_names == ("j", "k", "s") and free.joint_names == ("j", "k", "l", "s")
    assert set(coupled.mimic) == {"l", "l:k", "l:s"}
    q = np.array([[0.3, -0.4, 0.05], [1.1, 0.2, -0.2]])
    ref_j, ref_l = np.deg2rad(10), np.deg2rad(-5)
    l = ref_l + (0.1 + 3 * 0.7 * q[:, 2] - 0.5 * (q[:, 0] - ref_j) + q[:, 1]) / 2
    by_hand = np.stack([q[:, 0], q[:, 1], l, q[:, 2]], axis=-1)
    np.testing.assert_allclose(dk.link_poses(coupled, q), dk.link_poses(free, by_hand), rtol=0, atol=1e-15)


def test_a_tendon_equality_error_names_the_file(tmp_path):
    path = tmp_path / "leg.xml"
    path.write_text(_tendons({"t": "j 1 k 1"}, '<tendon name="hold" tendon1="t" tendon2="u"/>'))
    message = f"{path}: MJCF <equality><tendon name='hold' tendon1='t' tendon2='u'>: unknown tendon 'u'"
    with pytest.raises(ValueError, match=re.escape(message)):
        dk.load_robot(str(path))


T = "MJCF <equality><tendon tendon1='t'"
TU = "MJCF <equality><tendon tendon1='t' tendon2='u'>"
EQ = '<equality><tendon tendon1="t"/></equality>'


@pytest.mark.parametrize(
    ("xml", "message"),
    [
        (
            _tendons({"t": "j 1 k 1", "u": "s 1"}, '<tendon tendon1="t" tendon2="u" polycoef="0 1 .5 0 0"/>'),
            rf"{TU}: polycoef \[0.0, 1.0, 0.5, 0.0, 0.0\] is not linear",
        ),
        (
            _tendons({"t": "j 1 k 0"}, '<tendon tendon1="t"/>'),
            rf"{T}>: the coefficient of joint 'k' is 0 \(the last joint of tendon1",
        ),
        (  # k's coefficient: .3 in t, minus 3 times .1 in u (-5.6e-17 in floating point)
            _tendons({"t": "j 1 k .3", "u": "k .1 s 1"}, '<tendon tendon1="t" tendon2="u" polycoef="0 3 0 0 0"/>'),
            rf"{TU}: the coefficient of joint 'k' is 0",
        ),
        (  # k follows j (tendon), j follows k (joint equality)
            _tendons({"t": "j 1 k 1"}, '<tendon tendon1="t"/><joint joint1="j" joint2="k"/>'),
            r"MJCF <equality><joint joint1='j' joint2='k'>: the joint couplings form a cycle: k -> j -> k",
        ),
        (
            _tendons({"t": "j 1 k 1"}, '<joint joint1="k" joint2="j"/><tendon tendon1="t"/>'),
            rf"{T}>: joint 'k' is already coupled by MJCF <equality><joint joint1='k' joint2='j'>",
        ),
        (
            _tendons({}, '<tendon tendon1="t"/>', '<spatial name="t"><site site="tip"/><site site="tip"/></spatial>'),
            rf"{T}>: tendon 't' is a <spatial> tendon; only <fixed> tendons",
        ),
        (_tendons({"u": "j 1"}, '<tendon tendon1="t"/>'), rf"{T}>: unknown tendon 't'"),
        (_tendons({"t": "j 1 nope 1"}, '<tendon tendon1="t"/>'), rf"{T}>: 'nope' is not a hinge or slide joint"),
        (
            mjcf(LEG, tail='<tendon><fixed name="t"><joint joint="j"/></fixed></tendon>' + EQ),
            rf"{T}> tendon 't' joint 'j': missing attribute 'coef'",
        ),
        (_tendons({"t": "j 1 j 2"}, '<tendon tendon1="t"/>'), rf"{T}>: joint 'j' is repeated in tendon 't'"),
        (_tendons({"t": "j 1"}, '<tendon tendon1="t" tendon2="t"/>'), r"tendon1 and tendon2 are the same tendon"),
        (_tendons({"t": ""}, '<tendon tendon1="t"/>'), rf"{T}>: tendon 't' has no joints"),
        (_tendons({}, '<tendon tendon2="t"/>'), r"MJCF <equality><tendon tendon2='t'>: missing 'tendon1' attribute"),
    ],
    ids=[
        "nonlinear",
        "zero_coefficient",
        "zero_combined_coefficient",
        "cycle",
        "already_coupled",
        "spatial",
        "unknown_tendon",
        "unknown_joint",
        "missing_coef",
        "repeated_joint",
        "same_tendon",
        "empty_tendon",
        "missing_tendon1",
    ],
)
def test_unresolvable_tendon_equalities_are_rejected(xml, message):
    with pytest.raises(ValueError, match=message):
        dk.load_robot(xml)
