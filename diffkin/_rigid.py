"""Rigid transforms as structure-of-arrays, composed entry by entry.

A :class:`Rigid` holds the 3x3 rotation and the translation of a pose as nested tuples whose
entries are either arrays of the batch shape or Python floats. XLA's CPU backend is much
faster on elementwise arithmetic over a batch than on a ``vmap`` of tiny 4x4 matrix
products, and Python-float entries (exact 0 and +-1 of the constant parts of a chain) are
folded away at trace time, so only the arithmetic a robot really needs is compiled.

Model constants are folded only when they are concrete (not traced): a chain closed over by
``jit`` compiles to its sparse arithmetic, while a chain passed as a traced argument (for
gradients with respect to its parameters) takes the general path with the same result.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _trig
from diffkin._static import is_concrete
from diffkin._trig import atan2
from diffkin._xla import gpu_outputs, inverse_sqrt, materialize, stacked_sincos

Entry = jax.Array | float
# Three entries, and three rows of three. Variable-length tuple types: the entries are built by
# comprehensions (``tuple(... for i in range(3))``), which a type checker types as ``tuple[X, ...]``.
Vec3 = tuple[Entry, ...]
Mat3 = tuple[Vec3, ...]

_SNAP = 1e-12  # constants this close to 0 or +-1 are taken as exactly that


class Rigid(NamedTuple):
    """Pose ``[R p; 0 1]`` with entries that are arrays (one batch shape) or Python floats."""

    R: Mat3
    p: Vec3


def constant(x) -> Entry:
    """A scalar model parameter: a snapped Python float if concrete, else the traced array."""
    if not is_concrete(x):
        return x
    value = float(np.asarray(x, dtype=np.float64))
    for exact in (0.0, 1.0, -1.0):
        if abs(value - exact) < _SNAP:
            return exact
    return value


def mul(a: Entry, b: Entry) -> Entry:
    """Product, folding exact Python-float zeros and ones."""
    for x, y in ((a, b), (b, a)):
        if isinstance(x, float):
            if x == 0.0:
                return 0.0
            if x == 1.0:
                return y
            if x == -1.0:
                return -y
    return a * b


def add(*terms: Entry) -> Entry:
    """Sum, dropping exact Python-float zeros."""
    kept = [t for t in terms if not (isinstance(t, float) and t == 0.0)]
    if not kept:
        return 0.0
    total = kept[0]
    for t in kept[1:]:
        total = total + t
    return total


def dot(a: Vec3, b: Vec3) -> Entry:
    return add(mul(a[0], b[0]), mul(a[1], b[1]), mul(a[2], b[2]))


def cross(a: Vec3, b: Vec3) -> Vec3:
    return (
        add(mul(a[1], b[2]), -mul(a[2], b[1])),
        add(mul(a[2], b[0]), -mul(a[0], b[2])),
        add(mul(a[0], b[1]), -mul(a[1], b[0])),
    )


def scale(s: Entry, v: Vec3) -> Vec3:
    return (mul(s, v[0]), mul(s, v[1]), mul(s, v[2]))


def vadd(*vs: Vec3) -> Vec3:
    return tuple(add(*(v[i] for v in vs)) for i in range(3))


def column(R: Mat3, j: int) -> Vec3:
    return (R[0][j], R[1][j], R[2][j])


def rotate(R: Mat3, v: Vec3) -> Vec3:
    """``R @ v``."""
    return (dot(R[0], v), dot(R[1], v), dot(R[2], v))


def matmul(A: Mat3, B: Mat3) -> Mat3:
    cols = [column(B, j) for j in range(3)]
    return tuple(tuple(dot(A[i], cols[j]) for j in range(3)) for i in range(3))


def compose(A: Rigid, B: Rigid) -> Rigid:
    """``A @ B``."""
    return Rigid(matmul(A.R, B.R), vadd(rotate(A.R, B.p), A.p))


def inverse(A: Rigid) -> Rigid:
    Rt = tuple(column(A.R, j) for j in range(3))
    return Rigid(Rt, scale(-1.0, rotate(Rt, A.p)))


IDENTITY = Rigid(((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), (0.0, 0.0, 0.0))


def from_matrix(T) -> Rigid:
    """Split a ``(..., 4, 4)`` pose into entries, folding it if it is a concrete constant."""
    if is_concrete(T) and np.ndim(T) == 2:
        T = np.asarray(T, dtype=np.float64)  # index on the host: indexing a jax Array under jit stages it out
        return Rigid(
            tuple(tuple(constant(T[i, j]) for j in range(3)) for i in range(3)),
            tuple(constant(T[i, 3]) for i in range(3)),
        )
    T = jnp.asarray(T)
    return Rigid(
        tuple(tuple(T[..., i, j] for j in range(3)) for i in range(3)),
        tuple(T[..., i, 3] for i in range(3)),
    )


def vector(x) -> Vec3:
    """Split a ``(..., 3)`` vector into entries, folding it if it is a concrete constant."""
    if is_concrete(x) and np.ndim(x) == 1:
        x = np.asarray(x, dtype=np.float64)
        return tuple(constant(x[i]) for i in range(3))
    x = jnp.asarray(x)
    return (x[..., 0], x[..., 1], x[..., 2])


def stack(entries: list[Entry], shape: tuple[int, ...], dtype, axis: int = -1) -> jax.Array:
    """Entries broadcast to ``shape`` and stacked on a new axis (the last by default)."""
    arrays = [jnp.broadcast_to(jnp.asarray(e, dtype=dtype), shape) for e in entries]
    return jnp.stack(arrays, axis=axis)


def outputs(entries: list[Entry], shape: tuple[int, ...], dtype) -> jax.Array:
    """The entries stacked into one ``shape + (len(entries),)`` array (:func:`stack` on the last axis),
    the computed ones through :func:`diffkin._xla.gpu_outputs` (a barrier in float32 off the CPU)."""
    arrays = [jnp.broadcast_to(jnp.asarray(e, dtype=dtype), shape) for e in entries]
    computed = [i for i, e in enumerate(entries) if not isinstance(e, float)]
    if shape and computed:
        for i, a in zip(computed, gpu_outputs([arrays[i] for i in computed], dtype), strict=True):
            arrays[i] = a
    return jnp.stack(arrays, axis=-1)


def checkpoint(A: Rigid) -> Rigid:
    """``A`` with its array entries computed once (:func:`materialize`); Python-float entries stay folded."""
    flat = leaves(A)
    arrays = [i for i, e in enumerate(flat) if not isinstance(e, float)]
    if not arrays:
        return A
    done = materialize([flat[i] for i in arrays])
    for k, i in enumerate(arrays):
        flat[i] = done[k]
    return Rigid(tuple(tuple(flat[3 * r : 3 * r + 3]) for r in range(3)), tuple(flat[9:]))  # type: ignore[arg-type]


def _matrix_entries(A: Rigid) -> list[Entry]:
    """The 16 entries of ``A``'s 4x4 matrix, row by row."""
    return [e for i in range(3) for e in (*A.R[i], A.p[i])] + [0.0, 0.0, 0.0, 1.0]


