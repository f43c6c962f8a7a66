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

import jax
import jax.numpy as jnp
import numpy as np

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

    def normal(self, X: jax.Array, W: jax.Array, live: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """``(cost (C,), g (C, n dof), H (C, n dof, n dof), blocked (C,))``: ``|r|^2``, ``J^T r`` and
        ``J^T J`` at ``X`` ``(C, n, dof)``, ``W`` ``(Q, N)`` the basis weights of the clearance samples;
        ``blocked``: a clearance row is not zero (always, without ``avoid``: only smoothness to descend).
        The clearance rows only of the curves ``live`` ``(C,)`` (the others' results are not read)."""
        C, n, dof = X.shape
        P = self.control(X)
        D_host, D_free_host = _smoothing(P.shape[1], n)
        D, D_free = jnp.asarray(D_host, X.dtype), jnp.asarray(D_free_host, X.dtype)
        rs = jnp.einsum("rk,ckj->crj", D, P)  # (C, R, dof)
        cost = jnp.sum(rs**2, axis=(1, 2))
        g = jnp.einsum("rk,crj->ckj", D_free, rs).reshape(C, n * dof)
        H = jnp.broadcast_to(jnp.kron(D_free.T @ D_free, jnp.eye(dof, dtype=X.dtype)), (C, n * dof, n * dof))
        blocked = jnp.full((C,), self.avoid is None)
        if self.avoid is not None:
            q = jnp.einsum("qk,ckj->cqj", W, P)  # (C, Q, dof)
            r, J = self._clearance_rows(q, live)  # (m, C, Q), (m, dof, C, Q)
            Wf = W[:, _spline.ENDS : _spline.ENDS + n]  # (Q, n)
            clearance = jnp.sum(r**2, axis=(0, 2))
            cost, blocked = cost + clearance, clearance > 0
            Jr = jnp.einsum("mjcq,mcq->cqj", J, r)  # (C, Q, dof)
            g = g + jnp.einsum("qk,cqj->ckj", Wf, Jr).reshape(C, n * dof)
            G = jnp.einsum("mjcq,mlcq->cqjl", J, J)  # (C, Q, dof, dof)
            H = H + jnp.einsum("qk,qi,cqjl->ckjil", Wf, Wf, G).reshape(C, n * dof, n * dof)
        return cost, g, H, blocked

    def samples(self, N: int, dtype) -> jax.Array:
        """``(Q, N)`` the basis weights of the clearance samples: :data:`SAMPLES` per segment and the end."""
        segs = _spline.segments(N)
        u = np.concatenate([np.arange(segs * SAMPLES) / SAMPLES, [segs]])
        return _spline.basis(jnp.asarray(u, dtype), N).astype(dtype)

    def descend(self, X: jax.Array, iters: int) -> tuple[jax.Array, jax.Array]:
        """``(X, cost)``: ``X`` ``(C, n, dof)`` after at most ``iters`` Levenberg-Marquardt iterations, and
        its cost ``(C,)``. A curve stops once it has converged (its last step taken lowered its cost by
        less than :data:`CONVERGED` of it, or its damping is at its largest), and all of a problem's once
        one of them is clear of every row, since the last small gains and the smoothness rows alone change
        the curves only slightly and each iteration costs the clearance rows' distances; a curve stopped is
        left as it is (a problem's result does not depend on the others in its batch) and measures no
        distance exactly (a batch's iterations cost its curves still going)."""
        C, n, dof = X.shape
        X = self.project(X)
        W = self.samples(n + 2 * _spline.ENDS, X.dtype)
        eye = jnp.eye(n * dof, dtype=X.dtype)

        def going(blocked, mu, slow) -> jax.Array:
            """``(C,)`` whether each curve goes on: it has a clearance row and has neither stalled nor
            converged, and no curve of its problem is clear of every row."""
            live = blocked & (mu < _MU_MAX) & ~slow
            if self.avoid is not None:  # a problem with a curve clear of every row is done
                live = live & jnp.repeat(jnp.all(blocked.reshape(-1, self.k), axis=1), self.k)
            return live

        def step(state):
            it, X, cost, g, H, blocked, mu, slow = state
            live = going(blocked, mu, slow) | (it == 0)
            lam = jnp.where(jnp.isfinite(cost), mu * cost, 0.0) + 1e-10
            # Cholesky: the damped normal matrix is positive definite (an LU solve permutes its pivots in a loop)
            factor = jax.scipy.linalg.cho_factor(H + lam[:, None, None] * eye, lower=True)
            dx = jax.scipy.linalg.cho_solve(factor, -g[..., None])[..., 0]
            X_try = self.project(X + dx.reshape(C, n, dof))
            cost_try, g_try, H_try, blocked_try = self.normal(X_try, W, live)
            take = live & jnp.isfinite(cost_try) & (cost_try < cost)
            pick = lambda new, old: jnp.where(take.reshape((C,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
            raised = jnp.where(take, jnp.maximum(mu * _MU_DOWN, _MU_MIN), jnp.minimum(mu * _MU_UP, _MU_MAX))
            new = (pick(X_try, X), pick(cost_try, cost), pick(g_try, g), pick(H_try, H), pick(blocked_try, blocked))
            slow = jnp.where(take, cost - cost_try < CONVERGED * cost_try, slow)
            return (it + 1, *new, jnp.where(live, raised, mu), slow)

        def more(state):
            it, blocked, mu, slow = state[0], state[5], state[6], state[7]
            return (it == 0) | ((it <= iters) & jnp.any(going(blocked, mu, slow)))

        # the first iteration evaluates X itself (a zero step from an infinite cost): the residual is
        # compiled once, inside the loop
        cost = jnp.full((C,), jnp.inf, X.dtype)
        g, H = jnp.zeros((C, n * dof), X.dtype), jnp.broadcast_to(eye, (C, n * dof, n * dof))
        mu = jnp.full((C,), _MU_INIT, X.dtype)
        state = (jnp.int32(0), X, cost, g, H, jnp.ones((C,), bool), mu, jnp.zeros((C,), bool))
        out = jax.lax.while_loop(more, step, state)
        return out[1], out[2]
