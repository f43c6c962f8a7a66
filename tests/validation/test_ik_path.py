"""dk.ik.solve_path: the iiwa14 along lines and circles against its closed form (dk.srs), Panda and UR5
paths within tolerance and step bounds (and one through the workspace boundary reported), implicit
gradients against finite differences, a whole robot's path, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import URDF_ROBOTS

import diffkin as dk
import diffkin.srs as srs

T_WAYPOINTS = 24


def _paths(T0: np.ndarray, radius: float) -> np.ndarray:
    """``(4, T, 4, 4)``: from ``T0``, two straight lines (x, then y and z) and two circles (in the xy and
    xz planes) of ``radius``, the orientation held."""
    s = np.linspace(0.0, 1.0, T_WAYPOINTS)
    out = np.tile(T0, (4, T_WAYPOINTS, 1, 1))
    out[0, :, 0, 3] += 2 * radius * s
    out[1, :, 1, 3] -= 1.5 * radius * s
    out[1, :, 2, 3] += radius * s
    angle = 2 * np.pi * s
    for k, (a, b) in ((2, (0, 1)), (3, (0, 2))):
        out[k, :, a, 3] += radius * (np.cos(angle) - 1.0)
        out[k, :, b, 3] += radius * np.sin(angle)
    return out


def test_iiwa_paths_stay_in_one_configuration_on_the_closed_form():
    """Every waypoint's solution is the closed-form solution at its own arm angle, in the global
    configuration of waypoint 0, and the arm angle moves little between waypoints (float64)."""
    chain, arm = dk.robots.iiwa14(), srs.iiwa14()
    q_start = np.array([0.3, 0.7, -0.2, -1.2, 0.4, 0.9, 0.1])
    paths = _paths(np.asarray(dk.fk(chain, q_start)), 0.05)
    res = dk.ik.solve_path(
        chain, jnp.asarray(paths), q0=jnp.asarray(q_start), max_step=0.1, pos_tol=1e-10, rot_tol=1e-10
    )
    assert res.q.shape == (4, T_WAYPOINTS, 7) and bool(jnp.all(res.path_ok)), res.success
    psi, gc = srs.arm_angle(arm, res.q)
    assert np.all(np.asarray(gc) == np.asarray(gc)[:, :1]), "the global configuration changed along a path"
    q_closed, valid = srs.ik(arm, jnp.asarray(paths), psi, gc)
    assert bool(jnp.all(valid))
    assert float(jnp.max(jnp.abs(q_closed - res.q))) < 1e-6
    assert float(jnp.max(jnp.abs(jnp.diff(psi, axis=-1)))) < 0.05
    assert float(jnp.max(res.max_step)) <= 0.1 + 1e-15


@pytest.mark.parametrize("name", ["panda", "ur5"])
def test_lines_and_circles_within_tolerance_and_step_bounds(name, urdf_chains):
    """Four paths inside the workspace, every waypoint re-checked in float64; a fifth goes out through
    the arm's reach: reported (not ok, finite values, steps still bounded)."""
    chain = urdf_chains[name]
    q_start = {"panda": [0.1, -0.3, 0.2, -2.0, 0.1, 1.8, 0.5], "ur5": [0.3, -1.2, 1.4, -0.7, 1.1, 0.4]}[name]
    T0 = np.asarray(dk.fk(chain, np.asarray(q_start)))
    out = np.tile(T0, (1, T_WAYPOINTS, 1, 1))
    out[0, :, 0, 3] += np.linspace(0.0, 1.5, T_WAYPOINTS)
    paths = np.concatenate([_paths(T0, 0.1), out])
    res = dk.ik.solve_path(chain, jnp.asarray(paths, jnp.float32), q0=jnp.asarray(q_start, jnp.float32), max_step=0.1)
    assert np.array_equal(np.asarray(res.path_ok), [True, True, True, True, False])
    assert bool(jnp.all(res.success[:4])) and bool(res.success[4, 0]) and not bool(res.success[4, -1])
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in (res.q, res.pos_err, res.rot_err, res.max_step))
    # re-checked in float64 against the float64 waypoints
    T = np.asarray(dk.fk(chain, np.asarray(res.q[:4], np.float64)))
    assert np.linalg.norm(T[..., :3, 3] - paths[:4, :, :3, 3], axis=-1).max() <= 1e-5
    with jax.enable_x64(True):
        rot = np.asarray(dk.se3.rotation_angle(paths[:4, :, :3, :3] @ np.swapaxes(T[..., :3, :3], -1, -2)))
    assert rot.max() <= 1e-4
    steps = np.abs(np.diff(np.asarray(res.q, np.float64), axis=1)).max(axis=(1, 2))
    assert steps.max() <= 0.1 + 1e-6 and np.allclose(steps, np.asarray(res.max_step), atol=1e-6)


