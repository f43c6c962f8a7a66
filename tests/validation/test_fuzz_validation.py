"""Property-based fuzzing of the MJCF reader against MuJoCo (hypothesis): random kinematic trees (default
classes, frames, every orientation form) give MuJoCo's frames, limits and poses; random include
structures load as MuJoCo loads them or are rejected as MuJoCo rejects them. And whole-robot IK: random
targets, weights and locked joints of a tree. And the Jacobian properties of ``tests/unit/test_fuzz.py``
on the long chains (7 and 8 joints: compiling their Jacobians is slow). Budgets and the time limit as in
``tests/unit/test_fuzz.py`` (``DIFFKIN_FUZZ_EXAMPLES``)."""

import _reference
import hypothesis.extra.numpy as hnp
import jax.numpy as jnp
import numpy as np
import pytest
from _chain_fuzz import (
    LONG_DH_STRUCTURES,
    LONG_POE_STRUCTURES,
    chains,
    check_fk_and_jacobians_finite_for_any_finite_q,
    check_jacobians_match_central_differences,
)
from _fuzzing import EXAMPLES, FUZZ, MJCF_FUZZ, MJCF_TIME_LIMIT, time_limit
from _fuzzing import finite_floats as _floats
from _fuzzing import number_text as _text
from _models import FINGER
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import diffkin as dk
from diffkin._xla import solver_jit  # compiled as dk.ik.solve compiles itself

# Each example runs under a SIGALRM limit (a hang, such as an include bomb, fails the test instead of
# stalling CI) and a hypothesis deadline (an example slower than that is reported). No JAX compilation:
# poses come from the robot's arrays by the NumPy reference.
_MASSES = '<compiler boundmass="1" boundinertia="0.1"/>'  # MuJoCo needs them; no kinematic effect


def _coordinate(bound: float):
    """0 or a magnitude in ``[1e-3, bound]``: MuJoCo's compiler treats a frame within about 1e-6 of its
    parent's as that frame (``site_sameframe``), an approximation a test cannot follow."""
    return st.one_of(st.just(0.0), _floats(1e-3, bound), _floats(-bound, -1e-3))


def _vector(draw, n: int, bound: float, min_norm: float = 0.0) -> np.ndarray:
    values = st.lists(_coordinate(bound), min_size=n, max_size=n).filter(lambda v: np.linalg.norm(v) > min_norm)
    return np.array(draw(values))


@st.composite
def mjcf_orientations(draw) -> str:
    """An orientation attribute in one of MuJoCo's forms (or none)."""
    form = draw(st.sampled_from(["", "quat", "axisangle", "euler", "xyaxes", "zaxis"]))
    if form == "quat":
        return f'quat="{_text(_vector(draw, 4, 1, 0.1))}"'
    if form == "axisangle":
        return f'axisangle="{_text([*_vector(draw, 3, 1, 0.1), draw(_coordinate(400))])}"'
    if form == "euler":
        return f'euler="{_text(_vector(draw, 3, 400))}"'
    if form == "xyaxes":
        x = _vector(draw, 3, 1, 0.1)
        y = _vector(draw, 3, 1, 0.1)
        assume(np.linalg.norm(np.cross(x, y)) > 0.1 * np.linalg.norm(x) * np.linalg.norm(y))
        return f'xyaxes="{_text([*x, *y])}"'
    if form == "zaxis":
        return f'zaxis="{_text(_vector(draw, 3, 1, 0.1))}"'
    return ""


@st.composite
def mjcf_joint_attributes(draw) -> str:
    """Some of a joint's attributes: type, axis, anchor, range, ref."""
    parts = []
    if draw(st.booleans()):
        parts.append(f'type="{draw(st.sampled_from(["hinge", "slide"]))}"')
    if draw(st.booleans()):
        parts.append(f'axis="{_text(_vector(draw, 3, 1, 0.1))}"')
    if draw(st.booleans()):
        parts.append(f'pos="{_text(_vector(draw, 3, 0.5))}"')
    if draw(st.booleans()):
        lower = draw(_floats(-90, 80))
        parts.append(f'range="{_text([lower, lower + draw(_floats(1, 90))])}"')
    if draw(st.booleans()):
        parts.append(f'ref="{_text([draw(_floats(-30, 30))])}"')
    return " ".join(parts)


