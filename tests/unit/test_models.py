"""Model construction: pytree behaviour, and every bad input rejected on the host with a clear message."""

import re

import jax
import numpy as np
import pytest
from _models import URDF_ROBOTS

import diffkin as dk

IIWA_URDF = dk.robots.urdf_path("iiwa14")


def _urdf(joints: str) -> str:
    links = dict.fromkeys(re.findall(r'link="(\w+)"', joints))
    body = "".join(f'<link name="{name}"/>' for name in links if name != "zz")
    return f'<robot name="r">{body}{joints}</robot>'


def _joint(name, kind, parent, child, extra=""):
    limit = '<limit lower="-1" upper="1"/>' if kind in ("revolute", "prismatic") else ""
    return f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>{limit}{extra}</joint>'


def test_models_are_pytrees_with_static_structure():
    chain = dk.robots.iiwa14()
    leaves, treedef = jax.tree_util.tree_flatten(chain)
    assert all(isinstance(x, jax.Array) for x in leaves)
    assert chain.dof == 7 and chain.joint_types == "RRRRRRR" and len(chain.joint_names) == 7
    again = jax.tree_util.tree_unflatten(treedef, leaves)
    assert again.joint_types == chain.joint_types and again.modified == chain.modified
    moved = chain.replace(a=chain.a + 0.01)
    assert np.allclose(moved.a, 0.01) and np.allclose(chain.a, 0.0)
    with pytest.raises(AttributeError):
        chain.a = chain.a  # frozen
    poe = dk.load_urdf(IIWA_URDF)
    assert poe.dof == 7 and poe.screws.shape == (7, 6) and poe.link_homes.shape == (7, 4, 4)


def test_from_table_defaults_and_limits():
    chain = dk.DHChain.from_table(np.zeros((3, 4)))
    assert chain.joint_types == "RRR" and chain.joint_names == ("joint1", "joint2", "joint3")
    assert np.all(np.isneginf(chain.lower)) and np.all(np.isposinf(chain.upper))
    np.testing.assert_array_equal(chain.base, np.eye(4))


def test_from_screws_infers_joint_types():
    screws = [[0, 0, 0, 0, 0, 1], [1, 0, 0, 0, 0, 0]]
    chain = dk.PoEChain.from_screws(screws, np.eye(4))
    assert chain.joint_types == "RP"
    q = np.array([0.3, 0.2])
    T = np.asarray(dk.fk(chain, q))
    np.testing.assert_allclose(T[:3, 3], [np.cos(0.3) * 0.2, np.sin(0.3) * 0.2, 0.0], atol=1e-15)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(table=np.zeros((3, 3))), r"table: expected shape \(dof, 4\)"),
        (dict(table=np.zeros((0, 4))), r"table: expected shape \(dof, 4\)"),
        (dict(table=[[0, np.nan, 0, 0]]), r"table: expected numbers, got NaN at index \(0, 1\)"),
        (dict(table=[[0, 0, np.inf, 0]]), r"table: expected finite"),
        (dict(table=np.zeros((2, 4)), joint_types="R"), r"joint_types: expected 2 letters"),
        (dict(table=np.zeros((2, 4)), joint_types="RX"), r"joint_types\[1\]: expected 'R' or 'P', got 'X'"),
        (dict(table=np.zeros((2, 4)), lower=[0, 1], upper=[1, 0]), r"lower\[1\] = 1.0 > upper\[1\] = 0.0"),
        (dict(table=np.zeros((2, 4)), lower=[0, np.nan]), r"lower: expected numbers, got NaN at index \(1,\)"),
        (dict(table=np.zeros((2, 4)), upper=[1, 2, 3]), r"upper: expected shape \(2,\), got \(3,\)"),
        (dict(table=np.zeros((2, 4)), base=np.zeros((4, 4))), r"base: expected last row"),
        (dict(table=np.zeros((2, 4)), tool=np.diag([1, 1, -1, 1.0])), r"tool: expected a rotation"),
        (dict(table=np.zeros((2, 4)), base=np.eye(3)), r"base: expected shape \(4, 4\)"),
        (dict(table=np.zeros((2, 4)), joint_names=["a"]), r"joint_names: expected 2 strings"),
    ],
)
def test_from_table_rejects(kwargs, match):
    with pytest.raises(ValueError, match=match):
        dk.DHChain.from_table(**kwargs)


