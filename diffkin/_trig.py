"""Sine and cosine of one angle together, and the two-argument arctangent, fast on XLA's CPU backend.

XLA's CPU ``sin`` and ``cos`` are each evaluated on their own and dominate the cost of a
forward pass (an arm's FK is ~14 of them against ~300 multiply-adds). :func:`sincos` shares
one range reduction by ``pi/2`` (Cody-Waite, three-part constant) between two short
polynomials on ``[-pi/4, pi/4]`` (the classic Cephes minimax coefficients) and picks the
quadrant with selects, so the whole thing fuses into the surrounding elementwise arithmetic.

Accuracy against the exact values, for ``|x| <= 1e4`` rad: float32 within 1e-7 (XLA's own
float32 ``sin`` is within 4e-8), float64 within 2e-16 (as the library's). Larger angles lose
accuracy in the reduction (as ``k * pi/2`` no longer splits exactly): joint angles of that
size are not meaningful. Other dtypes use ``jnp.sin``/``jnp.cos``.

XLA's CPU ``atan`` is slow too (~13 ns per float32 element on a 2-core EPYC VM, ``atan2`` twice
that). :func:`atan2` reduces ``(y, x)`` to an argument ``|t| <= tan(pi/8)`` with one division
(``t = lo/hi`` or ``(lo - hi)/(lo + hi)`` for ``lo = min(|x|, |y|)``, ``hi = max(|x|, |y|)``),
evaluates the Cephes approximation of ``atan(t)`` there (float32: a degree-9 odd polynomial;
float64: a rational function) and unfolds the octant with selects. Accuracy: float32 within
2.7e-7 rad (XLA's within 2.5e-7), float64 within 4.7e-16 rad; signs of zero and the axes as
``arctan2``, except ``atan2(+-0, +-0) = +-0`` (a neutral value where the angle is undefined).

Both have exact derivatives (custom JVPs, not the derivatives of the approximations).
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


_TAN_PI_8 = 0.41421356237309504880
# atan t = t + t z P(z) / Q(z) with z = t^2 (Q monic, float64) or t + t z P(z) (float32),
# coefficients highest power first (Cephes atanf.c and atan.c).
_P = {
    np.dtype(np.float32): (8.05374449538e-2, -1.38776856032e-1, 1.99777106478e-1, -3.33329491539e-1),
    np.dtype(np.float64): (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
                           -1.228866684490136173410e2, -6.485021904942025371773e1),
}
_Q = (1.0, 2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
      4.853903996359136964868e2, 1.945506571482613964425e2)


@jax.custom_jvp
def atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """``arctan2(y, x)`` of float arrays of one dtype (broadcast together), elementwise; ``+-0`` at the origin."""
    dtype = np.dtype(jnp.result_type(y, x))
    if dtype not in _P:
        return jnp.arctan2(y, x)
    ax, ay = jnp.abs(x), jnp.abs(y)
    steep = ay > ax
    lo, hi = jnp.minimum(ax, ay), jnp.maximum(ax, ay)
    upper = lo > _TAN_PI_8 * hi  # atan(lo/hi) = pi/4 + atan((lo - hi)/(lo + hi))
    num, den = jnp.where(upper, lo - hi, lo), jnp.where(upper, lo + hi, hi)
    t = num / jnp.where(den > 0, den, 1.0)
    z = t * t
    if dtype == np.float32:
        r = t + t * z * _poly(_P[dtype], z)
    else:
        r = t + t * z * _poly(_P[dtype], z) / _poly(_Q, z)
    r = jnp.where(upper, 0.25 * np.pi + r, r)
    r = jnp.where(steep, 0.5 * np.pi - r, r)
    r = jnp.where(x < 0, np.pi - r, r)
    return jnp.where(jnp.signbit(y), -r, r)


@atan2.defjvp
def _atan2_jvp(primals, tangents):
    (y, x), (dy, dx) = primals, tangents
    r2 = x * x + y * y
    nonzero = r2 > 0
    d = jnp.where(nonzero, (x * dy - y * dx) / jnp.where(nonzero, r2, 1.0), 0.0)
    return atan2(y, x), d