@st.composite
def mjcf_trees(draw) -> str:
    """A random ``<mujoco>`` kinematic tree: up to 3 default classes (nested at random, setting joint and
    site attributes), bodies to depth 3 with any orientation form, 0-2 hinge or slide joints each,
    ``<frame>``s, named sites and ``class``/``childclass`` references, in degrees or radians, any Euler
    sequence."""
    angle = draw(st.sampled_from(["degree", "radian"]))
    seq = draw(st.sampled_from(["xyz", "zyx", "XYZ", "zYx", "zxz"]))
    classes = [f"c{k}" for k in range(draw(st.integers(0, 3)))]
    parent = {c: draw(st.sampled_from(["main", *classes[:k]])) for k, c in enumerate(classes)}

    def default(name: str) -> str:
        inside = f"<joint {draw(mjcf_joint_attributes())}/>" if draw(st.booleans()) else ""
        if draw(st.booleans()):
            inside += f'<site pos="{_text(_vector(draw, 3, 0.5))}" {draw(mjcf_orientations())}/>'
        inside += "".join(default(c) for c in classes if parent[c] == name)
        return f"<default{'' if name == 'main' else f' class={name!r}'}>{inside}</default>"

    class_names = st.sampled_from(["", *classes])
    counter = iter(range(1000))

    def class_attribute(attribute: str) -> str:
        name = draw(class_names)
        return f"{attribute}={name!r}" if name else ""

    def contents(depth: int) -> str:
        items = []
        for _ in range(draw(st.integers(0, 2)) if depth else 0):  # (the world body has none)
            # (armature: two joints on one axis make MuJoCo's mass matrix singular, and it logs a warning)
            joint = f"name='j{next(counter)}' armature='1' {class_attribute('class')} {draw(mjcf_joint_attributes())}"
            items.append(f"<joint {joint}/>")
        if draw(st.booleans()):
            items.append(f"<site name='s{next(counter)}' {class_attribute('class')} {placement(0.5)}/>")
        if depth < 3:
            for _ in range(draw(st.integers(0 if depth else 1, 2))):
                items.append(body(depth + 1))
        return "".join(items)

    def placement(reach: float) -> str:
        return f'pos="{_text(_vector(draw, 3, reach))}" {draw(mjcf_orientations())}'

    def body(depth: int) -> str:
        pose, inner = placement(1.0), contents(depth)
        if draw(st.booleans()):  # its contents inside a <frame>
            inner = f"<frame {placement(1.0)} {class_attribute('childclass')}>{inner}</frame>"
        return f"<body name='b{next(counter)}' {class_attribute('childclass')} {pose}>{inner}</body>"

    compiler = f'<compiler angle="{angle}" eulerseq="{seq}"/>'
    return f"<mujoco>{_MASSES}{compiler}{default('main')}<worldbody>{contents(0)}</worldbody></mujoco>"


def _mujoco_poses(model, q: np.ndarray, names) -> np.ndarray:
    """``(len(names), 4, 4)`` MuJoCo's world poses of the bodies and sites ``names`` at ``qpos = q``.

    A site's pose is its body's pose times its compiled ``site_pos``/``site_quat``: MuJoCo's own
    ``site_xmat`` copies the body's rotation when its compiler finds the site's within about 1e-7 of
    the body's (``site_sameframe``), a shortcut, not the file's pose.
    """
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)

    def body_pose(b: int) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = data.xmat[b].reshape(3, 3), data.xpos[b]
        return T

    poses = []
    for name in names:
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if b >= 0:
            poses.append(body_pose(b))
            continue
        s = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
        T_body_site = np.eye(4)
        mujoco.mju_quat2Mat(R := np.zeros(9), model.site_quat[s])
        T_body_site[:3, :3], T_body_site[:3, 3] = R.reshape(3, 3), model.site_pos[s]
        poses.append(body_pose(model.site_bodyid[s]) @ T_body_site)
    return np.stack(poses)


