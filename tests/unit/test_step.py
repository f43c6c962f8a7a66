"""dk.ik.step (velocity IK): its QP against an exact active-set enumeration (float64, 1e-8) and the
least violation of contradictory rows; the step against damped least squares from an autodiff
Jacobian; joint, velocity and distance limits that always hold (or ``feasible=False``); locked joints;
singular configurations without NaN; batching, ``jit`` and ``vmap``; bad input.

A two-link arm in the x-z plane (the collision example of docs/collision.md) and a planar DH chain;
one compiled program per shape of call, shared by the tests (module level).
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from _shapes import planar_capsule_arm

import diffkin as dk
from diffkin.collision import Sphere, World
from diffkin.ik import _qp
from diffkin.ik._linalg import cholesky

URDF = planar_capsule_arm("2", tip=True)
ROBOT = dk.load_robot(URDF)
GEOM = dk.collision.load(URDF, ROBOT)
LOWER, UPPER = np.array([-3.0, -2.0]), np.array([3.0, 2.0])
DT = 0.01
VELOCITY = np.array([1.0, 1.5])
CHAIN = dk.robots.planar([0.4, 0.3, 0.2])


@jax.jit
def _arm_step(q, target, velocity):
    return dk.ik.step(ROBOT, q, {"tip": target}, dt=DT, velocity=velocity)


@jax.jit
def _chain_step(q, target):
    return dk.ik.step(CHAIN, q, target, dt=DT)


def _avoid(world, margin):
    return dk.ik.Avoid(GEOM, world, margin, self_collision=False)


def _world(centre):
    return World(Sphere(centre[None], jnp.asarray([0.05], centre.dtype)))


@jax.jit
def _avoid_step(q, target, centre, velocity, margin):
    return dk.ik.step(ROBOT, q, {"tip": target}, dt=DT, velocity=velocity, avoid=_avoid(_world(centre), margin))


_solve_qp = jax.jit(_qp.solve)


def _enumerated(H, g, lo, hi, G, h):
    """The exact minimiser of a small QP: every active set tried, the one meeting the KKT conditions."""
    n, m = len(g), len(h)
    for box in itertools.product((0, -1, 1), repeat=n):
        for rows in itertools.product((0, 1), repeat=m):
            fixed = [i for i in range(n) if box[i]]
            free = [i for i in range(n) if not box[i]]
            act = [k for k in range(m) if rows[k]]
            v = np.zeros(n)
            v[fixed] = [lo[i] if box[i] < 0 else hi[i] for i in fixed]
            if not np.all(np.isfinite(v)):
                continue
            nf, na = len(free), len(act)
            K = np.zeros((nf + na, nf + na))
            K[:nf, :nf] = H[np.ix_(free, free)]
            A = G[np.ix_(act, free)]
            K[:nf, nf:], K[nf:, :nf] = -A.T, A
            rhs = np.r_[-g[free] - H[np.ix_(free, fixed)] @ v[fixed], h[act] - G[np.ix_(act, fixed)] @ v[fixed]]
            if np.linalg.matrix_rank(K) < nf + na:
                continue
            sol = np.linalg.solve(K, rhs)
            v[free], lam = sol[:nf], sol[nf:]
            grad = H @ v + g - G[act].T @ lam
            kkt = (
                np.all(v >= lo - 1e-12)
                and np.all(v <= hi + 1e-12)
                and np.all(G @ v >= h - 1e-12)
                and np.all(lam >= -1e-12)
                and all(b == 0 or b * grad[i] <= 1e-10 for i, b in enumerate(box))
            )
            if kkt:
                return v
    raise AssertionError("no active set meets the KKT conditions")


def _random_qps(P, n, m, seed):
    """``P`` feasible problems (a point of the box meets every row), some bounds infinite; problem axis last."""
    rng = np.random.default_rng(seed)
    out = []
    for p in range(P):
        J = rng.normal(size=(n + 1, n))
        H = J.T @ J + 1e-3 * np.eye(n)
        g = 3 * rng.normal(size=n)
        lo, hi = -rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n)
        if p % 4 == 0:
            lo[0] = -np.inf
        if p % 5 == 0:
            hi[-1] = np.inf
        G = rng.normal(size=(m, n))
        inside = rng.uniform(np.maximum(lo, -1), np.minimum(hi, 1))
        h = G @ inside - rng.uniform(0, 0.3, m)
        out.append((H, g, lo, hi, G, h))
    return out


def _stacked(problems, dtype=np.float64) -> _qp.QP:
    H, g, lo, hi, G, h = (jnp.asarray(np.moveaxis(np.array(a), 0, -1), dtype) for a in zip(*problems, strict=True))
    return _qp.QP(H, g, lo, hi, G, h, jnp.ones(h.shape, bool))


PROBLEMS = _random_qps(40, 4, 2, seed=0)
SOLVED = _solve_qp(_stacked(PROBLEMS))


@pytest.mark.parametrize("p", range(0, 40, 3))
def test_qp_matches_the_exact_active_set(p):
    H, g, lo, hi, G, h = PROBLEMS[p]
    v = np.asarray(SOLVED.v[:, p])
    np.testing.assert_allclose(v, _enumerated(H, g, lo, hi, G, h), atol=1e-8)
    assert np.all(v >= lo) and np.all(v <= hi)  # the box exactly
    assert np.all(G @ v >= h - 1e-10)


def test_qp_float32():
    # H's condition numbers reach ~1e4 (its damping 1e-3): float32 rounding of the problem alone moves
    # the minimiser by up to ~1e4 * 1.2e-7.
    v = _solve_qp(_stacked(PROBLEMS[:8], np.float32)).v
    assert v.dtype == jnp.float32
    for p, (H, g, lo, hi, G, h) in enumerate(PROBLEMS[:8]):
        np.testing.assert_allclose(np.asarray(v[:, p], np.float64), _enumerated(H, g, lo, hi, G, h), atol=3e-3)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_qp_factor_is_linalg_s_cholesky(dtype):
    # The QP factors column by column (each column materialised): the operations of _linalg.cholesky, so
    # the same values to rounding (XLA may contract a product and a sum differently in the two kernels),
    # and L L^T = M.
    H = _stacked(PROBLEMS[:8], dtype).H
    L, inv_diag = jax.jit(_qp._factor)(H)
    L_ref, inv_ref = jax.jit(lambda M: cholesky([[M[i, j] for j in range(i + 1)] for i in range(M.shape[0])]))(H)
    n, rtol = H.shape[0], 8 * np.finfo(dtype).eps
    for j in range(n):
        np.testing.assert_allclose(inv_diag[j], inv_ref[j], rtol=rtol)
        for i in range(j + 1, n):
            np.testing.assert_allclose(L[i][j], L_ref[i][j], rtol=rtol, atol=rtol)
    full = np.zeros(H.shape, dtype)
    for i in range(n):
        full[i, i] = 1 / np.asarray(inv_diag[i])
        for j in range(i):
            full[i, j] = L[i][j]
    np.testing.assert_allclose(np.einsum("ikp,jkp->ijp", full, full), H, rtol=1e-4 if dtype == np.float32 else 1e-12)


def _random_boxes(P, n, seed):
    """``P`` box problems (no rows), problem axis last, of every kind the active-set method meets: bounds
    inactive, some infinite, every bound active, ``lo == hi``, a minimiser exactly on a bound (zero
    multiplier), and ``H`` that is not an M-matrix."""
    rng = np.random.default_rng(seed)
    out = []
    for p in range(P):
        J = rng.normal(size=(n + 1, n))
        H = J.T @ J + 1e-3 * np.eye(n)
        lo, hi = -rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n)
        g = (0.3 if p % 6 == 0 else 30.0 if p % 6 == 1 else 3.0) * rng.normal(size=n)  # inside; every bound active
        if p % 6 == 2:
            lo[1] = hi[1] = rng.uniform(-0.5, 0.5)  # a variable held by its bounds
        if p % 6 == 3:  # the minimiser: v0 on its bound with a zero multiplier, v1 inside, the rest held at hi
            g = -H @ np.r_[lo[0], 0.5 * (lo[1] + hi[1]), hi[2:]]
            g[2:] -= 1.0
        if p % 4 == 0:
            lo[0] = -np.inf
        if p % 5 == 0:
            hi[-1] = np.inf
        out.append((H, g, lo, hi, np.zeros((0, n)), np.zeros(0)))
    return out


BOXES = _random_boxes(48, 5, seed=3)


def test_box_qp_matches_the_exact_active_set():
    """Without rows the QP is solved by the active-set method: the exact minimiser (to rounding), the box
    exactly, and the interior point's solution to its tolerance."""
    qp = _stacked(BOXES)
    v, iters, settled = jax.jit(lambda qp: _qp._active_set(qp.H, qp.g, qp.lo, qp.hi, max_iters=_qp.BOX_ITERS))(qp)
    assert bool(jnp.all(settled)) and int(jnp.max(iters)) <= _qp.BOX_ITERS
    solved = _solve_qp(qp)  # (compiled apart: the same to rounding)
    np.testing.assert_array_equal(solved.iters, iters)  # the interior point did not run
    np.testing.assert_allclose(solved.v, v, rtol=1e-13, atol=1e-15)
    interior, _ = jax.jit(lambda qp: _qp._interior(*qp, max_iters=_qp.MAX_ITERS))(qp)
    for p, (H, g, lo, hi, G, h) in enumerate(BOXES):
        exact = _enumerated(H, g, lo, hi, G, h)
        np.testing.assert_allclose(v[:, p], exact, atol=1e-12 * (1 + np.abs(exact).max()))
        # (the interior point's accuracy is worse where a bound is active with a zero multiplier)
        np.testing.assert_allclose(interior[:, p], exact, atol=1e-8 if p % 6 != 3 else 1e-6)
        assert np.all(v[:, p] >= lo) and np.all(v[:, p] <= hi)
    assert np.any(np.all((v == qp.lo) | (v == qp.hi), axis=0))  # some with every bound active