def to_matrix(A: Rigid, shape: tuple[int, ...], dtype) -> jax.Array:
    """The ``shape + (4, 4)`` matrix of ``A``."""
    return outputs(_matrix_entries(A), shape, dtype).reshape(shape + (4, 4))


def to_matrices(poses: list[Rigid], shape: tuple[int, ...], dtype) -> jax.Array:
    """The ``shape + (len(poses), 4, 4)`` matrices of ``poses``, written by one stack.

    One stack of every entry, not a stack of per-pose matrices (about 2x faster for a humanoid's
    link poses; docs/performance.md, "XLA CPU tricks").
    """
    flat = outputs([e for A in poses for e in _matrix_entries(A)], shape, dtype)
    return flat.reshape(shape + (len(poses), 4, 4))


def skew(w: Vec3) -> Mat3:
    return ((0.0, -w[2], w[1]), (w[2], 0.0, -w[0]), (-w[1], w[0], 0.0))


def screw_exp(v: Vec3, w: Vec3, theta: Entry) -> Rigid:
    """``exp([S] theta)`` for the screw ``S = [v; w]``.

    ``R = I + A [w] + B [w]^2`` and ``p = theta v + B [w] v + C [w]^2 v`` with
    ``A = sin(n theta)/n``, ``B = (1 - cos(n theta))/n^2``, ``C = (n theta - sin(n theta))/n^3``
    and ``n = |w|``. A concrete unit (or zero) ``w`` uses the exact closed form of a joint
    screw; a traced ``w`` (gradients with respect to the screws) uses the general form with
    Taylor expansions at ``n -> 0`` so that no derivative is NaN.
    """
    return screw_exps([(v, w)], [theta])[0]


