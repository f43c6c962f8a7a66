"""Sine and cosine of one angle together, fast on XLA's CPU backend.

XLA's CPU ``sin`` and ``cos`` are each evaluated on their own and dominate the cost of a
forward pass (an arm's FK is ~14 of them against ~300 multiply-adds). :func:`sincos` shares
one range reduction by ``pi/2`` (Cody-Waite, three-part constant) between two short
polynomials on ``[-pi/4, pi/4]`` (the classic Cephes minimax coefficients) and picks the
quadrant with selects, so the whole thing fuses into the surrounding elementwise arithmetic.

Accuracy against the exact values, for ``|x| <= 1e4`` rad: float32 within 1e-7 (XLA's own
float32 ``sin`` is within 4e-8), float64 within 2e-16 (as the library's). Larger angles lose
accuracy in the reduction (as ``k * pi/2`` no longer splits exactly): joint angles of that
size are not meaningful. Other dtypes use ``jnp.sin``/``jnp.cos``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_TWO_OVER_PI = 0.63661977236758134308

# pi/2 = P1 + P2 + P3, P1 and P2 with trailing zero bits so that k * P1, k * P2 are exact.
_PI_2 = {
    np.dtype(np.float32): (1.5703125, 4.837512969970703125e-4, 7.549789954891882e-08),
    np.dtype(np.float64): (1.57079625129699707031, 7.54978941586159635336e-8, 5.390302858158119e-15),
}
# sin r = r + r^3 S(r^2), cos r = 1 - r^2/2 + r^4 C(r^2); coefficients highest power first.
_SIN = {
    np.dtype(np.float32): (-1.9515295891e-4, 8.3321608736e-3, -1.6666654611e-1),
    np.dtype(np.float64): (1.58962301576546568060e-10, -2.50507477628578072866e-8,
                           2.75573136213857245213e-6, -1.98412698295895385996e-4,
                           8.33333333332211858878e-3, -1.66666666666666307295e-1),
}
_COS = {
    np.dtype(np.float32): (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2),
    np.dtype(np.float64): (-1.13585365213876817300e-11, 2.08757008419747316778e-9,
                           -2.75573141792967388112e-7, 2.48015872888517045348e-5,
                           -1.38888888888730564116e-3, 4.16666666666665929218e-2),
}


def _poly(coefficients, x):
    out = coefficients[0]
    for c in coefficients[1:]:
        out = out * x + c
    return out


@jax.custom_jvp
def sincos(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(sin x, cos x)`` of a float array, elementwise (any shape)."""
    dtype = np.dtype(x.dtype)
    if dtype not in _PI_2:
        return jnp.sin(x), jnp.cos(x)
    p1, p2, p3 = _PI_2[dtype]
    k = jnp.round(x * _TWO_OVER_PI)
    r = ((x - k * p1) - k * p2) - k * p3
    r2 = r * r
    s = r + r * r2 * _poly(_SIN[dtype], r2)
    c = 1.0 - 0.5 * r2 + r2 * r2 * _poly(_COS[dtype], r2)
    quadrant = k.astype(jnp.int32) & 3
    odd = (quadrant & 1) == 1
    sin_, cos_ = jnp.where(odd, c, s), jnp.where(odd, s, c)
    return jnp.where(quadrant >= 2, -sin_, sin_), jnp.where((quadrant == 1) | (quadrant == 2), -cos_, cos_)


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = sincos(x)
    return (s, c), (c * dx, -s * dx)