def test_box_qp_nearly_singular_and_float32():
    """``H`` of rank 2 in 5 variables plus 1e-10: the KKT conditions hold to the tolerance (the minimiser
    itself is ill-determined along the null space); float32 as the exact minimiser to its rounding."""
    rng = np.random.default_rng(4)
    problems = []
    for _ in range(16):
        J = rng.normal(size=(2, 5))
        H, g = J.T @ J + 1e-10 * np.eye(5), 3 * rng.normal(size=5)
        problems.append((H, g, -np.ones(5), np.ones(5), np.zeros((0, 5)), np.zeros(0)))
    qp = _stacked(problems)
    v, _, settled = jax.jit(lambda qp: _qp._active_set(qp.H, qp.g, qp.lo, qp.hi, max_iters=_qp.BOX_ITERS))(qp)
    assert bool(jnp.all(settled))
    out = np.asarray(_solve_qp(qp).v)
    np.testing.assert_allclose(out, v, rtol=1e-9, atol=1e-12)
    grad = np.einsum("ijp,jp->ip", qp.H, out) + qp.g
    at_lo, at_hi = out == -1.0, out == 1.0
    tol = 1e-9 * (1 + np.abs(qp.g).max())
    assert np.all(np.abs(grad[~at_lo & ~at_hi]) <= tol)
    assert np.all(grad[at_lo] >= -tol) and np.all(grad[at_hi] <= tol)
    assert np.all(np.abs(out) <= 1.0)
    v32 = np.asarray(_solve_qp(_stacked(BOXES[:12], np.float32)).v, np.float64)
    for p, (H, g, lo, hi, G, h) in enumerate(BOXES[:12]):
        np.testing.assert_allclose(v32[:, p], _enumerated(H, g, lo, hi, G, h), atol=3e-3)
        assert np.all(v32[:, p] >= lo.astype(np.float32)) and np.all(v32[:, p] <= hi.astype(np.float32))


