"""Sine and cosine of one angle together, and the two-argument arctangent, fast on XLA's CPU backend.

XLA's CPU ``sin`` and ``cos`` are each evaluated on their own and dominate the cost of a
forward pass (an arm's FK is ~14 of them against ~300 multiply-adds). :func:`sincos` shares
one range reduction by ``pi/2`` (Cody-Waite, three-part constant) between two short
polynomials on ``[-pi/4, pi/4]`` (the classic Cephes minimax coefficients) and picks the
quadrant with selects, so the whole thing fuses into the surrounding elementwise arithmetic.

Accuracy against the exact values: float32 within 1e-7 (XLA's own float32 ``sin`` is within
4e-8), float64 within 2e-16 (as the library's), over the whole finite range. The three-part
reduction is exact while ``|k| <= 2^13`` (float32, ``|x| <~ 1.3e4``) or ``2^30`` (float64): an array
with any angle beyond that takes a branch (one ``lax.cond`` per array, also under ``vmap``) that
gives those angles XLA's ``sin``/``cos``, whose range reduction is exact; the common case pays
only for the test. ``sin x`` of a tiny ``x`` (subnormals, ``-0.0``) is ``x`` itself, as numpy gives
it. Other dtypes use ``jnp.sin``/``jnp.cos``.

The fused ``sincos`` is for XLA's CPU backend only. On a GPU, XLA's own ``sin``/``cos`` are cheap
and the fused version is slower: the ``lax.cond`` on "any angle beyond the fast range" needs a
reduction over the whole array first and splits the forward pass into 9-16 kernels instead of
2-4 (about 3x slower float32 FK on an H100; docs/performance.md, "Trigonometry").
:func:`sincos` picks per platform with ``lax.platform_dependent`` (the platform
the computation is compiled for, not the default backend), so a program compiled for the CPU on a
GPU machine still gets the fused version, and the CPU's programs are unchanged.

XLA's CPU ``atan`` is slow too (~13 ns per float32 element on a 2-core EPYC VM, ``atan2`` twice
that). :func:`atan2` reduces ``(y, x)`` to an argument ``|t| <= tan(pi/8)`` with one division
(``t = lo/hi`` or ``(lo - hi)/(lo + hi)`` for ``lo = min(|x|, |y|)``, ``hi = max(|x|, |y|)``),
evaluates the Cephes approximation of ``atan(t)`` there (float32: a degree-9 odd polynomial;
float64: a rational function) and unfolds the octant with selects. Accuracy: float32 within
2.7e-7 rad (XLA's within 2.5e-7), float64 within 4.7e-16 rad; signs of zero and the axes as
``arctan2``, except ``atan2(+-0, +-0) = +-0`` (a neutral value where the angle is undefined);
both infinite as numpy (``atan2(inf, inf) = pi/4``), NaN in NaN out. Subnormal inputs are not
flushed to 0 (XLA's CPU compares, min/max and arithmetic do that): tiny pairs are scaled up by
an exact power of two, the pair is ordered by its bits, and a subnormal quotient is rounded from
a scaled one (within one unit in its last place of numpy's).

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
    np.dtype(np.float64): (
        1.58962301576546568060e-10,
        -2.50507477628578072866e-8,
        2.75573136213857245213e-6,
        -1.98412698295895385996e-4,
        8.33333333332211858878e-3,
        -1.66666666666666307295e-1,
    ),
}
_COS = {
    np.dtype(np.float32): (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2),
    np.dtype(np.float64): (
        -1.13585365213876817300e-11,
        2.08757008419747316778e-9,
        -2.75573141792967388112e-7,
        2.48015872888517045348e-5,
        -1.38888888888730564116e-3,
        4.16666666666665929218e-2,
    ),
}


# The fast reduction is exact while k * P1 and k * P2 are: |k| <= 2^13 (float32), 2^30 (float64).
_FAST_LIMIT = {np.dtype(np.float32): 2.0**13 * 1.5703125, np.dtype(np.float64): 2.0**30 * 1.5703125}
# Below these, sin x rounds to x (x^2/6 is under half an ulp).
_SIN_IS_X = {np.dtype(np.float32): 2.0**-12, np.dtype(np.float64): 2.0**-26}


def _poly(coefficients, x):
    out = coefficients[0]
    for c in coefficients[1:]:
        out = out * x + c
    return out


@jax.custom_jvp
def sincos(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(sin x, cos x)`` of a float array, elementwise (any shape).

    The fused version on the CPU, XLA's ``sin`` and ``cos`` elsewhere (chosen by the platform the
    computation is compiled for, not the default backend: see the module docstring).
    """
    dtype = np.dtype(x.dtype)
    if dtype not in _PI_2:
        return jnp.sin(x), jnp.cos(x)
    return jax.lax.platform_dependent(x, cpu=_sincos_any, default=_sincos_xla)


def _sincos_xla(x):
    return jnp.sin(x), jnp.cos(x)