def screw_exps(screws: Sequence[tuple[Vec3, Vec3]], thetas: Sequence[Entry]) -> list[Rigid]:
    """:func:`screw_exp` of every screw ``(v, w)`` and its ``theta``, every sine and cosine from one
    :func:`sincos_each` (a forward pass is one exponential per joint)."""
    norms2 = [dot(w, w) for _, w in screws]
    angles = [_exp_angle(n2, theta) for n2, theta in zip(norms2, thetas, strict=True)]
    trig = iter(sincos_each([x for x in angles if x is not None]))
    out = []
    for (v, w), theta, n2, x in zip(screws, thetas, norms2, angles, strict=True):
        if x is None:  # a concrete zero w: a translation
            out.append(Rigid(IDENTITY.R, scale(theta, v)))
            continue
        s, c = next(trig)
        if isinstance(n2, float) and abs(n2 - 1.0) < _SNAP:
            A, B, C = s, add(1.0, -c), add(theta, -s)
        else:
            A, B, C = _exp_coefficients(jnp.asarray(n2), theta, x, s, c)
        W = skew(w)
        W2 = matmul(W, W)
        R = tuple(
            tuple(add(1.0 if i == j else 0.0, mul(A, W[i][j]), mul(B, W2[i][j])) for j in range(3)) for i in range(3)
        )
        out.append(Rigid(R, vadd(scale(theta, v), scale(B, rotate(W, v)), scale(C, rotate(W2, v)))))
    return out


def rotation_exp(r: Vec3) -> tuple[Mat3, Mat3]:
    """``exp([r])`` of a rotation vector ``r`` and its left Jacobian ``J``, with which a change ``dr``
    turns the rotation by the angular velocity ``J dr`` (in the frame ``r`` is expressed in).

    ``R = I + A [r] + B [r]^2`` and ``J = I + B [r] + C [r]^2``, the coefficients of :func:`screw_exp`
    at ``theta = 1`` (NaN-free at ``r = 0``, where both are the identity).
    """
    n2 = jnp.asarray(dot(r, r))
    one = jnp.ones_like(n2)
    x = _safe_norm(n2)
    s, c = sincos(x)
    A, B, C = _exp_coefficients(n2, one, x, s, c)
    W = skew(r)
    W2 = matmul(W, W)
    eye = lambda i, j: 1.0 if i == j else 0.0  # noqa: E731
    R = tuple(tuple(add(eye(i, j), mul(A, W[i][j]), mul(B, W2[i][j])) for j in range(3)) for i in range(3))
    J = tuple(tuple(add(eye(i, j), mul(B, W[i][j]), mul(C, W2[i][j])) for j in range(3)) for i in range(3))
    return R, J


def _exp_angle(n2: Entry, theta: Entry) -> Entry | None:
    """The angle ``|w| theta`` of :func:`screw_exp` (``None`` for a concrete zero ``w``; ``theta`` for a unit one)."""
    if isinstance(n2, float):
        if n2 == 0.0:
            return None
        if abs(n2 - 1.0) < _SNAP:
            return theta
    return _safe_norm(jnp.asarray(n2)) * theta