@MJCF_FUZZ
@given(mjcf_trees(), st.integers(0, 2**32 - 1))
def test_mjcf_random_trees_match_mujoco(xml, seed):
    """diffkin's reading of a random tree: the frames, limits and, at random in-limit q, every body and site
    pose equal MuJoCo's (to 1e-10)."""
    import mujoco

    with time_limit(MJCF_TIME_LIMIT, "reading a random MJCF tree"):
        robot = dk.load_robot(xml)
        model = mujoco.MjModel.from_xml_string(xml)
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(model.nbody)]
    names[0] = "world"
    sites = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, s) for s in range(model.nsite)]
    names += sites
    for site in sites:  # MuJoCo takes a site within about 1e-6 of its body's frame for that frame
        T = np.asarray(robot.frame_poses[robot.frame_index(site)])
        assume(not 0 < np.abs(T[:3, :3] - np.eye(3)).max() < 1e-5 and not 0 < np.abs(T[:3, 3]).max() < 1e-5)
    assert sorted(robot.frame_names) == sorted(names)
    joints = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]
    assert list(robot.joint_names) == joints
    limited = model.jnt_limited.astype(bool)
    lower = np.where(limited, model.jnt_range[:, 0], -np.inf)
    upper = np.where(limited, model.jnt_range[:, 1], np.inf)
    np.testing.assert_allclose(robot.lower, lower, rtol=0, atol=1e-15)
    np.testing.assert_allclose(robot.upper, upper, rtol=0, atol=1e-15)
    rng = np.random.default_rng(seed)
    for q in rng.uniform(np.where(limited, lower, -np.pi), np.where(limited, upper, np.pi), (2, robot.dof)):
        ours = _reference.robot_poses(robot, q)
        np.testing.assert_allclose(ours, _mujoco_poses(model, q, robot.frame_names), rtol=0, atol=1e-10)


@st.composite
def include_structures(draw) -> dict[str, list[str]]:
    """Files ``f0 ... f{n-1}`` and the files each includes (``main.xml`` first): repeats, cycles, the main
    file itself, all possible."""
    files = [f"f{k}.xml" for k in range(draw(st.integers(1, 5)))]
    targets = st.sampled_from([*files, "main.xml"])
    structure = {"main.xml": draw(st.lists(st.sampled_from(files), min_size=1, max_size=3))}
    for name in files:
        structure[name] = draw(st.lists(targets, max_size=3))
    return structure


@MJCF_FUZZ
@given(include_structure=include_structures())
def test_mjcf_random_includes_as_mujoco(include_structure, tmp_path_factory):
    """Random include structures: diffkin loads exactly what MuJoCo loads (the same bodies), and rejects
    what MuJoCo rejects (a repeated or recursive include) with a ValueError naming the file."""
    import mujoco

    folder = tmp_path_factory.mktemp("includes")
    for name, included in include_structure.items():
        body = f"<body name='{name[:-4]}'><joint/>" + "".join(f"<include file='{f}'/>" for f in included) + "</body>"
        text = f"<worldbody>{body}</worldbody>" if name == "main.xml" else body
        (folder / name).write_text(f"<mujoco>{_MASSES if name == 'main.xml' else ''}{text}</mujoco>")
    try:
        model = mujoco.MjModel.from_xml_path(str(folder / "main.xml"))
    except ValueError as err:
        assert "already included" in str(err)
        model = None
    with time_limit(MJCF_TIME_LIMIT, "expanding random includes"):
        if model is None:
            rejected = r"file '.*\.xml' is included more than once|recursive include of '.*\.xml'"
            with pytest.raises(ValueError, match=rejected):
                dk.load_robot(str(folder / "main.xml"))
            return
        robot = dk.load_robot(str(folder / "main.xml"))
    bodies = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, model.nbody)]
    assert robot.frame_names == ("world", *bodies)