@jax.custom_batching.custom_vmap
def _sincos_any(x):
    # The branch on "any angle beyond the fast range" is taken once per array, so the fast path
    # pays only for one reduction; under vmap it stays one branch for the whole batch (the rule below).
    big = jnp.abs(x) > _FAST_LIMIT[np.dtype(x.dtype)]
    return jax.lax.cond(jnp.any(big), _sincos_guarded, _sincos_fast, x)


@_sincos_any.def_vmap
def _sincos_any_vmap(axis_size, in_batched, x):
    return _sincos_any(x), (in_batched[0], in_batched[0])


def _sincos_guarded(x):
    """:func:`_sincos_fast` in its range, XLA's ``sin``/``cos`` (exact range reduction) beyond it."""
    big = jnp.abs(x) > _FAST_LIMIT[np.dtype(x.dtype)]
    s, c = _sincos_fast(jnp.where(big, 0.0, x))
    xb = jnp.where(big, x, 0.0)
    return jnp.where(big, jnp.sin(xb), s), jnp.where(big, jnp.cos(xb), c)


def _sincos_fast(x):
    dtype = np.dtype(x.dtype)
    p1, p2, p3 = _PI_2[dtype]
    k = jnp.round(x * _TWO_OVER_PI)
    r = ((x - k * p1) - k * p2) - k * p3
    r2 = r * r
    s = r + r * r2 * _poly(_SIN[dtype], r2)
    c = 1.0 - 0.5 * r2 + r2 * r2 * _poly(_COS[dtype], r2)
    quadrant = k.astype(jnp.int32) & 3
    odd = (quadrant & 1) == 1
    sin_, cos_ = jnp.where(odd, c, s), jnp.where(odd, s, c)
    sin_ = jnp.where(quadrant >= 2, -sin_, sin_)
    # sin x = x exactly for tiny |x|: returned by a select, so that subnormal x (which XLA's CPU
    # arithmetic flushes to zero) and -0.0 come back unchanged, as numpy gives them.
    sin_ = jnp.where(jnp.abs(x) < _SIN_IS_X[dtype], x, sin_)
    return sin_, jnp.where((quadrant == 1) | (quadrant == 2), -cos_, cos_)


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
    np.dtype(np.float64): (
        -8.750608600031904122785e-1,
        -1.615753718733365076637e1,
        -7.500855792314704667340e1,
        -1.228866684490136173410e2,
        -6.485021904942025371773e1,
    ),
}
_Q = (
    1.0,
    2.485846490142306297962e1,
    1.650270098316988542046e2,
    4.328810604912902668951e2,
    4.853903996359136964868e2,
    1.945506571482613964425e2,
)


# Per dtype: (precision p, exponent of the smallest subnormal, the integer type of the bits).
_FORMAT = {np.dtype(np.float32): (24, -149, jnp.int32), np.dtype(np.float64): (53, -1074, jnp.int64)}
# Inputs below 2^-SMALL are scaled up by 2^SCALE (exactly) before the reduction.
_SMALL = {np.dtype(np.float32): 60, np.dtype(np.float64): 500}
_SCALE = {np.dtype(np.float32): 100, np.dtype(np.float64): 600}


def _times_pow2(v, k: int):
    """``v * 2^k`` for ``v >= 0``, exact also for subnormal ``v`` (which XLA's CPU arithmetic flushes to 0).

    A subnormal is its bits (an integer, exactly a float) times the smallest subnormal; ``k``
    must keep the result normal.
    """
    dtype = np.dtype(v.dtype)
    _, e_min, itype = _FORMAT[dtype]
    sub = jax.lax.bitcast_convert_type(v, itype).astype(dtype) * dtype.type(2.0 ** (k + e_min))
    return jnp.where(v < np.finfo(dtype).tiny, sub, v * dtype.type(2.0**k))


def _over_pow2(z, k: int):
    """``z * 2^-k`` for ``z >= 0``, rounded to a subnormal where it is one (not flushed to 0)."""
    dtype = np.dtype(z.dtype)
    _, e_min, itype = _FORMAT[dtype]
    normal = z * dtype.type(2.0**-k)
    bits = jnp.round(z * dtype.type(2.0 ** (-k - e_min))).astype(itype)
    sub = jax.lax.bitcast_convert_type(bits, dtype)
    return jnp.where(z < np.finfo(dtype).tiny * dtype.type(2.0**k), sub, normal)


@jax.custom_jvp
def atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """``arctan2(y, x)`` of float arrays of one dtype (broadcast together), elementwise; ``+-0`` at the origin."""
    dtype = np.dtype(jnp.result_type(y, x))
    if dtype not in _P:
        return jnp.arctan2(y, x)
    y, x = jnp.broadcast_arrays(jnp.asarray(y, dtype), jnp.asarray(x, dtype))
    return _atan2_any(y, x)


