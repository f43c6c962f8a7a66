"""Damped least squares on structure-of-arrays matrices, unrolled at trace time.

A batch of small ``m x n`` systems is held as nested lists of arrays of the batch shape (one
array per matrix entry), so every operation is elementwise over the batch and XLA fuses the
whole solve; on CPU this is far faster than a batched LAPACK call per tiny matrix.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin import _rigid as rg
from diffkin._xla import inverse_sqrt, materialize


def _cholesky_solve(A: list[list], b: list) -> list:
    """Solve ``A x = b`` for a symmetric positive definite ``A`` (``n x n`` nested lists)."""
    return cholesky_substitute(*cholesky(A), b)


def cholesky(A: list[list], settle=None) -> tuple[list[list], list]:
    """The lower Cholesky factor ``L`` of a symmetric positive definite ``A`` (``n x n`` nested lists,
    read from its lower triangle) and ``1 / L[j][j]``: its entries below the diagonal and the inverses.

    ``settle``, where given, takes each column ``[1 / L[j][j], L[j + 1][j], ...]`` once computed and
    returns the values later columns read instead (:func:`diffkin._xla.materialize`: each column
    computed once, not again inside every later entry's kernel)."""
    n = len(A)
    L: list[list[rg.Entry]] = [[0.0] * n for _ in range(n)]
    inv_diag = []
    for j in range(n):
        d = rg.add(A[j][j], *(-rg.mul(L[j][k], L[j][k]) for k in range(j)))
        inv = inverse_sqrt(jnp.maximum(d, jnp.finfo(jnp.result_type(d)).tiny))
        column = [rg.mul(rg.add(A[i][j], *(-rg.mul(L[i][k], L[j][k]) for k in range(j))), inv) for i in range(j + 1, n)]
        if settle is not None:
            inv, *column = settle([inv, *column])
        inv_diag.append(inv)
        for i, entry in zip(range(j + 1, n), column, strict=True):
            L[i][j] = entry
    return L, inv_diag


def cholesky_substitute(L: list[list], inv_diag: list, b: list) -> list:
    """``x`` of ``L L^T x = b`` for the factor of :func:`cholesky`: two triangular substitutions."""
    return back_substitute(L, inv_diag, forward_substitute(L, inv_diag, b))


def forward_substitute(L: list[list], inv_diag: list, b: list) -> list:
    """``y`` of ``L y = b`` for the factor of :func:`cholesky`."""
    y: list[rg.Entry] = []
    for i in range(len(b)):
        y.append(rg.mul(rg.add(b[i], *(-rg.mul(L[i][k], y[k]) for k in range(i))), inv_diag[i]))
    return y


def back_substitute(L: list[list], inv_diag: list, y: list) -> list:
    """``x`` of ``L^T x = y`` for the factor of :func:`cholesky`."""
    n = len(y)
    x: list[rg.Entry] = [0.0] * n
    for i in reversed(range(n)):
        x[i] = rg.mul(rg.add(y[i], *(-rg.mul(L[k][i], x[k]) for k in range(i + 1, n))), inv_diag[i])
    return x


def _materialized(A: list[list]) -> list[list]:
    """A symmetric matrix with its lower triangle computed once (see :func:`diffkin._xla.materialize`)."""
    n = len(A)
    flat = iter(materialize([A[i][j] for i in range(n) for j in range(i + 1)]))
    out = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            out[i][j] = out[j][i] = next(flat)
    return out


#: Largest normal matrix solved entry by entry. Above it (several targets of a whole robot) the
#: unrolled factorisation's trace and compile time grow as ``size^3`` and a batched LAPACK solve
#: of dense matrices is used instead.
_UNROLL_MAX = 6


def damped_step(J: jax.Array, r: jax.Array, lam: jax.Array) -> jax.Array:
    """Levenberg step ``dq = argmin |J dq - r|^2 + lam |dq|^2`` for a batch of small systems.

    Uses ``dq = J^T (J J^T + lam I)^-1 r`` when ``J`` has no more rows than columns and
    ``(J^T J + lam I)^-1 J^T r`` otherwise, so the Cholesky factorisation is of the smaller
    normal matrix (``min(m, n)`` square).

    Args:
        J: ``(m, n, P)`` matrices, problem axis last.
        r: ``(m, P)`` residuals.
        lam: ``(P,)`` damping (positive).

    Returns:
        ``(n, P)`` steps.
    """
    m, n = J.shape[:2]
    if min(m, n) > _UNROLL_MAX:
        return _dense_step(J, r, lam)
    return jnp.stack(_unrolled_step(J, r, lam))


def _dense_step(J: jax.Array, r: jax.Array, lam: jax.Array) -> jax.Array:
    """:func:`damped_step` with batched dense matrices (``(P, k, k)`` Cholesky)."""
    Jp, rp = jnp.moveaxis(J, -1, 0), jnp.moveaxis(r, -1, 0)  # (P, m, n), (P, m)
    m, n = Jp.shape[1:]
    if m <= n:
        A = Jp @ jnp.swapaxes(Jp, -1, -2) + lam[:, None, None] * jnp.eye(m, dtype=J.dtype)
        y = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(A, lower=True), rp[..., None])[..., 0]
        return jnp.einsum("pmn,pm->np", Jp, y)
    A = jnp.swapaxes(Jp, -1, -2) @ Jp + lam[:, None, None] * jnp.eye(n, dtype=J.dtype)
    b = jnp.einsum("pmn,pm->pn", Jp, rp)
    return jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(A, lower=True), b[..., None])[..., 0].T


def _unrolled_step(J, r, lam) -> list:
    """:func:`damped_step` entry by entry (``J[i][k]``, ``r[i]`` of the batch shape): ``n`` entries."""
    m, n = len(J), len(J[0])
    if m <= n:
        A = [[rg.add(*(rg.mul(J[i][k], J[j][k]) for k in range(n))) for j in range(m)] for i in range(m)]
        for i in range(m):
            A[i][i] = rg.add(A[i][i], lam)
        y = materialize(_cholesky_solve(_materialized(A), r))
        return [rg.add(*(rg.mul(J[i][k], y[i]) for i in range(m))) for k in range(n)]
    A = [[rg.add(*(rg.mul(J[i][k], J[i][j]) for i in range(m))) for j in range(n)] for k in range(n)]
    for k in range(n):
        A[k][k] = rg.add(A[k][k], lam)
    b = [rg.add(*(rg.mul(J[i][k], r[i]) for i in range(m))) for k in range(n)]
    return _cholesky_solve(_materialized(A), b)