def test_from_table_type_errors():
    with pytest.raises(TypeError, match="joint_types: expected a string"):
        dk.DHChain.from_table(np.zeros((2, 4)), ["R", "R"])
    with pytest.raises(TypeError, match="table: expected an array of numbers"):
        dk.DHChain.from_table([["a", "b", "c", "d"]])


@pytest.mark.parametrize(
    "screws, home, kwargs, match",
    [
        ([[0, 0, 0, 0, 0, 2.0]], np.eye(4), {}, r"screws\[0\]: expected a unit screw .* \|w\| = 2"),
        ([[0, 0, 0.5, 0, 0, 0]], np.eye(4), {}, r"screws\[0\]: expected a unit screw .* \|v\| = 0.5"),
        ([[0, 0, 0, 0, 0, 1]], np.eye(4), dict(joint_types="P"), r"joint_types\[0\]: 'P' contradicts screws\[0\]"),
        (np.zeros((2, 5)), np.eye(4), {}, r"screws: expected shape \(dof, 6\)"),
        ([[0, 0, 0, 0, 0, 1]], 2 * np.eye(4), {}, r"home: expected"),
        ([[0, 0, 0, 0, 0, 1]], np.eye(4), dict(link_homes=np.zeros((1, 4, 4))), r"link_homes\[0\]: expected"),
        ([[0, 0, np.inf, 0, 0, 1]], np.eye(4), {}, r"screws: expected finite"),
    ],
)
def test_from_screws_rejects(screws, home, kwargs, match):
    with pytest.raises(ValueError, match=match):
        dk.PoEChain.from_screws(screws, home, **kwargs)


@pytest.mark.parametrize("chain", [dk.robots.iiwa14(), dk.load_urdf(IIWA_URDF)], ids=["dh", "poe"])
def test_q_of_the_wrong_size_is_rejected(chain):
    for fn in (dk.fk, dk.link_poses, dk.jacobian, dk.manipulability):
        with pytest.raises(ValueError, match=r"q: expected shape \(\.\.\., 7\) for a 7-joint chain, got \(3, 6\)"):
            fn(chain, np.zeros((3, 6)))
        with pytest.raises(ValueError, match=r"q: expected shape \(\.\.\., 7\)"):
            fn(chain, 0.0)
    with pytest.raises(TypeError, match="chain: expected a DHChain, PoEChain or Robot, got str"):
        dk.fk("iiwa", np.zeros(7))
    with pytest.raises(ValueError, match="frame: expected one of"):
        dk.jacobian(chain, np.zeros(7), frame="tool")
    with pytest.raises(ValueError, match="method: expected one of"):
        dk.jacobian(chain, np.zeros(7), method="numeric")


def test_urdf_root_and_leaf_defaults():
    chain = dk.load_urdf(IIWA_URDF)
    assert chain.joint_names == tuple(f"iiwa14_joint_{i}" for i in range(1, 8)) and chain.name == "iiwa14"
    short = dk.load_urdf(IIWA_URDF, "iiwa14_link_4", base_link="iiwa14_link_1")
    assert short.dof == 3
    full = np.asarray(dk.link_poses(chain, np.full(7, 0.3)))
    rel = np.linalg.inv(full[1]) @ full[4]
    np.testing.assert_allclose(dk.fk(short, np.full(3, 0.3)), rel, atol=1e-14)