# ----- whole-robot IK: random targets, weights and locked joints -----------------------------------------

_FINGER_ROBOT = dk.load_robot(FINGER)
# Weights and locks are static (one compilation each): a few of them, the numbers random.
_ROBOT_WEIGHTS = [None, (1.0, 1.0, 0.0, 1.0, 1.0, 1.0), (1e-5, 1e-5)]
_ROBOT_LOCKS = [None, "finger_upper_to_middle_joint"]
_robot_solvers: dict = {}


def _robot_solve(weights, lock):
    if (weights, lock) not in _robot_solvers:
        w = None if weights is None else {"finger_tip_link": weights}

        def solve(p, locked_value):
            locked = None if lock is None else {lock: locked_value}
            return dk.ik.solve(_FINGER_ROBOT, {"finger_tip_link": p}, weights=w, locked=locked, num_seeds=8)

        _robot_solvers[weights, lock] = solver_jit(solve)
    return _robot_solvers[weights, lock]


@settings(FUZZ, max_examples=min(EXAMPLES, 12))
@given(st.data())
def test_robot_ik_success_means_the_weighted_target_is_reached(data):
    """A tree's frame by position (finger_edu), with random weights (a free world axis, uniformly tiny
    weights) and a random locked joint, reachable, far and non-finite targets: a success reaches its
    target on the weighted axes (NumPy FK of the tree), locked joints keep their value to the bit,
    every joint within its limits, every output finite."""
    weights, lock = data.draw(st.sampled_from(_ROBOT_WEIGHTS)), data.draw(st.sampled_from(_ROBOT_LOCKS))
    robot, tip = _FINGER_ROBOT, _FINGER_ROBOT.frame_index("finger_tip_link")
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    q_true = np.stack([data.draw(hnp.arrays(np.float64, 3, elements=_floats(0.0, 1.0))) for _ in range(3)])
    q_true = lo + q_true * (hi - lo)
    locked_value = data.draw(_floats(-1.0, 1.0))
    if lock is not None:
        q_true[:, robot.joint_names.index(lock)] = locked_value
    targets = np.stack([_reference.robot_poses(robot, q)[tip, :3, 3] for q in q_true])
    far = data.draw(st.sampled_from([1e3, 1e30, 1e300]))
    bad = data.draw(st.sampled_from([np.nan, np.inf]))
    p = np.concatenate([targets, [[far, 0.0, 0.0], [bad, 0.0, 0.0]]])
    with time_limit(120.0, "solving a whole robot's random targets"):
        res = _robot_solve(weights, lock)(jnp.asarray(p), jnp.full((5,), locked_value))
    for field in (f for f in res if f is not None):
        assert np.all(np.isfinite(np.asarray(field)))
    q, success = np.asarray(res.q), np.asarray(res.success)
    assert not success[3] and not success[4]
    assert np.all(q >= lo) and np.all(q <= hi)
    if lock is not None:
        assert np.all(q[:, robot.joint_names.index(lock)] == locked_value)
    axes = np.asarray([1.0, 1.0, 1.0] if weights is None or len(weights) == 2 else weights[:3]) > 0
    for i in np.flatnonzero(success):
        reached = _reference.robot_poses(robot, q[i])[tip, :3, 3]
        assert np.linalg.norm((reached - p[i])[axes]) <= 1e-5
    if lock is None and (weights is None or len(weights) == 2):  # 3 joints, 3 constraints: reachable ones solved
        assert np.all(success[:3])


# ----- the Jacobian properties of tests/unit/test_fuzz.py on the long chains ---------------------------------

LONG_CHAINS = chains(LONG_DH_STRUCTURES, LONG_POE_STRUCTURES)


@FUZZ
@given(st.data())
def test_fk_and_jacobian_finite_for_any_finite_q_long_chains(data):
    check_fk_and_jacobians_finite_for_any_finite_q(data, LONG_CHAINS)


@FUZZ
@given(st.data())
def test_jacobian_matches_central_differences_long_chains(data):
    check_jacobians_match_central_differences(data, LONG_CHAINS)
