"""A small dense convex QP with box bounds and a few general inequality rows, batched, in JAX.

    minimise  v^T H v / 2 + g^T v   subject to   lo <= v <= hi,   G v >= h (rows that are on)

``H`` symmetric positive definite (``dk.ik.step`` adds its damping), ``n`` up to a few dozen
variables and ``m`` up to a few dozen rows. Bounds may be infinite (that side is absent) and a row
may be off; every problem of the batch is solved at once, problem axis last.

Method, without general rows (``m = 0``, a box): an active-set method (:func:`_active_set`). Each
iteration holds a set of variables at their bounds and solves the equality-constrained problem of the
others exactly (one ``n x n`` Cholesky factorisation); the first few change the set by the KKT
conditions all at once (a primal-dual active-set step), the later ones one bound at a time (a primal
active-set step, which cannot cycle). A problem is solved when its set no longer changes: its ``v`` is
then the exact minimiser to rounding, within the box. Problems still unsettled after :data:`BOX_ITERS`
iterations are solved by the interior point below instead; it runs only when there are some. Batches of
more than ``2 BOX_STEP`` problems go through both :data:`BOX_STEP` problems at a time.

With general rows: a primal-dual interior-point method with Mehrotra's predictor-corrector (Nocedal &
Wright, *Numerical Optimization*, 2nd ed., section 16.6), started from the unconstrained minimiser
and one affine step (their (16.60) heuristic), stopped when every problem of the batch has its
residuals and complementarity below ``TOL_EPS`` machine epsilons relative to the problem's scale, or
after ``MAX_ITERS`` iterations. Each iteration factors the reduced ``n x n`` system
``H + A^T (Z/S) A`` once and solves it twice. In both methods every operation is elementwise along
the batch (the factorisation unrolled entry by entry: :func:`_factor`), so XLA vectorises each over
the problems. The interior point's ``v`` is then clipped into ``[lo, hi]`` (a move of the order of
the stopping tolerance).

Tolerance: the active-set method's solution is exact to rounding (its multipliers' signs to
``TOL_EPS`` machine epsilons of the problem's scale). The interior point's, on non-degenerate problems
(strict complementarity), matches an exact active-set enumeration to ~1e-10 relative in float64
(``tests/unit/test_step.py`` checks 1e-8 absolute on random problems) and ~1e-5 in float32. The bounds
hold exactly; the general rows to the same tolerance. The rows must be feasible together with the box
(``dk.ik.step`` makes them so: :func:`least_violation`); the box must have ``lo <= hi``.
"""

from __future__ import annotations

import functools
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from diffkin._xla import in_steps, materialize, summed_products
from diffkin.ik._linalg import back_substitute, cholesky, forward_substitute

#: Iterations at most (float64 converges in 10-20 on the problems of ``dk.ik.step``).
MAX_ITERS = 40
#: Stopping tolerance, in machine epsilons relative to the problem's scale.
TOL_EPS = 64.0
#: Active-set iterations at most on a box (the Panda's steps of ``experiments/bench_step.py`` settle well
#: within it; problems still unsettled go to the interior point).
BOX_ITERS = 24
#: Problems per step of the active-set method on larger batches (:func:`diffkin._xla.in_steps`): a step's
#: arrays stay in cache and its kernels on one thread, and each step iterates until its own slowest problem
#: settles. The Panda's 4,096 steps of ``experiments/bench_step.py``: QP 2-3x faster than in one batch.
BOX_STEP = 256
#: The active-set method's first iterations that jump (change every variable's status at once).
BOX_JUMPS = 4
_STEP_TO_BOUNDARY = 0.995


