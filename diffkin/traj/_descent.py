"""Levenberg-Marquardt on a curve's free control points: smoothness rows and clearance rows.

The state of a curve is its free control points ``X (n, dof)`` (:mod:`diffkin.traj._spline`). Its
residual stacks

- smoothness: the control polygon's first differences (weight :data:`W_LENGTH`: short, evenly spread)
  and second differences (weight :data:`W_BEND`: little acceleration), linear in ``X``;
- clearance: at :data:`SAMPLES` points per segment, the rows of collision-aware IK's clearance term
  (:class:`diffkin.ik._terms.avoid.AvoidTerm`: one per self pair and one per robot shape against the
  world, zero beyond ``margin + band``, with the motion Jacobians of the distances), pushed to the
  control points through the curve's basis weights (``dq(u)/dX_k = basis_k(u)``).

The margin the rows aim for is raised by :data:`EXTRA` (or a given ``extra``) so that the certificate
(:mod:`diffkin.traj._certify`), which subtracts the motion between its samples, holds. Steps solve
the ``n dof`` normal equations with error-proportional damping (:mod:`diffkin.ik._lm`'s rule); a
step is taken only if it lowers the cost; joints stay within their limits (clipped control points:
the curve lies in their convex hull) and locked joints at their values.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.ik.interface import BAND
from diffkin.traj import _rows, _spline

W_LENGTH = 0.05  # per rad of a control-polygon step
W_BEND = 0.2  # per rad of a second difference
SAMPLES = 8  # clearance samples per segment (fewer let a curve pass through a thin board between two)
EXTRA = 0.02  # metres the clearance rows aim beyond the margin
W_CLEAR = 30.0  # per metre of a clearance row (rows in metres against smoothness in radians)
#: a curve whose last step lowered its cost by less than this share of it has converged
CONVERGED = 0.02
_MU_INIT, _MU_MIN, _MU_MAX, _MU_UP, _MU_DOWN = 1e-2, 1e-6, 1e6, 8.0, 0.25


def _smoothing(N: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``D (R, N)`` the weighted difference rows of the control polygon and ``D[:, free]`` ``(R, n)``."""
    D1 = np.diff(np.eye(N), axis=0)
    D2 = np.diff(np.eye(N), n=2, axis=0)
    D = np.concatenate([W_LENGTH * D1, W_BEND * D2])
    return D, D[:, _spline.ENDS : _spline.ENDS + n]


class Descent(NamedTuple):
    """The state of the curves' descent (:meth:`Curves.descend`), per curve of ``C``."""

    it: jax.Array  # the iterations run (0: not yet evaluated)
    X: jax.Array  # (C, n, dof) free control points
    cost: jax.Array  # (C,) |r|^2 at X
    g: jax.Array  # (C, n dof) J^T r
    H: jax.Array  # (C, n dof, n dof) J^T J
    blocked: jax.Array  # (C,) a clearance row is not zero
    mu: jax.Array  # (C,) damping
    slow: jax.Array  # (C,) converged
    low: jax.Array  # (C,) metres: a lower bound of the smallest distance at the clearance samples (of searched)


