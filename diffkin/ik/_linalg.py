"""Damped least squares on structure-of-arrays matrices, unrolled at trace time.

A batch of small ``m x n`` systems is held as nested lists of arrays of the batch shape (one
array per matrix entry), so every operation is elementwise over the batch and XLA fuses the
whole solve; on CPU this is far faster than a batched LAPACK call per tiny matrix.
"""

from __future__ import annotations

import jax.numpy as jnp

from diffkin import _rigid as rg


def _cholesky_solve(A: list[list], b: list) -> list:
    """Solve ``A x = b`` for a symmetric positive definite ``A`` (``n x n`` nested lists)."""
    n = len(b)
    L = [[0.0] * n for _ in range(n)]
    inv_diag = []
    for j in range(n):
        d = rg.add(A[j][j], *(-rg.mul(L[j][k], L[j][k]) for k in range(j)))
        inv = 1.0 / jnp.sqrt(jnp.maximum(d, jnp.finfo(jnp.result_type(d)).tiny))
        inv_diag.append(inv)
        for i in range(j + 1, n):
            L[i][j] = rg.mul(rg.add(A[i][j], *(-rg.mul(L[i][k], L[j][k]) for k in range(j))), inv)
    y = []
    for i in range(n):
        y.append(rg.mul(rg.add(b[i], *(-rg.mul(L[i][k], y[k]) for k in range(i))), inv_diag[i]))
    x = [0.0] * n
    for i in reversed(range(n)):
        x[i] = rg.mul(rg.add(y[i], *(-rg.mul(L[k][i], x[k]) for k in range(i + 1, n))), inv_diag[i])
    return x


def _materialized(A: list[list]) -> list[list]:
    """A symmetric matrix with its lower triangle computed once (see :func:`rg.materialize`)."""
    n = len(A)
    flat = iter(rg.materialize([A[i][j] for i in range(n) for j in range(i + 1)]))
    out = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            out[i][j] = out[j][i] = next(flat)
    return out


def damped_step(J: list[list], r: list, lam) -> list:
    """Levenberg step ``dq = argmin |J dq - r|^2 + lam |dq|^2`` for a batch of small systems.

    Uses ``dq = J^T (J J^T + lam I)^-1 r`` when ``J`` has no more rows than columns and
    ``(J^T J + lam I)^-1 J^T r`` otherwise, so the Cholesky factorisation is of the smaller
    normal matrix (``min(m, n)`` square).

    Args:
        J: ``m x n`` nested lists of entries (arrays of the batch shape, or Python floats).
        r: ``m`` residual entries.
        lam: damping, an array of the batch shape (positive).

    Returns:
        ``n`` entries of the step.
    """
    m, n = len(J), len(J[0])
    if m <= n:
        A = [[rg.add(*(rg.mul(J[i][k], J[j][k]) for k in range(n))) for j in range(m)] for i in range(m)]
        for i in range(m):
            A[i][i] = rg.add(A[i][i], lam)
        y = rg.materialize(_cholesky_solve(_materialized(A), r))
        return [rg.add(*(rg.mul(J[i][k], y[i]) for i in range(m))) for k in range(n)]
    A = [[rg.add(*(rg.mul(J[i][k], J[i][j]) for i in range(m))) for j in range(n)] for k in range(n)]
    for k in range(n):
        A[k][k] = rg.add(A[k][k], lam)
    b = [rg.add(*(rg.mul(J[i][k], r[i]) for i in range(m))) for k in range(n)]
    return _cholesky_solve(_materialized(A), b)