def test_urdf_continuous_prismatic_and_any_axis():
    xml = _urdf(
        _joint("j1", "continuous", "a", "b", '<origin xyz="0 0 1"/><axis xyz="0 0 2"/>')
        + _joint("j2", "prismatic", "b", "c", '<origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/><axis xyz="1 1 0"/>')
    )
    chain = dk.load_urdf(xml)
    assert chain.joint_types == "RP" and np.isinf(chain.upper[0]) and chain.upper[1] == 1.0
    q1, q2 = 0.4, 0.3
    T = np.asarray(dk.fk(chain, np.array([q1, q2])))
    # joint 2 frame sits at (1,0,1) of link b, turned +90 deg; its axis (1,1)/sqrt2 is (-1,1)/sqrt2 in b.
    p_b = np.array([1.0, 0, 0]) + q2 * np.array([-1.0, 1.0, 0]) / np.sqrt(2)
    c, s = np.cos(q1), np.sin(q1)
    expected = np.array([c * p_b[0] - s * p_b[1], s * p_b[0] + c * p_b[1], 1.0])
    np.testing.assert_allclose(T[:3, 3], expected, atol=1e-14)


@pytest.mark.parametrize(
    "source, kwargs, match",
    [
        ("<robot><link name='a'/>", {}, r"malformed URDF XML"),
        ("/nonexistent/robot.urdf", {}, r"URDF file not found: '/nonexistent/robot.urdf'"),
        ("<model/>", {}, r"expected a <robot> root element, got <model>"),
        (IIWA_URDF, dict(end_link="flange"), r"end_link: unknown link 'flange'; available links: \['iiwa14_link_0'"),
        (IIWA_URDF, dict(base_link="world"), r"base_link: unknown link 'world'; available links"),
        (IIWA_URDF, dict(end_link="iiwa14_link_1", base_link="iiwa14_link_3"), r"'iiwa14_link_1' is not below frame"),
        (URDF_ROBOTS["panda"][0], {}, r"several leaf links below 'panda_link0', choose one of \[.*'panda_hand_tcp'"),
        (
            _urdf(_joint("r", "revolute", "a", "b") + _joint("j", "floating", "b", "c")),
            dict(end_link="c"),
            r"joint 'j': a floating joint is supported only as the single joint of the root link",
        ),
        (_urdf(_joint("j", "planar", "a", "b")), dict(end_link="b"), r"joint type 'planar' is not supported"),
        (_urdf(_joint("j", "ball", "a", "b")), dict(end_link="b"), r"joint type 'ball' is not supported"),
        (
            _urdf(_joint("j", "revolute", "a", "b") + _joint("k", "revolute", "b", "c", '<mimic joint="x"/>')),
            dict(end_link="c"),
            r"joint 'k' mimics 'x', which is not a joint of the robot",
        ),
        (
            _urdf(_joint("j", "revolute", "a", "b", '<axis xyz="0 0 0"/>')),
            dict(end_link="b"),
            r"<axis>: expected a nonzero",
        ),
        (
            _urdf(_joint("j", "revolute", "a", "b", '<origin xyz="0 0"/>')),
            dict(end_link="b"),
            r"joint 'j' <origin> xyz: expected 3 finite numbers, got '0 0'",
        ),
        (
            _urdf(_joint("j", "revolute", "a", "b", '<origin rpy="0 x 0"/>')),
            dict(end_link="b"),
            r"rpy: expected 3 finite",
        ),
        (_urdf(_joint("j", "revolute", "a", "zz")), dict(end_link="b"), r"link 'zz' is not defined"),
        (_urdf(_joint("j", "fixed", "a", "b")), dict(end_link="b"), r"no moving joint between 'a' and 'b'"),
        (
            _urdf(_joint("j", "revolute", "a", "b").replace('lower="-1"', 'lower="2"')),
            dict(end_link="b"),
            r"<limit>: expected lower <= upper",
        ),
    ],
)
def test_load_urdf_rejects(source, kwargs, match):
    with pytest.raises(ValueError, match=match):
        dk.load_urdf(source, **kwargs)


def test_load_urdf_type_error():
    with pytest.raises(TypeError, match="source: expected a URDF path or XML string, got int"):
        dk.load_urdf(3)