def test_box_qp_falls_back_to_the_interior_point(monkeypatch):
    """Problems whose held set has not settled within ``BOX_ITERS`` are the interior point's: with one
    iteration allowed, few settle; the others still get the minimiser (to the interior point's accuracy)."""
    qp = _stacked(BOXES)
    v, first, settled = jax.jit(lambda qp: _qp._active_set(qp.H, qp.g, qp.lo, qp.hi, max_iters=1))(qp)
    assert np.any(settled) and not np.all(settled)
    monkeypatch.setattr(_qp, "BOX_ITERS", 1)
    out = jax.jit(lambda qp: _qp.solve(qp))(qp)  # (a new function: jit caches per function)
    interior, iters = jax.jit(lambda qp: _qp._interior(*qp, max_iters=_qp.MAX_ITERS))(qp)
    np.testing.assert_array_equal(out.iters, np.where(settled, first, iters))  # those not settled: the interior point's
    for p, (H, g, lo, hi, G, h) in enumerate(BOXES):
        np.testing.assert_allclose(out.v[:, p], v[:, p] if settled[p] else interior[:, p], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(out.v[:, p], _enumerated(H, g, lo, hi, G, h), atol=1e-8 if p % 6 != 3 else 1e-6)


@pytest.mark.parametrize("box_iters", [_qp.BOX_ITERS, 1])
def test_box_qp_in_steps(monkeypatch, box_iters):
    """A batch larger than ``2 BOX_STEP`` goes through the active set ``BOX_STEP`` problems at a time (the
    last step overlapping the one before): each problem's ``v`` and iterations are those of one batch, also
    where the interior point takes over (one active-set iteration allowed)."""
    qp = _stacked(BOXES)
    monkeypatch.setattr(_qp, "BOX_ITERS", box_iters)
    whole = jax.jit(lambda qp: _qp.solve(qp))(qp)  # (a new function: jit caches per function)
    monkeypatch.setattr(_qp, "BOX_STEP", 10)  # 48 problems: steps at 0, 10, 20, 30 and 38
    stepped = jax.jit(lambda qp: _qp.solve(qp))(qp)  # (a new function: jit caches per function)
    np.testing.assert_array_equal(stepped.iters, whole.iters)
    np.testing.assert_allclose(stepped.v, whole.v, rtol=1e-13, atol=1e-15)


def test_box_qp_non_finite_problems_stay_finite():
    """A problem with NaN in ``H`` or an infinite ``g`` beside a plain one: every ``v`` finite, the plain
    one solved."""
    H = np.stack([np.eye(3), np.full((3, 3), np.nan), np.eye(3)], axis=-1)
    g = np.stack([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [np.inf, 0.0, 0.0]], axis=-1)
    lo, hi = np.full((3, 3), -0.5), np.full((3, 3), 0.5)
    none = (jnp.zeros((0, 3, 3)), jnp.zeros((0, 3)), jnp.zeros((0, 3), bool))
    out = _solve_qp(_qp.QP(*map(jnp.asarray, (H, g, lo, hi)), *none))
    assert bool(jnp.all(jnp.isfinite(out.v)))
    np.testing.assert_array_equal(out.v[:, 0], [-0.5, 0.0, 0.0])


def test_least_violation_of_contradictory_rows():
    # v0 >= 1 and v0 <= -1 in the box [-5, 5]: the least largest violation is 1 (at v0 = 0).
    H = jnp.eye(2)[:, :, None]
    qp = _qp.QP(
        H,
        jnp.zeros((2, 1)),
        jnp.full((2, 1), -5.0),
        jnp.full((2, 1), 5.0),
        jnp.asarray([[1.0, 0.0], [-1.0, 0.0]])[:, :, None],
        jnp.asarray([[1.0], [1.0]]),
        jnp.ones((2, 1), bool),
    )
    np.testing.assert_allclose(_qp.least_violation(qp), [1.0], atol=1e-6)
    np.testing.assert_allclose(_qp.least_violation(qp._replace(h=-qp.h)), [0.0], atol=1e-9)


def test_step_is_damped_least_squares_off_the_limits():
    q = jnp.asarray([0.3, 0.8])
    point = lambda q: dk.fk(ROBOT, q, "tip")[:3, 3]  # noqa: E731
    target = point(q) + jnp.asarray([0.002, 0.0, -0.001])
    out = _arm_step(q, target, jnp.full(2, jnp.inf))
    J = np.asarray(jax.jacfwd(point)(q))
    e = np.asarray(target - point(q))
    v_ref = np.linalg.solve(J.T @ J + 1e-6 * np.eye(2), J.T @ e / DT)
    np.testing.assert_allclose(out.v, v_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out.q, q + v_ref * DT, atol=1e-12)
    assert bool(out.feasible)
    np.testing.assert_allclose(out.task_err, np.linalg.norm(e - J @ v_ref * DT), atol=1e-12)


def test_limits_always_hold():
    rng = np.random.default_rng(1)
    q = rng.uniform(LOWER, UPPER, (64, 2))
    q[:8] = np.where(rng.uniform(size=(8, 2)) < 0.5, LOWER, UPPER)  # at a limit
    q[8:16] = q[8:16] + np.sign(q[8:16]) * (UPPER - np.abs(q[8:16])) * 0.999  # just inside
    targets = rng.uniform(-1.5, 1.5, (64, 3))  # mostly far or unreachable: the limits bind
    out = _arm_step(jnp.asarray(q), jnp.asarray(targets), jnp.asarray(VELOCITY))
    assert bool(jnp.all(out.feasible))
    assert np.all(np.asarray(out.q) >= LOWER) and np.all(np.asarray(out.q) <= UPPER)
    assert np.all(np.abs(np.asarray(out.v)) <= VELOCITY)
    assert np.any(np.isclose(np.abs(np.asarray(out.v)), VELOCITY))  # some velocity limits bind


@jax.jit
def _model_step(robot, q, target):
    return dk.ik.step(robot, q, {"tip": target}, dt=DT)


def test_the_model_s_velocity_limits_are_the_default():
    """Without ``velocity``: the model's (a file's), concrete or traced; a URDF without them: none."""
    rng = np.random.default_rng(4)
    q, targets = jnp.asarray(rng.uniform(LOWER, UPPER, (64, 2))), jnp.asarray(rng.uniform(-1.5, 1.5, (64, 3)))
    limited = ROBOT.replace(velocity=jnp.asarray(VELOCITY))
    given = _arm_step(q, targets, jnp.asarray(VELOCITY))
    assert np.any(np.isclose(np.abs(np.asarray(given.v)), VELOCITY))  # they bind
    for out in (dk.ik.step(limited, q, {"tip": targets}, dt=DT), _model_step(limited, q, targets)):
        np.testing.assert_allclose(out.v, given.v, rtol=1e-12, atol=1e-12)
    assert np.all(np.isposinf(np.asarray(ROBOT.velocity)))  # the file gives none
    np.testing.assert_allclose(
        _model_step(ROBOT, q, targets).v, _arm_step(q, targets, jnp.full(2, jnp.inf)).v, rtol=1e-12, atol=1e-12
    )


def test_outside_the_limits():
    target = jnp.asarray([0.3, 0.0, 0.5])
    far, near = 2.0 + 0.1, 2.0 + 0.5 * VELOCITY[1] * DT  # j2 beyond its upper limit
    out = _arm_step(jnp.asarray([[0.0, far], [0.0, near]]), target, jnp.asarray(VELOCITY))
    assert not bool(out.feasible[0]) and bool(out.feasible[1])
    assert float(out.v[0, 1]) == -VELOCITY[1]  # back towards the range at its velocity limit
    assert float(out.q[1, 1]) <= 2.0  # within one step: back inside, exactly


def test_every_joint_outside_the_limits():
    """Both joints further outside than a step can bring them back (a box with no point): every joint moves
    back at its velocity limit, ``feasible=False``, nothing NaN; one joint so and the other free: the other
    still tracks the target within its box."""
    target = jnp.asarray([0.3, 0.0, 0.5])
    q = jnp.asarray([[3.1, -2.1], [3.1, 0.5]])
    out = _arm_step(q, target, jnp.asarray(VELOCITY))
    assert not bool(jnp.any(out.feasible))
    np.testing.assert_array_equal(out.v[0], [-VELOCITY[0], VELOCITY[1]])
    assert float(out.v[1, 0]) == -VELOCITY[0] and abs(float(out.v[1, 1])) <= VELOCITY[1]
    assert float(out.v[1, 1]) != 0.0
    assert bool(jnp.all(jnp.isfinite(out.v))) and bool(jnp.all(jnp.isfinite(out.q)))


def test_locked_joint_does_not_move():
    q = jnp.asarray([0.3, 0.8])
    target = jnp.asarray([0.5, 0.0, 0.4])
    out = dk.ik.step(ROBOT, q, {"tip": target}, dt=DT, locked=["j2"])
    assert float(out.v[1]) == 0.0 and float(out.q[1]) == 0.8
    assert float(out.v[0]) != 0.0


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_singular_configurations_are_finite(dtype):
    # Stretched out (singular), target beyond reach along the arm and at the base: no NaN.
    q = jnp.zeros((3, 3), dtype)
    targets = jnp.asarray([[2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.9, 1e-9, 0.0]], dtype)
    out = _chain_step(q, targets)
    assert out.v.dtype == dtype
    assert bool(jnp.all(jnp.isfinite(out.v))) and bool(jnp.all(jnp.isfinite(out.task_err)))
    assert bool(jnp.all(out.feasible))


def test_distance_rows_hold():
    # A sphere 4 cm from the lower link, the tip pulled through it: the linearised distance holds.
    q = jnp.asarray([[0.0, 0.6], [0.0, 0.6]])
    centre = jnp.asarray([0.277, 0.0, 0.724])
    target = jnp.asarray([0.8, 0.0, 0.5])
    velocity = jnp.asarray([[5.0, 5.0], [0.0, 0.0]])  # the second cannot move
    out = _avoid_step(q, target, centre, velocity, 0.02)
    avoid = _avoid(_world(centre), 0.02)
    d = lambda q: avoid.clearance(ROBOT, q)  # noqa: E731
    d0, grad = float(d(q[0])), np.asarray(jax.grad(d)(q[0]))
    assert 0.03 < d0 < 0.05
    linear = d0 + DT * float(grad @ out.v[0])
    assert linear >= 0.02 - 1e-9
    free = _arm_step(q[0], target, jnp.asarray([5.0, 5.0]))  # without the obstacle: nearer than the margin
    assert d0 + DT * float(grad @ free.v) < 0.02
    assert bool(out.feasible[0]) and bool(out.feasible[1])  # the second: clear, and standing still keeps it
    # A margin above the distance that the velocity limits cannot restore in one step: infeasible,
    # the box still exact.
    stuck = _avoid_step(q, target, centre, jnp.full((2, 2), 0.01), d0 + 0.01)
    assert not bool(jnp.any(stuck.feasible))
    assert bool(jnp.all(jnp.abs(stuck.v) <= 0.01)) and bool(jnp.all(jnp.isfinite(stuck.v)))


def test_batches_jit_and_vmap():
    rng = np.random.default_rng(2)
    q = jnp.asarray(rng.uniform(-1, 1, (2, 3, 2)))
    targets = jnp.asarray(rng.uniform(-0.6, 0.6, (2, 3, 3)))
    vel = jnp.asarray(VELOCITY)
    batched = _arm_step(q, targets, vel)
    assert batched.v.shape == (2, 3, 2) and batched.feasible.shape == (2, 3) and batched.task_err.shape == (2, 3)
    mapped = jax.vmap(jax.vmap(_arm_step, (0, 0, None)), (0, 0, None))(q, targets, vel)
    one = _arm_step(q[1, 2], targets[1, 2], vel)
    np.testing.assert_allclose(mapped.v, batched.v, atol=1e-12)
    np.testing.assert_allclose(one.v, batched.v[1, 2], atol=1e-12)
    shared = _arm_step(q, targets[0, 0], vel)  # one target for every configuration
    assert shared.v.shape == (2, 3, 2)
    np.testing.assert_allclose(shared.v[0, 0], batched.v[0, 0], atol=1e-12)


def test_solve_base_moves_the_root_by_a_body_twist():
    """A floating robot with ``solve_base``: ``v`` is the root's body twist then the joints' velocities,
    the damped least-squares step of ``dk.jacobian(..., include_base=True)`` off the limits; ``base`` is
    the root moved by ``exp`` of that twist over ``dt``."""
    floating = dk.load_robot(URDF, floating=True)
    q = jnp.asarray([0.3, 0.8])
    c, s = np.cos(0.4), np.sin(0.4)
    T = jnp.asarray([[c, -s, 0.0, 0.1], [s, c, 0.0, -0.2], [0.0, 0.0, 1.0, 0.3], [0.0, 0.0, 0.0, 1.0]])
    target = dk.fk(floating, q, "tip", base=T)[:3, 3] + jnp.asarray([0.002, 0.001, -0.001])
    out = dk.ik.step(floating, q, {"tip": target}, dt=DT, base=T, solve_base=True, damping=1e-3)
    J = np.asarray(dk.jacobian(floating, q, "tip", base=T, include_base=True))[:3]  # (3, 6 + 2)
    e = np.asarray(target - dk.fk(floating, q, "tip", base=T)[:3, 3])
    v_ref = np.linalg.solve(J.T @ J + 1e-3 * np.eye(8), J.T @ e / DT)
    assert out.v.shape == (8,) and out.base.shape == (4, 4) and bool(out.feasible)
    np.testing.assert_allclose(out.v, v_ref, atol=1e-9 * (1 + np.abs(v_ref).max()))  # the QP's accuracy
    np.testing.assert_allclose(out.q, q + out.v[6:] * DT, atol=1e-15)
    twist = np.zeros((4, 4))
    twist[:3, :3], twist[:3, 3] = np.asarray(dk.se3.skew(out.v[3:6] * DT)), out.v[:3] * DT
    np.testing.assert_allclose(out.base, np.asarray(T) @ scipy.linalg.expm(twist), atol=1e-12)
    assert dk.ik.step(ROBOT, q, {"tip": target}, dt=DT).base is None


@pytest.mark.parametrize(
    ("kwargs", "error", "field"),
    [
        ({"q": jnp.zeros(3)}, ValueError, "q:"),
        ({"dt": 0.0}, ValueError, "dt:"),
        ({"dt": float("nan")}, ValueError, "dt:"),
        ({"gain": -1.0}, ValueError, "gain:"),
        ({"damping": 0.0}, ValueError, "damping:"),
        ({"velocity": jnp.asarray([1.0, -1.0])}, ValueError, "velocity:"),
        ({"velocity": jnp.ones(3)}, ValueError, "velocity:"),
        ({"locked": {"j1": 0.0}}, TypeError, "locked:"),
        ({"locked": ["nope"]}, ValueError, "locked:"),
        ({"weights": {"rest": -1.0}}, ValueError, "weights['rest']:"),
        ({"targets": {"tip": jnp.zeros((4, 4, 4))}}, ValueError, "target"),
        ({"model": "arm"}, TypeError, "model:"),
        ({"solve_base": 1}, TypeError, "solve_base:"),
        ({"solve_base": True}, ValueError, "solve_base:"),  # a fixed root
        ({"model": CHAIN, "q": jnp.zeros(3), "targets": jnp.zeros(3), "solve_base": True}, ValueError, "solve_base:"),
    ],
)
def test_bad_input(kwargs, error, field):
    args = {"model": ROBOT, "q": jnp.zeros(2), "targets": {"tip": jnp.zeros(3)}, "dt": DT} | kwargs
    with pytest.raises(error, match=field.replace("[", r"\[")):
        dk.ik.step(args.pop("model"), args.pop("q"), args.pop("targets"), **args)