def test_implicit_gradients_of_a_path_match_finite_differences():
    """UR5 (not redundant: one solution per waypoint near the last), float64: d q_t / d (waypoint t's
    position) against central differences of whole path solves."""
    chain = dk.robots.ur5()
    q_start = np.array([0.3, -1.2, 1.4, -0.7, 1.1, 0.4])
    path = jnp.asarray(_paths(np.asarray(dk.fk(chain, q_start)), 0.05)[2, ::4])  # a circle, 6 waypoints

    def q_of(p):
        return dk.ik.solve_path(
            chain, p, q0=jnp.asarray(q_start), num_seeds=1, max_step=0.2, pos_tol=1e-12, rot_tol=1e-12
        ).q

    direction = jnp.zeros_like(path).at[:, :3, 3].set(jnp.asarray(np.random.default_rng(4).normal(size=(6, 3))))
    h = 1e-6
    fd = (q_of(path + h * direction) - q_of(path - h * direction)) / (2 * h)
    _, jvp = jax.jvp(q_of, (path,), (direction,))
    np.testing.assert_allclose(jvp, fd, rtol=1e-5, atol=1e-6)


def test_a_robot_path_with_a_locked_joint(urdf_chains):
    """A whole robot (the Panda tree: mimic finger) along a line, a finger locked; a position target."""
    robot = dk.load_robot(URDF_ROBOTS["panda"][0])
    q_start = np.array([0.1, -0.3, 0.2, -2.0, 0.1, 1.8, 0.5, 0.02])
    p0 = np.asarray(dk.fk(robot, q_start, "panda_link8"))[:3, 3]
    line = p0 + np.linspace(0.0, 0.15, 10)[:, None] * np.array([0.0, 1.0, 0.0])
    res = dk.ik.solve_path(
        robot,
        {"panda_link8": jnp.asarray(line, jnp.float32)},
        q0=jnp.asarray(q_start, jnp.float32),
        locked=["panda_finger_joint1"],
        max_step=0.1,
    )
    assert bool(res.path_ok) and res.pos_err.shape == (10, 1)
    assert np.all(np.asarray(res.q[:, 7]) == np.float32(0.02))
    reached = np.asarray(dk.fk(robot, np.asarray(res.q, np.float64), "panda_link8"))[:, :3, 3]
    assert np.linalg.norm(reached - line, axis=-1).max() <= 1e-5
    # a non-finite root pose: every waypoint fails, with finite values
    nan_base = jnp.eye(4, dtype=jnp.float32).at[0, 3].set(jnp.nan)
    bad = dk.ik.solve_path(robot, {"panda_link8": jnp.asarray(line, jnp.float32)}, base=nan_base, max_step=0.1)
    assert not bool(jnp.any(bad.success)) and all(bool(jnp.all(jnp.isfinite(x))) for x in (bad.q, bad.max_step))


def test_bad_arguments_raise():
    chain = dk.robots.ur5()
    path = jnp.tile(jnp.eye(4), (3, 1, 1))
    for kwargs, error, match in [
        (dict(max_step=0.0), ValueError, "max_step: expected positive"),
        (dict(max_step=np.ones(5)), ValueError, "max_step: expected a positive number or 6"),
        (dict(secondary="rest"), ValueError, "not supported by solve_path"),
        (dict(colour="red"), TypeError, "unexpected arguments"),
    ]:
        with pytest.raises(error, match=match):
            dk.ik.solve_path(chain, path, **kwargs)
    with pytest.raises(ValueError, match="expected a path axis"):
        dk.ik.solve_path(chain, jnp.eye(4))