class Curves:
    """The curves of a flat batch: ``C`` curves, ``B`` problems (``C = B k``, curves of one problem
    consecutive), their ends, limits, locked joints and what keeps them clear."""

    def __init__(self, model, q_start, q_goal, lower, upper, locked, locked_q, avoid, base, k: int, extra=EXTRA):
        self.model, self.q_start, self.q_goal = model, q_start, q_goal  # (C, dof)
        self.lower, self.upper = lower, upper  # (dof,)
        self.locked, self.locked_q = locked, locked_q  # static mask, (C, dof)
        self.avoid, self.base, self.k = avoid, base, k  # avoid: flat (B, ...) world or shared
        self.extra = extra  # metres the clearance rows aim beyond the margin (a scalar, traced or not)

    def project(self, X: jax.Array) -> jax.Array:
        X = jnp.clip(X, self.lower, self.upper)
        if any(self.locked):
            X = jnp.where(jnp.asarray(self.locked), self.locked_q[:, None, :], X)
        return X

    def cap(self) -> jax.Array:
        """The clearance the clearance rows aim for: the margin plus ``extra`` (:data:`EXTRA` unless given)."""
        return self.avoid.margin + self.extra

    def control(self, X: jax.Array) -> jax.Array:
        return _spline.control_points(self.q_start, X, self.q_goal)

    def _clearance_rows(self, q: jax.Array, live: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``r (m, C, Q)`` and ``dr/dq`` ``(m, dof, C, Q)`` at configurations ``q`` ``(C, Q, dof)``, weighted;
        zero for the curves not ``live`` ``(C,)`` (their margin is ``-inf``: no pair of theirs is near, so
        none is measured exactly)."""
        C, Q, _ = q.shape
        margin = jnp.broadcast_to(jnp.where(live[:, None], self.cap(), -jnp.inf), (C, Q)).reshape(C * Q)
        r, J = _rows.rows(self.model, self.avoid, self.locked, self.base, self.k, q, margin)
        return W_CLEAR * r, W_CLEAR * J

    def normal(self, X: jax.Array, W: jax.Array, live: jax.Array) -> tuple[jax.Array, ...]:
        """``(cost (C,), g (C, n dof), H (C, n dof, n dof), blocked (C,), low (C,))``: ``|r|^2``, ``J^T r`` and
        ``J^T J`` at ``X`` ``(C, n, dof)``, ``W`` ``(Q, N)`` the basis weights of the clearance samples;
        ``blocked``: a clearance row is not zero (always, without ``avoid``: only smoothness to descend);
        ``low``: a lower bound of the smallest distance at the samples, from the largest row (a row vanishes
        at ``cap() + BAND``; a shape's row against the world is at least each obstacle's), ``inf`` without
        ``avoid``.
        The clearance rows only of the curves ``live`` ``(C,)`` (the others' results are not read)."""
        C, n, dof = X.shape
        P = self.control(X)
        D_host, D_free_host = _smoothing(P.shape[1], n)
        D, D_free = jnp.asarray(D_host, X.dtype), jnp.asarray(D_free_host, X.dtype)
        rs = jnp.einsum("rk,ckj->crj", D, P)  # (C, R, dof)
        cost = jnp.sum(rs**2, axis=(1, 2))
        g = jnp.einsum("rk,crj->ckj", D_free, rs).reshape(C, n * dof)
        H = jnp.broadcast_to(jnp.kron(D_free.T @ D_free, jnp.eye(dof, dtype=X.dtype)), (C, n * dof, n * dof))
        blocked, low = jnp.full((C,), self.avoid is None), jnp.full((C,), jnp.inf, X.dtype)
        if self.avoid is not None:
            q = jnp.einsum("qk,ckj->cqj", W, P)  # (C, Q, dof)
            r, J = self._clearance_rows(q, live)  # (m, C, Q), (m, dof, C, Q)
            Wf = W[:, _spline.ENDS : _spline.ENDS + n]  # (Q, n)
            clearance = jnp.sum(r**2, axis=(0, 2))
            cost, blocked = cost + clearance, clearance > 0
            low = self.cap() + BAND - jnp.max(r, axis=(0, 2)) / W_CLEAR
            Jr = jnp.einsum("mjcq,mcq->cqj", J, r)  # (C, Q, dof)
            g = g + jnp.einsum("qk,cqj->ckj", Wf, Jr).reshape(C, n * dof)
            G = jnp.einsum("mjcq,mlcq->cqjl", J, J)  # (C, Q, dof, dof)
            H = H + jnp.einsum("qk,qi,cqjl->ckjil", Wf, Wf, G).reshape(C, n * dof, n * dof)
        return cost, g, H, blocked, low

    def samples(self, N: int, dtype) -> jax.Array:
        """``(Q, N)`` the basis weights of the clearance samples: :data:`SAMPLES` per segment and the end."""
        segs = _spline.segments(N)
        u = np.concatenate([np.arange(segs * SAMPLES) / SAMPLES, [segs]])
        return _spline.basis(jnp.asarray(u, dtype), N).astype(dtype)

    def start(self, X: jax.Array) -> Descent:
        """The state of a descent from the free control points ``X`` ``(C, n, dof)``, before its first iteration
        (which evaluates ``X`` itself: a zero step from an infinite cost)."""
        C, n, dof = X.shape
        eye = jnp.broadcast_to(jnp.eye(n * dof, dtype=X.dtype), (C, n * dof, n * dof))
        real = lambda value: jnp.full((C,), value, X.dtype)  # noqa: E731
        no = jnp.zeros((C,), bool)
        return Descent(jnp.int32(0), self.project(X), real(jnp.inf), jnp.zeros((C, n * dof), X.dtype), eye,
                       ~no, real(_MU_INIT), no, real(-jnp.inf))  # fmt: skip

    def going(self, state: Descent, stopped=None) -> jax.Array:
        """``(C,)`` whether each curve goes on: it has a clearance row and has neither stalled nor converged, no
        curve of its problem is clear of every row, and its problem is not ``stopped`` ``(C,)`` (where given)."""
        live = state.blocked & (state.mu < _MU_MAX) & ~state.slow
        if self.avoid is not None:  # a problem with a curve clear of every row is done
            live = live & jnp.repeat(jnp.all(state.blocked.reshape(-1, self.k), axis=1), self.k)
        return live if stopped is None else live & ~stopped

    def descend(self, state: Descent, iters, stopped=None) -> Descent:
        """``state`` after its Levenberg-Marquardt iterations up to the ``iters``-th (an int, may be traced:
        a descent goes on from where it was, in as many calls as it likes). A curve stops once it has
        converged (its last step taken lowered its cost by less than :data:`CONVERGED` of it, or its
        damping is at its largest), and all of a problem's once one of them is clear of every row or
        where ``stopped`` ``(C,)``: the last small gains and the smoothness rows alone change the curves
        only slightly and each iteration costs the clearance rows' distances; a curve stopped is left as
        it is (a problem's result does not depend on the others in its batch) and measures no distance
        exactly (a batch's iterations cost its curves still going)."""
        C, n, dof = state.X.shape
        W = self.samples(n + 2 * _spline.ENDS, state.X.dtype)
        eye = jnp.eye(n * dof, dtype=state.X.dtype)

        def step(state: Descent) -> Descent:
            live = self.going(state, stopped) | (state.it == 0)
            mu, cost = state.mu, state.cost
            lam = jnp.where(jnp.isfinite(cost), mu * cost, 0.0) + 1e-10
            # Cholesky: the damped normal matrix is positive definite (an LU solve permutes its pivots in a loop)
            factor = jax.scipy.linalg.cho_factor(state.H + lam[:, None, None] * eye, lower=True)
            dx = jax.scipy.linalg.cho_solve(factor, -state.g[..., None])[..., 0]
            X_try = self.project(state.X + dx.reshape(C, n, dof))
            cost_try, g_try, H_try, blocked_try, low_try = self.normal(X_try, W, live)
            take = live & jnp.isfinite(cost_try) & (cost_try < cost)
            pick = lambda new, old: jnp.where(take.reshape((C,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
            raised = jnp.where(take, jnp.maximum(mu * _MU_DOWN, _MU_MIN), jnp.minimum(mu * _MU_UP, _MU_MAX))
            slow = jnp.where(take, cost - cost_try < CONVERGED * cost_try, state.slow)
            return Descent(
                state.it + 1,
                pick(X_try, state.X),
                pick(cost_try, cost),
                pick(g_try, state.g),
                pick(H_try, state.H),
                pick(blocked_try, state.blocked),
                jnp.where(live, raised, mu),
                slow,
                pick(low_try, state.low),
            )

        def more(state: Descent) -> jax.Array:
            return (state.it == 0) | ((state.it <= iters) & jnp.any(self.going(state, stopped)))

        return jax.lax.while_loop(more, step, state)