def test_planar_rejects_bad_lengths():
    with pytest.raises(ValueError, match="lengths: expected a non-empty list of positive link lengths"):
        dk.robots.planar([1.0, -1.0])
    with pytest.raises(ValueError, match="name: expected one of"):
        dk.robots.urdf_path("ur5")


# ----- one validation hook: construction, replace, and not JAX's own rebuilding (issue 18) -----

_SCALED = np.diag([2.0, 2.0, 2.0, 1.0])


@pytest.mark.parametrize(
    "changes, error, match",
    [
        ({"a": np.full(7, np.nan)}, ValueError, r"^a: expected finite numbers"),
        ({"d": np.array([0.3, 0.0, 0.4, 0.0, 0.4, 0.0, np.inf])}, ValueError, r"^d: expected finite"),
        ({"lower": np.full(7, 1.0), "upper": np.zeros(7)}, ValueError, r"lower\[0\] = 1.0 > upper\[0\]"),
        ({"lower": np.full(7, np.nan)}, ValueError, r"^lower: expected numbers, got NaN"),
        ({"alpha": np.zeros(6)}, ValueError, r"^alpha: expected shape \(7,\), got \(6,\)"),
        (
            {"joint_types": "RRR"},
            ValueError,
            r"^(joint_names: expected 3 strings|a: expected shape \(3,\), got \(7,\))",
        ),
        ({"joint_types": "RRRRRRX"}, ValueError, r"joint_types\[6\]: expected 'R' or 'P'"),
        ({"joint_types": ""}, ValueError, r"^joint_types: expected at least one joint"),
        ({"base": _SCALED}, ValueError, r"^base: expected a rotation"),
        ({"tool": np.eye(4) * 1.001}, ValueError, r"^tool: expected"),
        ({"base": np.eye(3)}, ValueError, r"^base: expected shape \(4, 4\)"),
        ({"modified": "False"}, TypeError, r"^modified: expected True or False"),
        ({"joint_names": "abcdefg"}, TypeError, r"^joint_names: expected a tuple or list"),
        ({"name": 3}, TypeError, r"^name: expected a string"),
        ({"a": np.zeros(7, bool)}, TypeError, r"^a: expected a real floating-point array, got dtype bool"),
        ({"d": np.zeros(7, complex)}, TypeError, r"^d: expected a real floating-point array, got dtype complex"),
        ({"a": [0.0] * 7}, TypeError, r"^a: expected an array, got list"),
        ({"theta_offset": None}, TypeError, r"^theta_offset: expected an array"),
        ({"velocity": np.r_[np.ones(6), -1.0]}, ValueError, r"^velocity\[6\]: expected a limit >= 0"),
        ({"velocity": np.full(7, np.nan)}, ValueError, r"^velocity: expected numbers, got NaN"),
        ({"velocity": np.ones(6)}, ValueError, r"^velocity: expected shape \(7,\), got \(6,\)"),
    ],
)
def test_replace_and_direct_construction_validate_like_the_builder(changes, error, match):
    chain = dk.robots.iiwa14()
    with pytest.raises(error, match=match):
        chain.replace(**changes)
    fields = {f: getattr(chain, f) for f in ("a", "alpha", "d", "theta_offset", "lower", "upper", "base", "tool")}
    with pytest.raises(error, match=match):
        dk.DHChain(**{**fields, "joint_types": chain.joint_types, **changes})