def _safe_norm(n2):
    """``|w|`` from ``n^2 = |w|^2``, 1 where ``n^2 < 1e-8`` (the series of :func:`_exp_coefficients` take over)."""
    return jnp.sqrt(jnp.where(n2 < 1e-8, 1.0, n2))


def norm(v: Vec3) -> jax.Array:
    """``|v|`` with a zero (not NaN) derivative at ``v = 0``."""
    sq = dot(v, v)
    nonzero = sq > 0
    return jnp.where(nonzero, jnp.sqrt(jnp.where(nonzero, sq, 1.0)), 0.0)


def _angle_terms(M: Mat3) -> tuple[Vec3, jax.Array, jax.Array]:
    """``vee(M) = sin(theta) axis``, ``|vee(M)| = sin(theta)`` and ``cos(theta) = (tr M - 1) / 2`` of a rotation."""
    v = tuple(mul(0.5, add(M[i][j], -M[j][i])) for i, j in ((2, 1), (0, 2), (1, 0)))
    return v, norm(v), jnp.asarray(mul(0.5, add(M[0][0], M[1][1], M[2][2], -1.0)))


def rotation_angle(M: Mat3) -> jax.Array:
    """Angle ``theta`` in ``[0, pi]`` of the rotation ``M`` (entries): ``atan2(|vee(M)|, (tr M - 1) / 2)``.

    Accurate near 0 and pi (``arccos`` of the trace is not: it loses half the digits near 0);
    a finite derivative everywhere (zero at the identity, where ``theta`` has no two-sided one).
    """
    _, sin_, cos_ = _angle_terms(M)
    return atan2(sin_, cos_)


def so3_log(M: Mat3) -> tuple[Vec3, jax.Array]:
    """Rotation vector ``w`` with ``M = exp([w])``, ``|w| <= pi``, and its angle ``theta = |w|``, elementwise.

    ``w = theta / sin(theta) vee(M)`` (a series below 1e-4 rad). Near a half-turn (``cos theta <
    -0.99``) the axis is the column of ``(M + M^T)/2 - cos(theta) I = (1 - cos theta) a a^T`` of
    largest diagonal entry, normalised and oriented by ``vee(M)``. Written with selects, not gathers,
    so that XLA fuses it over the batch; finite derivatives for every rotation.
    """
    v, sin_, cos_ = _angle_terms(M)
    theta = atan2(sin_, cos_)
    small = theta < 1e-4
    factor = jnp.where(small, 1.0 + theta * theta / 6.0, theta / jnp.where(small, 1.0, sin_))
    S = [[add(mul(0.5, add(M[i][j], M[j][i])), -cos_ if i == j else 0.0) for j in range(3)] for i in range(3)]
    first = (S[0][0] >= S[1][1]) & (S[0][0] >= S[2][2])
    second = S[1][1] >= S[2][2]
    col = [jnp.where(first, S[i][0], jnp.where(second, S[i][1], S[i][2])) for i in range(3)]
    inv_norm = inverse_sqrt(
        jnp.maximum(col[0] * col[0] + col[1] * col[1] + col[2] * col[2], jnp.finfo(theta.dtype).tiny)
    )
    signed = jnp.where(col[0] * v[0] + col[1] * v[1] + col[2] * v[2] < 0, -theta, theta) * inv_norm
    near_pi = cos_ < -0.99
    w = tuple(jnp.where(near_pi, signed * col[i], factor * v[i]) for i in range(3))
    return w, theta