class QP(NamedTuple):
    """A batch of problems, problem axis last.

    Attributes:
        H: ``(n, n, P)`` symmetric positive definite.
        g: ``(n, P)``.
        lo, hi: ``(n, P)`` bounds (``-inf``/``inf``: none), ``lo <= hi``.
        G: ``(m, n, P)`` general rows ``G v >= h``; ``h``: ``(m, P)``; ``on``: ``(m, P)`` bool,
            which rows count (``m`` may be 0).
    """

    H: jax.Array
    g: jax.Array
    lo: jax.Array
    hi: jax.Array
    G: jax.Array
    h: jax.Array
    on: jax.Array


class Solution(NamedTuple):
    """``v`` ``(n, P)``, ``iters`` ``(P,)`` (int32, per problem) and ``violation`` ``(P,)``: the largest
    violation of an on row, ``max(h - G v)`` (0 without rows or when they hold)."""

    v: jax.Array
    iters: jax.Array
    violation: jax.Array


def solve(qp: QP, max_iters: int = MAX_ITERS) -> Solution:
    """The minimiser of each problem of ``qp`` (see the module docstring for the methods and their
    tolerance): on a box (``m = 0``) the active-set method, the interior point (at most ``max_iters``
    iterations) for the problems it leaves; with rows the interior point."""
    H, g, lo, hi, G, h, on = qp
    if G.shape[0]:
        v, iters = _interior(*qp, max_iters=max_iters)
    else:
        box = functools.partial(_box, max_iters=max_iters)
        if g.shape[-1] > 2 * BOX_STEP:
            v, iters = in_steps(box, (H, g, lo, hi), BOX_STEP, axis=-1, in_axis=-1)
        else:
            v, iters = box(H, g, lo, hi)
    v = jnp.where(jnp.isfinite(v), v, jnp.clip(0.0, lo, hi))  # (never: a guard for infeasible rows)
    violation = jnp.max(jnp.where(on, h - jnp.sum(G * v[None], axis=1), 0.0), axis=0, initial=0.0)
    return Solution(v, iters, violation)


def _box(H, g, lo, hi, *, max_iters: int) -> tuple[jax.Array, jax.Array]:
    """``v`` ``(n, P)`` and the iterations ``(P,)`` of box QPs (``H`` ``(n, n, P)``, ``g``, ``lo``, ``hi``
    ``(n, P)``): the active set, the interior point where it has not settled."""
    v, iters, settled = _active_set(H, g, lo, hi, max_iters=BOX_ITERS)
    G, h = jnp.zeros((0,) + g.shape, g.dtype), jnp.zeros((0,) + g.shape[1:], g.dtype)  # no rows
    interior = lambda: _interior(H, g, lo, hi, G, h, jnp.zeros(h.shape, bool), max_iters=max_iters)  # noqa: E731
    return _unless(settled, (v, iters), interior)


def _unless(settled: jax.Array, value: tuple, fallback) -> tuple:
    """``value`` (arrays ``(..., P)``), or ``fallback()``'s where not ``settled`` ``(P,)``, the fallback
    computed only when some problem needs it (a ``lax.cond``: as a loop of at most one pass, XLA hoisted
    the fallback's loop-invariant part out of the loop, and it always ran; under ``vmap`` a ``cond``
    computes both)."""
    fell_back = lambda: tuple(jnp.where(settled, a, b) for a, b in zip(value, fallback(), strict=True))  # noqa: E731
    return jax.lax.cond(jnp.all(settled), lambda: value, fell_back)


def _tolerance(g: jax.Array, b: jax.Array) -> jax.Array:
    """``(P,)`` the stopping tolerance of problems with linear terms ``g`` ``(n, P)`` and finite bounds or
    right-hand sides ``b`` ``(k, P)`` (0 where absent): :data:`TOL_EPS` epsilons of their scale."""
    scale = 1.0 + jnp.max(jnp.abs(g), axis=0) + jnp.max(jnp.abs(b), axis=0, initial=0.0)
    return TOL_EPS * jnp.finfo(g.dtype).eps * scale


