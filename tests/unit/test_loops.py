"""Closed kinematic loops (MJCF ``<equality><connect>``) on a planar four-bar: the dependent joints against the
four-bar's closed-form position analysis, closure, implicit-function derivatives against central differences,
the gap reported where the loop cannot close, and loading errors (the Robotiq 2F-85 and Cassie against
MuJoCo: ``tests/validation/test_loops_validation.py``)."""

import dataclasses
import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _fuzzing import FUZZ, finite_floats
from _mjcf import WELDED_ARMS
from _models import FOUR_BAR
from _paths import DATA
from hypothesis import example, given
from hypothesis import strategies as st

import diffkin as dk
from diffkin._static import is_concrete
from diffkin.models import _loops

# The four-bar's dimensions (tests/_models.py: FOUR_BAR)
GROUND, CRANK = np.array([0.25, 0.0]), 0.1
COUPLER, ROCKER = np.hypot(0.1, 0.2), np.hypot(-0.05, 0.2)


@pytest.fixture(scope="module")
def four_bar():
    return dk.load_robot(FOUR_BAR)


N = 41  # the four-bar's batches of crank angles, padded to N rows: `solved` compiles once


def _batch(theta) -> jax.Array:
    """Crank angles as an ``(N, 1)`` batch, padded with the reference configuration (zero)."""
    theta = np.asarray(theta, np.float64)
    return jnp.asarray(np.pad(theta, (0, N - len(theta)))[:, None])


@pytest.fixture(scope="module")
def solved(four_bar):
    """At ``(N, 1)`` crank angles: the dependent joints and the gap, the coupler's and the rocker's poses, the
    tip's, the centre of mass (the four-bar closed over: its constants fold, which compiles far faster than a
    robot passed as an argument)."""

    @jax.jit
    def run(q):
        dependent, gap = dk.loop_closure(four_bar, q)
        return dependent, gap, dk.fk(four_bar, q, ["coupler", "rocker"]), dk.fk(four_bar, q, "tip"), dk.com(four_bar, q)

    return run