def _exp_coefficients(n2, theta, x, s, c):
    """``A, B, C`` of :func:`screw_exp` for ``n^2 = |w|^2``, ``x = n theta`` (:func:`_exp_angle`) and
    ``(s, c) = (sin x, cos x)``, NaN-free at ``n = 0``."""
    small = n2 < 1e-8
    n = _safe_norm(n2)
    # The series below multiply an axis that is exactly zero for a prismatic joint: evaluated there at a
    # clipped theta, so that theta^5 (which overflows from |theta| ~ 1.8e61 m in float64, 5e7 m in
    # float32) cannot make inf * 0 = NaN. Elsewhere (and for every |theta| below the clip) unchanged.
    clip = float(np.finfo(jnp.result_type(theta)).max) ** 0.2 / 10.0
    theta_s = jnp.where(n2 == 0.0, jnp.clip(theta, -clip, clip), theta)
    t2, t3 = theta_s * theta_s, theta_s * theta_s * theta_s
    A = jnp.where(small, theta_s - n2 * t3 / 6.0, s / n)
    B = jnp.where(small, t2 / 2.0 - n2 * t2 * t2 / 24.0, (1.0 - c) / jnp.where(small, 1.0, n2))
    C = jnp.where(small, t3 / 6.0 - n2 * t3 * t2 / 120.0, (x - s) / (n * jnp.where(small, 1.0, n2)))
    return A, B, C


def batch_shape(*entries) -> tuple[int, ...]:
    """Broadcast shape of the array entries (Python floats count as scalars)."""
    shapes = [jnp.shape(e) for e in entries if not isinstance(e, float)]
    return tuple(np.broadcast_shapes(*shapes)) if shapes else ()


def leaves(A: Rigid) -> list[Entry]:
    return [e for row in A.R for e in row] + list(A.p)


def world_from_space(columns: Sequence[tuple[Vec3, Vec3]], p: Vec3) -> list[tuple[Vec3, Vec3]]:
    """Space twists ``(v, w)`` as ``(v + w x p, w)``: the velocity of the point ``p`` and the angular velocity."""
    return [(vadd(v, cross(w, p)), w) for v, w in columns]


def root_screws(B: Rigid) -> list[tuple[Vec3, Vec3]]:
    """Space twists of a root pose ``B = T_world_root`` moved by its body twist ``[v; w]`` (unit steps):
    ``Ad(B) e_k``, ``k = 0 .. 5``."""
    axes = [column(B.R, k) for k in range(3)]
    zero = (0.0, 0.0, 0.0)
    return [(a, zero) for a in axes] + [(cross(B.p, a), a) for a in axes]


def sincos(x: Entry) -> tuple[Entry, Entry]:
    """``(sin x, cos x)`` of an entry (as :func:`diffkin._trig.sincos`), as snapped Python floats for a constant."""
    if isinstance(x, float):
        return constant(np.sin(x)), constant(np.cos(x))
    return _trig.sincos(x)


def sincos_each(xs: Sequence[Entry]) -> list[tuple[Entry, Entry]]:
    """:func:`sincos` of each entry; the array entries (broadcast to one shape) through one
    :func:`diffkin._trig.sincos` of their stack.

    One call for a whole forward pass instead of one per joint (:func:`diffkin._xla.stacked_sincos`).
    """
    arrays = [x for x in xs if not isinstance(x, float)]
    if not arrays:
        return [sincos(x) for x in xs]
    s, c = stacked_sincos(tuple(jnp.broadcast_arrays(*arrays)))
    computed = zip(s, c, strict=True)
    return [sincos(x) if isinstance(x, float) else next(computed) for x in xs]


def per_joint(x, snap: bool = True) -> list[Entry]:
    """The values of a ``(n,)`` model parameter, one per joint: snapped floats if concrete, else traced slices.

    ``snap=False`` keeps concrete values as they are (only exact zeros fold away): for quantities such as
    masses whose scale is arbitrary, where 1e-13 is not 0.
    """
    if is_concrete(x):
        values = np.asarray(x, dtype=np.float64)
        return [constant(v) for v in values] if snap else [float(v) for v in values]
    return [x[..., i] for i in range(x.shape[-1])]