def _active_set(H, g, lo, hi, *, max_iters: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The active-set method on the box (module docstring), every problem at once: ``H`` ``(n, n, P)``,
    ``g``, ``lo``, ``hi`` ``(n, P)``. Returns ``v`` ``(n, P)``, the iterations ``(P,)`` (the unconstrained
    solve counted) and whether each problem settled ``(P,)`` (where not, ``v`` is the last iterate: within
    the box, not the minimiser).

    The start is the unconstrained minimiser clipped into the box, holding the clipped variables. Each
    iteration solves, for the held set ``A`` (at ``lo`` or ``hi``: values ``w``), the system whose rows and
    columns of ``A`` are those of the identity: ``v_A = w_A`` and ``H_FF v_F = -g_F - H_FA w_A``; the
    multipliers there are ``grad = H v + g`` on ``A`` (``>= 0`` at a lower bound, ``<= 0`` at an upper).

    - The first :data:`BOX_JUMPS` iterations jump (Hintermüller, Ito & Kunisch, *SIAM J. Optim.* 13(3),
      2002): every free variable beyond a bound is held, every held one with a wrong-signed multiplier let
      go, all at once. Usually few sets are tried, but the sets may cycle.
    - Then they move (Nocedal & Wright, *Numerical Optimization*, 2nd ed., algorithm 16.3): towards the
      solution as far as the box allows, holding the variables that stop the move; at the solution, the
      most wrong-signed multiplier's variable is let go. The objective decreases at every move, so no
      set comes back.

    A problem is solved when its set stays: no free variable beyond its bounds, no multiplier wrong by
    more than the tolerance."""
    dtype, n = g.dtype, g.shape[0]
    bounded = jnp.concatenate([jnp.where(jnp.isfinite(lo), lo, 0.0), jnp.where(jnp.isfinite(hi), hi, 0.0)])
    tol = _tolerance(g, bounded)
    eye = jnp.eye(n, dtype=dtype)[:, :, None]

    def body(state):
        k, iters, at_lo, at_hi, v, settled = state
        held = at_lo | at_hi
        w = jnp.where(at_lo, lo, jnp.where(at_hi, hi, 0.0))
        M = jnp.where(held[:, None] | held[None, :], eye, H)
        goal = _substitute(_factor(M), jnp.where(held, w, -g - summed_products(H, w[None], axis=1)))
        # As far towards the goal as the box allows: the first bounds met are held.
        d = jnp.where(held, 0.0, goal - v)
        down, up = d < 0, d > 0
        ratio = jnp.where(
            down, (lo - v) / jnp.where(down, d, -1.0), jnp.where(up, (hi - v) / jnp.where(up, d, 1.0), jnp.inf)
        )
        alpha = jnp.minimum(jnp.min(ratio, axis=0), 1.0)
        reached = alpha >= 1.0
        stops = ~reached & (ratio <= alpha)
        moved = jnp.where(stops & down, lo, jnp.where(stops & up, hi, jnp.clip(v + alpha * d, lo, hi)))
        # At the goal: the held variable whose multiplier is the most wrong-signed is let go.
        grad = summed_products(H, goal[None], axis=1) + g
        wrong = jnp.where(at_lo, -grad, jnp.where(at_hi, grad, -jnp.inf))
        worst = jnp.max(wrong, axis=0)
        go = reached & (worst > tol)
        dropped = go & (wrong >= worst)
        moving = (
            jnp.where(reached, at_lo & ~dropped, at_lo | (stops & down)),
            jnp.where(reached, at_hi & ~dropped, at_hi | (stops & up)),
            jnp.where(reached, jnp.clip(goal, lo, hi), moved),
        )
        # Or, in the first iterations, jump: every variable beyond a bound and every wrong multiplier at once.
        jump_lo = (~held & (goal < lo)) | (at_lo & (grad >= -tol))
        jump_hi = (~held & (goal > hi)) | (at_hi & (grad <= tol))
        jumping = k < BOX_JUMPS
        jumped = (jump_lo, jump_hi, jnp.clip(goal, lo, hi))
        new = tuple(jnp.where(jumping, a, b) for a, b in zip(jumped, moving, strict=True))
        stays = jnp.all((jump_lo == at_lo) & (jump_hi == at_hi), axis=0)
        done = jnp.where(jumping, stays, reached & ~go)
        keep = lambda a, b: jnp.where(settled, b, a)  # noqa: E731
        at_lo, at_hi, v = (keep(a, b) for a, b in zip(new, (at_lo, at_hi, v), strict=True))
        return k + 1, iters + (~settled).astype(iters.dtype), at_lo, at_hi, v, settled | done

    def cond(state):
        k, *_, settled = state
        return (k < max_iters) & ~jnp.all(settled)

    free = _substitute(_factor(H), -g)
    at_lo, at_hi = free < lo, free > hi
    settled = ~jnp.any(at_lo | at_hi, axis=0)
    start = (jnp.zeros((), jnp.int32), jnp.ones(g.shape[1:], jnp.int32), at_lo, at_hi, jnp.clip(free, lo, hi), settled)
    _, iters, _, _, v, settled = jax.lax.while_loop(cond, body, start)
    return v, iters, settled


#: Largest ``n`` factored entry by entry (:func:`_factor`); above it, a batched LAPACK Cholesky
#: (the unrolled factorisation's trace and compile time grow as ``n^3``).
_UNROLL_MAX = 16


def _factor(M: jax.Array):
    """The Cholesky factorisation of each ``M`` ``(n, n, P)``, for :func:`_substitute`: the lower factor
    ``L`` (nested lists of ``(P,)`` arrays, below the diagonal) and ``1 / L[j][j]``.

    Up to :data:`_UNROLL_MAX`, entry by entry over the batch (:func:`diffkin.ik._linalg.cholesky`,
    every operation elementwise along ``P``): LAPACK on a tiny matrix,
    one call per problem, made the QP of ``dk.ik.step`` slow. Each column is computed once
    (:func:`diffkin._xla.materialize`) before the next reads it: materialised all at the end, each
    entry was a kernel that recomputed every column before its own (the Panda's QP at 4,096: 15-25 %
    slower; ``experiments/results/amd-epyc-2-cores-step.md``).
    """
    n = M.shape[0]
    if n > _UNROLL_MAX:
        return jax.scipy.linalg.cho_factor(jnp.moveaxis(M, -1, 0), lower=True)
    return cholesky([[M[i, j] for j in range(i + 1)] for i in range(n)], settle=materialize)


def _substitute(factor, b: jax.Array) -> jax.Array:
    """``M^-1 b`` for ``b`` ``(n, P)`` and the factorisation of :func:`_factor`."""
    if isinstance(factor[0], jax.Array):
        return jax.scipy.linalg.cho_solve(factor, b.T[..., None])[..., 0].T
    L, inv_diag = factor
    # Each substitution's entries computed once: fused into its consumers, each would redo the chain.
    y = list(materialize(forward_substitute(L, inv_diag, list(b))))
    return materialize(back_substitute(L, inv_diag, y))


def _computed(*arrays: jax.Array) -> tuple[jax.Array, ...]:
    """``arrays`` (``(k_i, P)``) computed once (:func:`diffkin._xla.materialize`, joined along their first
    axis): without it XLA's fusion recomputes a Newton direction inside each of its many consumers."""
    sizes = [a.shape[0] for a in arrays]
    joined = materialize([row for a in arrays for row in a])
    return tuple(jnp.split(joined, list(itertools.accumulate(sizes))[:-1]))


def _interior(H, g, lo, hi, G, h, on, *, max_iters: int) -> tuple[jax.Array, jax.Array]:
    """The interior point (module docstring), every problem at once, problem axis last: ``H``
    ``(n, n, P)``, ``g``, ``lo``, ``hi`` ``(n, P)``, ``G`` ``(m, n, P)``, ``h``, ``on`` ``(m, P)``; returns ``v``
    ``(n, P)`` (clipped into the box) and the iterations ``(P,)``. Each problem's iterates are those of the
    problem alone: it stops when it converges, the others go on (the loop runs while any has not)."""
    dtype, n = g.dtype, g.shape[0]
    # The constraints a^T v - b >= 0: the lower bounds (a = e_i), the upper (a = -e_i), the rows.
    has_lo, has_hi = jnp.isfinite(lo), jnp.isfinite(hi)
    mask = jnp.concatenate([has_lo, has_hi, on])  # (2n + m, P)
    b = jnp.where(mask, jnp.concatenate([lo, -hi, h]), 0.0)
    count = jnp.maximum(jnp.sum(mask, axis=0), 1)
    tol = _tolerance(g, b)
    rows = G.shape[0] > 0
    eye = jnp.eye(n, dtype=dtype)[:, :, None]

    def times_a(v):  # A v (2n + m, P)
        return jnp.where(mask, jnp.concatenate([v, -v, jnp.sum(G * v[None], axis=1) if rows else v[:0]]), 0.0)

    def times_at(y):  # A^T y (n, P)
        return y[:n] - y[n : 2 * n] + (jnp.sum(G * y[2 * n :, None], axis=0) if rows else 0.0)

    def factor(d):  # Cholesky of H + A^T diag(d) A
        M = H + eye * (d[:n] + d[n : 2 * n])[None]
        if rows:
            M = M + jnp.sum(G[:, :, None] * G[:, None, :] * d[2 * n :, None, None], axis=0)
        return _factor(M)

    def residuals(v, z):  # H v written out column by column (elementwise along P; a reduction is slower)
        Hv = functools.reduce(jnp.add, [H[:, j] * v[j] for j in range(n)])
        return Hv + g - times_at(z), times_a(v) - b

    def direction(c, s, z, r_d, r_p, r_c):
        """The Newton direction ``(dv, ds, dz)`` for complementarity residual ``r_c``."""
        y = jnp.where(mask, (r_c + z * r_p) / s, 0.0)
        dv = _substitute(c, -r_d - times_at(y))
        ds = times_a(dv) + r_p
        dz = jnp.where(mask, -(r_c + z * ds) / s, 0.0)
        return _computed(dv, ds, dz)

    def longest(s, ds, z, dz):  # the largest step keeping s, z >= 0 (inf: any)
        ratio = lambda x, dx: jnp.where(mask & (dx < 0), -x / jnp.where(dx < 0, dx, -1.0), jnp.inf)  # noqa: E731
        return jnp.min(jnp.minimum(ratio(s, ds), ratio(z, dz)), axis=0, initial=jnp.inf)

    # Start: the unconstrained minimiser, slacks and multipliers from one affine step (N&W 16.60).
    v = _substitute(_factor(H), -g)
    s, z = jnp.ones_like(b), mask.astype(dtype)  # off rows keep s = 1, z = 0
    r_d, r_p = residuals(v, z)
    r_p = r_p - jnp.where(mask, s, 0.0)
    dv, ds, dz = direction(factor(z / s), s, z, r_d, r_p, s * z)
    s = jnp.where(mask, jnp.maximum(1.0, jnp.abs(s + ds)), 1.0)
    z = jnp.where(mask, jnp.maximum(1.0, jnp.abs(z + dz)), 0.0)
    v = v + dv

    def measure(v, s, z):  # residuals, mu and whether converged
        r_d, r_p = residuals(v, z)
        r_p = jnp.where(mask, r_p - s, 0.0)
        mu = jnp.sum(s * z, axis=0) / count
        worst = jnp.maximum(jnp.max(jnp.abs(r_d), axis=0), jnp.max(jnp.abs(r_p), axis=0, initial=0.0))
        return r_d, r_p, mu, (worst <= tol) & (mu <= tol)

    def body(state):
        i, v, s, z, (r_d, r_p, mu, done) = state
        c = factor(jnp.where(mask, z / s, 0.0))
        dv_a, ds_a, dz_a = direction(c, s, z, r_d, r_p, s * z)
        alpha = jnp.minimum(1.0, longest(s, ds_a, z, dz_a))
        mu_aff = jnp.sum((s + alpha * ds_a) * (z + alpha * dz_a) * mask, axis=0) / count
        sigma = jnp.where(mu > 0, (mu_aff / jnp.where(mu > 0, mu, 1.0)) ** 3, 0.0)
        r_c = jnp.where(mask, s * z + ds_a * dz_a - sigma * mu, 0.0)
        dv, ds, dz = direction(c, s, z, r_d, r_p, r_c)
        alpha = jnp.minimum(1.0, _STEP_TO_BOUNDARY * longest(s, ds, z, dz))
        new = (
            v + alpha * dv,
            jnp.where(mask, jnp.maximum(s + alpha * ds, jnp.finfo(dtype).tiny), 1.0),
            jnp.where(mask, jnp.maximum(z + alpha * dz, 0.0), 0.0),
        )
        # Past the attainable accuracy the system degenerates (z / s overflows): stop where it was.
        finite = jnp.all(jnp.concatenate([jnp.isfinite(x) for x in new]), axis=0)
        v_new, s_new, z_new = _computed(*(jnp.where(finite, a, b) for a, b in zip(new, (v, s, z), strict=True)))
        r_d_new, r_p_new, mu_new, done_new = measure(v_new, s_new, z_new)
        # Only the problems still running move (as each problem's own loop would).
        go = (i < max_iters) & ~done
        keep = lambda a, b: jnp.where(go, a, b)  # noqa: E731
        return (
            i + go.astype(i.dtype),
            keep(v_new, v),
            keep(s_new, s),
            keep(z_new, z),
            (keep(r_d_new, r_d), keep(r_p_new, r_p), keep(mu_new, mu), keep(done_new | ~finite, done)),
        )

    def cond(state):
        i, *_, (_, _, _, done) = state
        return jnp.any((i < max_iters) & ~done)

    start = (jnp.zeros(g.shape[1:], jnp.int32), v, s, z, measure(v, s, z))
    iters, v, *_ = jax.lax.while_loop(cond, body, start)
    return jnp.clip(v, lo, hi), iters


def least_violation(qp: QP, max_iters: int = MAX_ITERS) -> jax.Array:
    """``(P,)`` the least ``t >= 0`` for which ``G v + t >= h`` (on rows) holds with ``v`` in the box:
    the smallest largest violation of the rows (0 when they can hold), to the solver's tolerance.

    Solved as a QP in ``(v, t)``: ``t`` weighted 1, ``v`` and ``t`` regularised by ``eps^(1/2)`` (the
    regularisation moves ``t`` by about that much relative, which :func:`diffkin.ik.step` allows for).
    """
    n, P = qp.g.shape
    dtype = qp.g.dtype
    reg = jnp.sqrt(jnp.finfo(dtype).eps)
    H = jnp.zeros((n + 1, n + 1, P), dtype) + reg * jnp.eye(n + 1, dtype=dtype)[:, :, None]
    g = jnp.concatenate([jnp.zeros((n, P), dtype), jnp.ones((1, P), dtype)])
    lo = jnp.concatenate([qp.lo, jnp.zeros((1, P), dtype)])
    hi = jnp.concatenate([qp.hi, jnp.full((1, P), jnp.inf, dtype)])
    G = jnp.concatenate([qp.G, jnp.ones((qp.G.shape[0], 1, P), dtype)], axis=1)
    t = solve(QP(H, g, lo, hi, G, qp.h, qp.on), max_iters).v[n]
    return jnp.maximum(t, 0.0)