def _closed_form(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coupler's and the rocker's joint angles of the four-bar at crank angles ``theta``: the pin is where the
    circle about the crank's tip (radius: the coupler's) meets the circle about the rocker's pivot, on the side
    of the reference configuration (left of the line from the crank's tip to the pivot)."""
    tip = CRANK * np.stack([np.cos(theta), np.sin(theta)], -1)
    d = GROUND - tip
    dist = np.linalg.norm(d, axis=-1)
    a = (COUPLER**2 - ROCKER**2 + dist**2) / (2 * dist)
    h = np.sqrt(COUPLER**2 - a**2)
    u = d / dist[:, None]
    pin = tip + a[:, None] * u + h[:, None] * np.stack([-u[:, 1], u[:, 0]], -1)
    coupler_dir = np.arctan2(*(pin - tip)[:, ::-1].T) - np.arctan2(0.2, 0.1)  # the coupler's angle in the world
    rocker_dir = np.arctan2(*(pin - GROUND)[:, ::-1].T) - np.arctan2(0.2, -0.05)
    wrap = lambda x: (x + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    return wrap(coupler_dir - theta), wrap(rocker_dir)


def test_the_coupler_and_rocker_are_solved_from_the_crank(four_bar, solved):
    assert four_bar.joint_names == ("crank",) and four_bar.dependent_names == ("coupler", "rocker")
    theta = np.linspace(-np.pi, np.pi, N)
    dependent, gap, poses = (np.asarray(x) for x in solved(_batch(theta))[:3])
    assert gap.max() < 1e-12
    coupler, rocker = _closed_form(theta)
    turns = lambda a, b: np.angle(np.exp(1j * (a - b)))  # noqa: E731  (the same angle, up to whole turns)
    np.testing.assert_allclose(turns(dependent[:, 0], coupler), 0.0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(turns(dependent[:, 1], rocker), 0.0, rtol=0, atol=1e-10)
    # the pin of each body, from their poses: the same point
    pin_coupler = poses[:, 0] @ np.array([0.1, 0.2, 0, 1])
    pin_rocker = poses[:, 1] @ np.array([-0.05, 0.2, 0, 1])
    np.testing.assert_allclose(pin_coupler, pin_rocker, rtol=0, atol=1e-12)


@FUZZ
@given(st.lists(finite_floats(-200.0, 200.0), min_size=1, max_size=N))
@example([10.07, -8.78, 13.07, 15.07])  # (issue 56: the other assembly mode, or open by 1.2 m and 3.3 m)
def test_the_crank_keeps_the_reference_branch_over_many_turns(solved, theta):
    """The crank turns fully (Grashof): at any angle, however many turns from the reference, the loop closes in
    the reference's assembly mode (the closed form's), as the linkage does when it is turned there (issue 56)."""
    theta = np.asarray(theta)
    dependent, gap = (np.asarray(x)[: len(theta)] for x in solved(_batch(theta))[:2])
    assert gap.max() < 1e-12
    coupler, rocker = _closed_form(theta)
    np.testing.assert_allclose(np.angle(np.exp(1j * (dependent[:, 0] - coupler))), 0.0, rtol=0, atol=1e-10)
    np.testing.assert_allclose(np.angle(np.exp(1j * (dependent[:, 1] - rocker))), 0.0, rtol=0, atol=1e-10)


def test_a_four_bar_passed_as_an_argument_keeps_its_branch_too(four_bar):
    """A robot traced by ``jit`` (its limits and multipliers unknown when traced) finds its hinge unlimited all
    the same: many turns from the reference, the same branch."""
    theta = np.array([13.07, -8.78, 100.5])
    dependent, gap = (np.asarray(x) for x in jax.jit(dk.loop_closure)(four_bar, theta[:, None]))
    assert gap.max() < 1e-12
    coupler, rocker = _closed_form(theta)
    np.testing.assert_allclose(np.angle(np.exp(1j * (dependent - np.stack([coupler, rocker], -1)))), 0.0, atol=1e-10)


def test_only_unlimited_hinges_are_turned_back_by_whole_turns(four_bar):
    """The crank (no limits) is moved by whole turns before the staged solve; a limited joint, or a hinge that
    turns a joint by half its value (a turn of it is not a turn of the joint), is followed as it is."""
    assert _loops._periodic(four_bar) == [True]
    limited = dataclasses.replace(four_bar, lower=jnp.asarray([-20.0]), upper=jnp.asarray([20.0]))
    half = dataclasses.replace(four_bar, multipliers=jnp.asarray([0.5, 1.0, 1.0]))
    assert _loops._periodic(limited) == [False] and _loops._periodic(half) == [False]


def test_a_connect_between_sites_is_the_same_loop(solved):
    """MuJoCo's site form: the two sites' origins coincide (here where the body form puts the pin)."""
    sites = FOUR_BAR.replace('<site name="tip"', '<site name="pin_c" pos=".1 .2 0"/><site name="tip"').replace(
        '<geom size=".01" mass=".1"/></body>', '<geom size=".01" mass=".1"/><site name="pin_r" pos="-.05 .2 0"/></body>'
    )
    robot = dk.load_robot(
        sites.replace('body1="coupler" body2="rocker" anchor=".1 .2 0"', 'site1="pin_c" site2="pin_r"')
    )
    theta = np.linspace(-3.0, 3.0, 7)
    np.testing.assert_allclose(
        np.asarray(dk.loop_closure(robot, theta[:, None])[0]), np.asarray(solved(_batch(theta))[0])[:7], atol=1e-12
    )


def test_a_connect_names_sites_in_their_own_namespace(solved):
    """A site named as a body is the frame ``site:{name}`` (MuJoCo keeps sites and bodies apart), and the connect
    pins that site, not the body; a site that is not there is named in the error."""
    sites = FOUR_BAR.replace('<site name="tip"', '<site name="pin_c" pos=".1 .2 0"/><site name="tip"').replace(
        '<geom size=".01" mass=".1"/></body>',
        '<geom size=".01" mass=".1"/><site name="rocker" pos="-.05 .2 0"/></body>',
    )
    robot = dk.load_robot(
        sites.replace('body1="coupler" body2="rocker" anchor=".1 .2 0"', 'site1="pin_c" site2="rocker"')
    )
    assert "site:rocker" in robot.frame_names and "rocker" in robot.frame_names
    theta = np.linspace(-3.0, 3.0, 7)
    np.testing.assert_allclose(
        np.asarray(dk.loop_closure(robot, theta[:, None])[0]), np.asarray(solved(_batch(theta))[0])[:7], atol=1e-12
    )
    missing = sites.replace('body1="coupler" body2="rocker" anchor=".1 .2 0"', 'site1="pin_c" site2="nowhere"')
    with pytest.raises(ValueError, match=r"^MJCF <equality><connect>: unknown site 'nowhere'$"):
        dk.load_robot(missing)


@pytest.mark.parametrize("relpose", ["", ' relpose=".1 .2 0 0.9659258 0 0 0.2588190"'], ids=["reference", "relpose"])
def test_a_weld_holds_the_relative_pose(relpose):
    """The weld keeps body2's pose in body1: the one at the reference configuration, or ``relpose`` (position,
    then the quaternion of a 30 degree turn about z)."""
    robot = dk.load_robot(WELDED_ARMS.format(relpose=relpose))
    assert robot.joint_names == ("a1", "b1") and set(robot.dependent_names) == {"a2", "a3", "b2"}
    if relpose:
        angle = 2 * np.arctan2(0.2588190, 0.9659258)  # the quaternion's turn about z (~30 degrees)
        T_rel = np.eye(4)
        T_rel[:3, :3] = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
        T_rel[:3, 3] = [0.1, 0.2, 0.0]
    else:
        # (the loops close at the reference, q = 0: a batch of q's shape, whose compiles the calls below reuse)
        T0 = np.asarray(dk.fk(robot, np.zeros((16, 2)), ["a3", "b2"]))[0]
        T_rel = np.linalg.solve(T0[0], T0[1])
    q = np.random.default_rng(0).uniform(-0.2, 0.2, (16, 2))
    _, gap = dk.loop_closure(robot, q)
    T = np.asarray(dk.fk(robot, q, ["a3", "b2"]))
    closed = np.asarray(gap) < 1e-12
    assert closed.sum() >= 8
    np.testing.assert_allclose(
        np.linalg.solve(T[closed, 0], T[closed, 1]), np.broadcast_to(T_rel, (closed.sum(), 4, 4)), atol=1e-12
    )


def test_derivatives_are_the_implicit_functions(four_bar, solved):
    theta = np.linspace(-3.0, 3.0, 13)
    n, step = len(theta), 1e-6

    @jax.jit
    def derivatives(q):
        """d dependent / d crank (forward mode), the tip's Jacobian (analytic and autodiff), the centre of mass's."""
        d_dependent = jax.vmap(jax.jacfwd(lambda q: dk.loop_closure(four_bar, q)[0]))(q)
        analytic, autodiff = dk.jacobian(four_bar, q, "tip"), dk.jacobian(four_bar, q, "tip", method="autodiff")
        return d_dependent, analytic, autodiff, dk.com_jacobian(four_bar, q)

    d_dep, analytic, autodiff, J_com = (np.asarray(x) for x in derivatives(jnp.asarray(theta[:, None])))
    (dep_plus, _, _, tip_plus, com_plus), (dep_minus, _, _, tip_minus, com_minus) = (
        [np.asarray(x)[:n] for x in solved(_batch(theta + s))] for s in (step, -step)
    )
    np.testing.assert_allclose(d_dep[..., 0], (dep_plus - dep_minus) / (2 * step), rtol=0, atol=1e-8)
    np.testing.assert_allclose(analytic, autodiff, rtol=0, atol=1e-12)
    dp = (tip_plus - tip_minus) / (2 * step)
    np.testing.assert_allclose(analytic[:, :3, 0], dp[:, :3, 3], rtol=0, atol=1e-8)
    np.testing.assert_allclose(J_com[..., 0], (com_plus - com_minus) / (2 * step), atol=1e-9)


def test_both_jacobians_are_the_linearised_closure_where_a_loop_stays_open():
    """The welded arms at random ``q``: where the weld closes, the analytic and autodiff Jacobians are the
    derivative of ``fk`` (central differences); where it cannot close, ``fk`` returns the solve's last
    Gauss-Newton iterate, not a smooth function of ``q`` (its differences run to 1e5), the gap says it is
    open, and both Jacobians are the same motion: the loop held closed to first order, in least squares
    (``J_q + J_dep G``, ``G = -pinv(C_dep) C_q`` of the weld's points on the arms as a tree). The autodiff one
    differed by up to 14 there (the derivative of the last step's matrix times the open residual; issue 56)."""
    robot = dk.load_robot(WELDED_ARMS.format(relpose=""))
    tree = dk.load_robot(WELDED_ARMS.format(relpose="").split("<equality>")[0] + "</mujoco>")  # every joint in q
    q = np.random.default_rng(1).uniform(-0.6, 0.6, (24, 2))
    order = [tree.joint_names.index(n) for n in robot.joint_names + robot.dependent_names]
    (a, b), points = robot.loop_bodies[0], np.asarray(robot.loop_points)  # the weld's three points on a3 and b2
    assert [robot.frame_bodies[robot.frame_index(n)] for n in ("a3", "b2")] == [a, b] and len(robot.loop_bodies) == 3

    def residual(x):  # (9,): the weld's points on a3 less those on b2, the tree at x (robot's q, then dependent)
        T = dk.fk(tree, jnp.zeros(tree.dof).at[jnp.asarray(order)].set(x), ["a3", "b2"])
        ends = [T[k, :3, :3] @ points[:, k].T + T[k, :3, 3:] for k in (0, 1)]
        return (ends[0] - ends[1]).T.reshape(-1)

    @jax.jit
    def derivatives(q):
        dependent, gap = dk.loop_closure(robot, q)
        x = jnp.concatenate([q, dependent], -1)
        C = jax.vmap(jax.jacfwd(residual))(x)
        J_tree = dk.jacobian(tree, jnp.zeros((len(q), tree.dof)).at[:, jnp.asarray(order)].set(x), "a3")
        analytic, autodiff = dk.jacobian(robot, q, "a3"), dk.jacobian(robot, q, "a3", method="autodiff")
        return gap, C, J_tree[..., jnp.asarray(order)], analytic, autodiff

    gap, C, J_tree, analytic, autodiff = (np.asarray(x) for x in derivatives(jnp.asarray(q)))
    closed, open_ = gap < 1e-12, gap > 1e-3
    assert closed.sum() >= 8 and open_.sum() >= 4 and np.all(closed | open_)
    np.testing.assert_allclose(autodiff, analytic, rtol=0, atol=1e-12)
    C_dep, C_q = C[..., 2:], C[..., :2]  # d dependent / d q holding the weld in least squares, damped as the solve
    A = np.swapaxes(C_dep, -1, -2) @ C_dep
    A += _loops.DAMPING * np.trace(A, axis1=-2, axis2=-1)[:, None, None] * np.eye(3)
    G = -np.linalg.solve(A, np.swapaxes(C_dep, -1, -2) @ C_q)  # (n, 3, 2)
    np.testing.assert_allclose(analytic, J_tree[..., :2] + J_tree[..., 2:] @ G, rtol=0, atol=1e-11)
    step, T = 1e-6, np.asarray(dk.fk(robot, q, "a3"))
    for i in range(robot.dof):
        dT = [np.asarray(dk.fk(robot, q + s * np.eye(robot.dof)[i], "a3")) for s in (step, -step)]
        dT = (dT[0] - dT[1]) / (2 * step)
        W = dT[:, :3, :3] @ np.swapaxes(T[:, :3, :3], -1, -2)  # [w] = dR R^T
        fd = np.concatenate([dT[:, :3, 3], W[:, [2, 0, 1], [1, 2, 0]]], -1)
        np.testing.assert_allclose(analytic[closed, :, i], fd[closed], rtol=1e-6, atol=1e-8)


def test_a_loop_that_cannot_close_says_so():
    """A crank longer than the rest allows: the loop opens for some crank angles; finite values and a gap."""
    xml = FOUR_BAR.replace('pos=".1 0 0"', 'pos=".3 0 0"', 1)  # crank 0.3: out of reach half a turn away
    robot = dk.load_robot(xml)
    theta = jnp.asarray(np.concatenate([np.linspace(-np.pi, np.pi, 25), [1e3, -1e6]])[:, None])
    dependent, gap = (np.asarray(x) for x in dk.loop_closure(robot, theta))
    assert np.all(np.isfinite(dependent)) and np.all(np.isfinite(gap))
    assert gap[0] > 0.05 and gap[12] < 1e-12  # open at a half turn, closed at the reference
    d_gap = jax.grad(lambda q: dk.loop_closure(robot, q)[1].sum())(theta[10:14])  # a closed one among them
    assert np.all(np.isfinite(np.asarray(d_gap)))
    # (IK counts an open loop as no success: tests/validation/test_loops_validation.py, on the 2F-85)


def test_the_gap_is_the_one_of_the_returned_poses():
    """Open or closed, the gap ``loop_closure`` reports is the pin's mismatch between the coupler's and the rocker's
    poses ``link_poses`` returns at the same ``q`` (the pin in each body: at (0.1, 0.2) from the crank's tip in
    the coupler; where the coupler puts it at the reference, (0.4, 0.2), in the rocker pivoted at (0.25, 0)).
    The crank 0.3 long: it cannot close half a turn away (issue 56)."""
    robot = dk.load_robot(FOUR_BAR.replace('pos=".1 0 0"', 'pos=".3 0 0"', 1))
    theta = np.random.default_rng(4).uniform(-20.0, 20.0, (24, 1))
    _, gap = dk.loop_closure(robot, theta)
    T = np.asarray(dk.link_poses(robot, theta))
    coupler, rocker = (T[:, robot.frame_names.index(name)] for name in ("coupler", "rocker"))
    mismatch = np.linalg.norm(coupler @ [0.1, 0.2, 0, 1] - rocker @ [0.15, 0.2, 0, 1], axis=-1)
    assert (mismatch > 1e-3).sum() >= 4 and (mismatch < 1e-12).sum() >= 4  # open and closed among them
    np.testing.assert_allclose(np.asarray(gap), mismatch, rtol=0, atol=1e-12)


def test_eager_calls_run_the_solve_compiled_once_per_model_and_shape(solved):
    """Outside any trace the loop solve runs compiled, one program per model (by value) and shape of ``q``: a
    second eager call, with new values and the four-bar loaded again, compiles nothing (the solve's Gauss-Newton
    loop was lowered and compiled again at every eager call: 0.3 of the 0.35 s of an eager ``dk.fk`` of 81
    configurations of the 2F-85), and its values are the jitted ones (issue 56)."""
    theta = np.linspace(-3.0, 3.0, N)
    dk.loop_closure(dk.load_robot(FOUR_BAR), _batch(theta))
    programs = _loops._compiled._cache_size()
    dependent, gap = dk.loop_closure(dk.load_robot(FOUR_BAR), _batch(theta + 0.5))
    assert _loops._compiled._cache_size() == programs >= 1
    jitted = solved(_batch(theta + 0.5))
    np.testing.assert_allclose(np.asarray(dependent), np.asarray(jitted[0]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(gap), np.asarray(jitted[1]), rtol=0, atol=1e-12)


def test_a_closed_over_robot_folds_into_the_solve(four_bar, monkeypatch):
    """Jitted with the robot closed over, every Gauss-Newton step of the solve reads the robot's numbers as
    constants, folded (its frozen copy for the steps without gradients was traced: Cassie's loop solve of 81
    configurations ran 8 s jitted, 21 ms folded) (issue 56)."""
    concrete = []
    normal_equations = _loops._normal_equations
    monkeypatch.setattr(
        _loops,
        "_normal_equations",
        lambda robot, *args: concrete.append(is_concrete(robot.joint_poses)) or normal_equations(robot, *args),
    )
    jax.make_jaxpr(lambda q: dk.loop_closure(four_bar, q))(jnp.zeros((2, 1)))
    assert len(concrete) == 2 and all(concrete)  # the staged steps' and the last one's


def test_a_non_finite_crank_angle_leaves_the_loop_open(four_bar):
    """NaN and infinite ``q`` cannot close a loop: the gap is infinite, never the 0 of a closed one (issue 56)."""
    theta = jnp.asarray([[np.nan], [np.inf], [-np.inf], [0.0]])
    _, gap = dk.loop_closure(four_bar, theta)
    np.testing.assert_array_equal(np.asarray(gap)[:3], np.inf)
    assert np.asarray(gap)[3] < 1e-12


def test_a_loop_robot_in_float32_loads_and_runs_without_warnings():
    """The 2F-85 under a user's default settings (x64 off): no library-internal dtype warnings (issue 56)."""
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.simplefilter("error")
        robot = dk.load_robot(os.path.join(DATA, "robotiq_2f85.xml"))
        q = np.zeros(robot.dof, np.float32)
        assert dk.fk(robot, q, "pinch").dtype == jnp.float32 and dk.link_poses(robot, q).dtype == jnp.float32
        assert float(dk.loop_closure(robot, q)[1]) < 1e-5


def test_bad_loops_are_refused():
    with pytest.raises(ValueError, match="MJCF <equality><connect body1='coupler'>: unknown body or site 'nowhere'"):
        dk.load_robot(FOUR_BAR.replace('body2="rocker"', 'body2="nowhere"'))
    every = FOUR_BAR.replace("</actuator>", '<motor joint="coupler"/><motor joint="rocker"/></actuator>')
    with pytest.raises(ValueError, match="no joint left to solve"):
        dk.load_robot(every)
    with pytest.raises(ValueError, match="closes a loop"):
        dk.load_robot(FOUR_BAR).chain("rocker")