@jax.custom_batching.custom_vmap
def _atan2_any(y, x):
    # Infinite pairs, tiny pairs and tiny quotients take the careful branch, once per array.
    dtype = np.dtype(x.dtype)
    ax, ay = jnp.abs(x), jnp.abs(y)
    p, _, itype = _FORMAT[dtype]
    # Zero-ness from the bits: XLA's CPU compares treat subnormals as 0.
    nx, ny = (jax.lax.bitcast_convert_type(v, itype) != 0 for v in (ax, ay))
    small = dtype.type(2.0 ** -_SMALL[dtype])
    lo, hi = jnp.minimum(ax, ay), jnp.maximum(ax, ay)
    special = (
        (jnp.isinf(ax) & jnp.isinf(ay))
        | (nx & (ax < small))
        | (ny & (ay < small))
        | (nx & ny & (lo < hi * dtype.type(2.0 ** -(2 * p))))
    )
    return jax.lax.cond(jnp.any(special), _atan2_careful, _atan2_fast, y, x)


@_atan2_any.def_vmap
def _atan2_any_vmap(axis_size, in_batched, y, x):
    y, x = (v if b else jnp.broadcast_to(v, (axis_size, *v.shape)) for v, b in zip((y, x), in_batched, strict=True))
    return _atan2_any(y, x), True


def _atan2_fast(y, x):
    dtype = np.dtype(x.dtype)
    ax, ay = jnp.abs(x), jnp.abs(y)
    steep = ay > ax
    lo, hi = jnp.minimum(ax, ay), jnp.maximum(ax, ay)
    r = _atan_octant(lo, hi, dtype)
    r = jnp.where(steep, 0.5 * np.pi - r, r)
    r = jnp.where(x < 0, np.pi - r, r)
    return jnp.where(jnp.signbit(y), -r, r)


def _atan_octant(lo, hi, dtype):
    """``atan(lo/hi)`` for ``0 <= lo <= hi``."""
    upper = lo > _TAN_PI_8 * hi  # atan(lo/hi) = pi/4 + atan((lo - hi)/(lo + hi))
    num, den = jnp.where(upper, lo - hi, lo), jnp.where(upper, lo + hi, hi)
    t = num / jnp.where(den > 0, den, 1.0)
    z = t * t
    if dtype == np.float32:
        r = t + t * z * _poly(_P[dtype], z)
    else:
        r = t + t * z * _poly(_P[dtype], z) / _poly(_Q, z)
    return jnp.where(upper, 0.25 * np.pi + r, r)


def _atan2_careful(y, x):
    dtype = np.dtype(x.dtype)
    ax, ay = jnp.abs(x), jnp.abs(y)
    # Both infinite: the diagonal of the quadrant, as (1, 1).
    both_inf = jnp.isinf(ax) & jnp.isinf(ay)
    ax, ay = jnp.where(both_inf, 1.0, ax), jnp.where(both_inf, 1.0, ay)
    # Both tiny (possibly subnormal): scale them up exactly, the angle is the same.
    small = (ax < dtype.type(2.0 ** -_SMALL[dtype])) & (ay < dtype.type(2.0 ** -_SMALL[dtype]))
    k = _SCALE[dtype]
    ax = jnp.where(small, _times_pow2(jnp.where(small, ax, 0.0), k), ax)
    ay = jnp.where(small, _times_pow2(jnp.where(small, ay, 0.0), k), ay)
    # Ordered by their bits (integers ordered as the non-negative floats): XLA's CPU compares and
    # min/max treat subnormals as 0, which would lose them here.
    itype = _FORMAT[dtype][2]
    bx, by = (jax.lax.bitcast_convert_type(v, itype) for v in (ax, ay))
    steep = by > bx
    lo, hi = jnp.where(steep, ax, ay), jnp.where(steep, ay, ax)
    r = _atan_octant(lo, hi, dtype)
    # atan(lo/hi) = lo/hi where lo/hi is below eps^2; formed as (lo/hi) 2^k / 2^k so that a
    # subnormal quotient is not flushed to 0.
    p, k = _FORMAT[dtype][0], _SCALE[dtype]
    tiny = lo < hi * dtype.type(2.0 ** -(2 * p))
    lo_up = lo < 1.0
    scaled = jnp.where(lo_up, _times_pow2(jnp.where(lo_up, lo, 0.0), k), lo) / jnp.where(
        lo_up, hi, hi * dtype.type(2.0**-k)
    )
    r = jnp.where(tiny, _over_pow2(jnp.where(tiny, scaled, 0.0), k), r)
    r = jnp.where(steep, 0.5 * np.pi - r, r)
    r = jnp.where(jnp.signbit(x) & (bx != 0), np.pi - r, r)
    r = jnp.where(jnp.signbit(y), -r, r)
    return jnp.where(jnp.isnan(x) | jnp.isnan(y), np.nan, r)


@atan2.defjvp
def _atan2_jvp(primals, tangents):
    (y, x), (dy, dx) = primals, tangents
    r2 = x * x + y * y
    nonzero = r2 > 0
    d = jnp.where(nonzero, (x * dy - y * dx) / jnp.where(nonzero, r2, 1.0), 0.0)
    return atan2(y, x), d