def test_velocity_limits_of_chains_are_given_or_none():
    """``velocity``: none (``inf``) unless given, through the builders, direct construction and ``to_poe``."""
    table = np.zeros((2, 4))
    assert np.all(np.isposinf(np.asarray(dk.DHChain.from_table(table).velocity)))
    dh = dk.DHChain.from_table(table, velocity=[1.0, np.inf])
    assert np.asarray(dh.velocity).tolist() == [1.0, np.inf] and dh.velocity.dtype == dh.lower.dtype
    assert np.asarray(dk.to_poe(dh).velocity).tolist() == [1.0, np.inf]
    fields = {f: getattr(dh, f) for f in ("a", "alpha", "d", "theta_offset", "lower", "upper", "base", "tool")}
    assert np.all(np.isposinf(np.asarray(dk.DHChain(**fields, joint_types="RR").velocity)))
    poe = dk.PoEChain.from_screws([[0, 0, 0, 0, 0, 1.0]], np.eye(4), velocity=[0.5])
    assert float(poe.velocity[0]) == 0.5
    with pytest.raises(ValueError, match=r"^velocity\[0\]: expected a limit >= 0"):
        dk.PoEChain.from_screws([[0, 0, 0, 0, 0, 1.0]], np.eye(4), velocity=[-0.5])


def test_replace_with_traced_values_checks_shapes_not_values():
    chain = dk.robots.iiwa14()
    q = np.zeros(7)
    # Values are not checked on tracers (grad through a field, jit, vmap of fields) ...
    g = jax.grad(lambda s: dk.fk(chain.replace(base=chain.base * s), q)[0, 3])(1.0)
    assert np.isfinite(g)
    out = jax.jit(lambda lo: chain.replace(lower=lo).lower)(np.full(7, 5.0))  # lower > upper, traced
    assert out.shape == (7,)
    batched = jax.vmap(lambda a: dk.fk(chain.replace(a=a), q))(np.zeros((3, 7)))
    assert batched.shape == (3, 4, 4)
    # ... but shapes are.
    with pytest.raises(ValueError, match=r"^a: expected shape \(7,\), got \(6,\)"):
        jax.jit(lambda a: chain.replace(a=a))(np.zeros(6))
    with pytest.raises(TypeError, match=r"^a: expected a real floating-point array"):
        jax.jit(lambda a: chain.replace(a=a))(np.zeros(7, np.int32))


def test_jax_rebuilding_is_not_validated():
    """tree_unflatten with placeholders, batched leaves from tree_map: no check, no error."""
    chain = dk.robots.iiwa14()
    leaves, treedef = jax.tree_util.tree_flatten(chain)
    for placeholder in (None, object()):
        rebuilt = jax.tree_util.tree_unflatten(treedef, [placeholder] * len(leaves))
        assert rebuilt.a is placeholder and rebuilt.joint_types == chain.joint_types
    stacked = jax.tree_util.tree_map(lambda x: np.stack([x, x]), chain)
    assert stacked.base.shape == (2, 4, 4)
    out = jax.vmap(dk.fk, in_axes=(0, None))(stacked, np.zeros(7))
    np.testing.assert_allclose(out[0], dk.fk(chain, np.zeros(7)))
    paths = [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(chain)[0]]
    assert paths[0] == ".a" and paths[-1] == ".velocity"  # the last field


@pytest.mark.parametrize(
    "changes, error, match",
    [
        ({"screws": np.tile([0.0, 0, 0, 0, 0, 2.0], (7, 1))}, ValueError, r"^screws\[0\]: expected a unit screw"),
        ({"screws": np.tile([0.5, 0, 0, 1.0, 0, 0], (7, 1))}, ValueError, r"^screws\[0\]: expected a revolute screw"),
        ({"joint_types": "RRRRRRP"}, ValueError, r"^joint_types\[6\]: 'P' contradicts screws\[6\]"),
        ({"home": _SCALED}, ValueError, r"^home: expected a rotation"),
        ({"link_homes": np.tile(_SCALED, (7, 1, 1))}, ValueError, r"^link_homes\[0\]: expected a rotation"),
        ({"link_homes": np.zeros((6, 4, 4))}, ValueError, r"^link_homes: expected shape \(7, 4, 4\)"),
        ({"upper": np.full(7, -10.0)}, ValueError, r"lower\[0\] = .* > upper\[0\]"),
        ({"joint_names": ("a",) * 7}, ValueError, r"^joint_names: expected distinct names"),
        ({"screws": np.zeros((7, 6), complex)}, TypeError, r"^screws: expected a real floating-point array"),
    ],
)
def test_poe_replace_validates(changes, error, match):
    chain = dk.load_urdf(IIWA_URDF)
    with pytest.raises(error, match=match):
        chain.replace(**changes)


def test_from_screws_rejects_pitch_and_normalises_within_tolerance():
    home = np.eye(4)
    with pytest.raises(ValueError, match=r"^screws\[0\]: expected a revolute screw without pitch"):
        dk.PoEChain.from_screws([[0.0, 0, 0.1, 0, 0, 1]], home)  # a helix: v . w = 0.1
    w = np.array([0.0, 0.6, 0.8]) * (1 + 5e-7)
    p = np.array([0.3, -0.2, 0.5])
    chain = dk.PoEChain.from_screws([[*np.cross(p, w), *w]], home)  # [-w x p; w] with |w| = 1 + 5e-7
    S = np.asarray(chain.screws)
    np.testing.assert_allclose(np.linalg.norm(S[0, 3:]), 1.0, rtol=0, atol=1e-15)
    assert abs(np.dot(S[0, :3], S[0, 3:])) < 1e-15
    # The rotation about the unit axis through p, to rounding.
    u, th = w / np.linalg.norm(w), 1.3
    K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    T = np.asarray(dk.fk(chain, np.array([th])))
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], p - R @ p, atol=1e-15)


def test_bool_and_complex_tables_and_q_are_type_errors():
    with pytest.raises(TypeError, match=r"^table: expected an array of real numbers, got dtype bool"):
        dk.DHChain.from_table(np.ones((2, 4), bool))
    with pytest.raises(TypeError, match=r"^table: expected an array of real numbers, got dtype complex"):
        dk.DHChain.from_table(np.ones((2, 4), complex))
    with pytest.raises(TypeError, match=r"^modified: expected True or False"):
        dk.DHChain.from_table(np.ones((2, 4)), modified="False")
    with pytest.raises(TypeError, match=r"^joint_names: expected a tuple or list"):
        dk.DHChain.from_table(np.ones((3, 4)), joint_names="abc")
    with pytest.raises(TypeError, match=r"^screws: expected an array of real numbers"):
        dk.PoEChain.from_screws(np.ones((1, 6), complex), np.eye(4))
    chain = dk.robots.iiwa14()
    for q in (np.zeros(7, bool), np.zeros(7, complex)):
        with pytest.raises(TypeError, match=r"^q: expected real joint values"):
            dk.fk(chain, q)
        with pytest.raises(TypeError, match=r"^q: expected real joint values"):
            dk.jacobian(chain, q)


@pytest.mark.parametrize(
    "kind, changes, match",
    [  # two faults each: the first in the order of the checks is named
        ("dh", {"a": np.zeros(6), "velocity": np.ones(6)}, r"^a: expected shape"),
        ("dh", {"velocity": np.ones(6), "base": np.eye(3)}, r"^velocity: expected shape"),
        ("dh", {"lower": np.full(7, 1.0), "upper": np.zeros(7), "base": _SCALED}, r"^lower\[0\] = 1.0 > upper"),
        ("poe", {"home": np.eye(3), "lower": np.zeros(6)}, r"^home: expected shape"),
        ("poe", {"joint_types": "RRRRRRP", "upper": np.full(7, -10.0)}, r"^joint_types\[6\]: 'P' contradicts"),
        ("poe", {"joint_names": ("a",) * 7, "screws": np.zeros((6, 6))}, r"^joint_names: expected distinct"),
    ],
)
def test_chains_check_their_fields_in_one_order(kind, changes, match):
    """The serial chains' shared check: static fields, the chain's own leaves, ``lower``/``upper``/``velocity``,
    then the chain's own values (DH: the limits, then base and tool; PoE: screws and poses, then the limits)."""
    chain = dk.robots.iiwa14() if kind == "dh" else dk.load_urdf(IIWA_URDF)
    with pytest.raises(ValueError, match=match):
        chain.replace(**changes)
