"""Box-box and capsule-box signed distances, from the closest-feature candidates.

A box and a segment (or a box) have a zonotope as Minkowski difference, whose facet normals are
the box axes and the cross products of the generators.

- Overlapping: the separating-axis test over exactly those axes gives the depth (the largest
  separation, which is negative). Its derivative is that of the winning axis' expression.
- Apart: the distance between two convex sets is attained vertex-to-solid or edge-to-edge, and an
  edge pair can only be closest along its common normal ``e_i x b_m``: the candidates are the
  corners of each shape against the other, and per axis pair the support edges of each shape
  along that normal. Every candidate is a distance between a point of each shape, so the smallest
  is the distance. Its derivative comes from the closest points (:func:`_apart`), not from
  differentiating the candidates.

Vectors are tuples of three arrays (one per coordinate) of broadcastable batch shapes: the
arithmetic is entry by entry, which XLA's CPU backend fuses into one loop over the batch (as the
rigid transforms of :mod:`diffkin._rigid`), instead of tiny batched matrix products.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from diffkin.collision._closest import safe_div
from diffkin.collision._shapes import Box, Capsule

Vec = tuple[jax.Array, jax.Array, jax.Array]


def _vec(x: jax.Array) -> Vec:
    return (x[..., 0], x[..., 1], x[..., 2])


def _rotation(pose: jax.Array) -> tuple[Vec, Vec, Vec]:
    """The columns of the rotation of ``pose (..., 4, 4)``: the box's axes in the outer frame."""
    return tuple((pose[..., 0, j], pose[..., 1, j], pose[..., 2, j]) for j in range(3))  # type: ignore[return-value]


def _dot(u: Vec, v: Vec) -> jax.Array:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _sub(u: Vec, v: Vec) -> Vec:
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def _to_frame(axes: tuple[Vec, Vec, Vec], v: Vec) -> Vec:
    """``R^T v`` for the rotation of columns ``axes``."""
    return (_dot(axes[0], v), _dot(axes[1], v), _dot(axes[2], v))


def _sign(x: jax.Array) -> jax.Array:
    """``+1`` where ``x >= 0``, else ``-1`` (never 0: a tie picks a side)."""
    return jnp.where(x >= 0, 1, -1).astype(x.dtype)


def _sqrt(sq: jax.Array) -> jax.Array:
    """``sqrt`` with a zero (not NaN) derivative at 0."""
    ok = sq > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1)), 0)


def _unit(v: Vec) -> tuple[Vec, jax.Array]:
    """``v / |v|`` and a mask of the axes in use (``|v|`` not vanishingly small)."""
    sq = _dot(v, v)
    ok = sq > jnp.sqrt(jnp.finfo(sq.dtype).tiny)
    inv = 1 / jnp.sqrt(jnp.where(ok, sq, 1))
    return (v[0] * inv, v[1] * inv, v[2] * inv), ok


def _cross_axis(i: int, v: Vec) -> Vec:
    """``e_i x v``."""
    zero = jnp.zeros_like(v[0])
    if i == 0:
        return (zero, -v[2], v[1])
    if i == 1:
        return (v[2], zero, -v[0])
    return (-v[1], v[0], zero)


def _clamp(p: Vec, h: Vec) -> tuple[jax.Array, Vec]:
    """The squared distance from points ``p`` (box frame) to a box of half extents ``h``, and the closest point."""
    closest = tuple(jnp.clip(p[i], -h[i], h[i]) for i in range(3))
    return sum(jnp.square(p[i] - closest[i]) for i in range(3)), closest  # type: ignore[return-value]


def _segment_edge(r: Vec, u: Vec, uu: jax.Array, i: int, h: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The segment ``r + s u`` (``0 <= s <= 1``) against the axis-aligned segment ``t e_i`` (``|t| <= h``).

    Ericson's clamped least squares (as :func:`diffkin.collision._closest.segment_segment`),
    written for an edge along a coordinate axis.

    Returns:
        The squared distance and the closest parameters ``s`` and ``t``.
    """
    j, k = (i + 1) % 3, (i + 2) % 3
    perp = u[j] * u[j] + u[k] * u[k]  # |u|^2 - u_i^2, the denominator of the unclamped optimum
    s = jnp.clip(safe_div(-(r[j] * u[j] + r[k] * u[k]), perp), 0, 1)
    t = r[i] + s * u[i]
    clamped = jnp.clip(t, -h, h)
    s = jnp.where(t == clamped, s, jnp.clip(safe_div(clamped * u[i] - _dot(r, u), uu), 0, 1))
    w = [r[0] + s * u[0], r[1] + s * u[1], r[2] + s * u[2]]
    w[i] = w[i] - clamped
    return w[0] * w[0] + w[1] * w[1] + w[2] * w[2], s, clamped


def _support_edges(n: Vec, i: int, h: Vec) -> list[Vec]:
    """Midpoints of the edges along axis ``i`` of a box of half extents ``h`` that may be closest in direction ``n``.

    The edge whose normal cone holds ``n`` (``n_i = 0``): the signs of ``n_j`` and ``n_k``. The sign of
    the larger of the two is sure; the smaller one may be a tie (``n`` along a face normal, a face
    parallel to the other shape), so both edges on that side are returned.
    """
    j, k = (i + 1) % 3, (i + 2) % 3
    big_j = jnp.abs(n[j]) >= jnp.abs(n[k])
    sj, sk = _sign(n[j]) * h[j], _sign(n[k]) * h[k]
    zero = jnp.zeros_like(sj)
    out = []
    for side in (1, -1):
        mid = [zero, zero, zero]
        mid[j] = jnp.where(big_j, sj, side * h[j])
        mid[k] = jnp.where(big_j, side * h[k], sk)
        out.append(tuple(mid))
    return out


def _with(v: Vec, i: int, x: jax.Array) -> Vec:
    """``v`` with entry ``i`` replaced by ``x``."""
    return tuple(x if k == i else v[k] for k in range(3))  # type: ignore[return-value]


def _best(candidates: list, better: Callable) -> Any:
    """The candidate whose key (its first leaf) is ``better`` than the others', the first on ties.

    Chosen by selects, so its derivative is the chosen candidate's: the derivative of a chain of
    ``jnp.maximum`` compares the maximum with each operand, and XLA's CPU backend can round an
    operand differently in two fusions (seen: every weight zero, a zero derivative). Where only the
    key is used, XLA drops the rest.
    """
    best = candidates[0]
    for candidate in candidates[1:]:
        take = better(jax.tree.leaves(candidate)[0], jax.tree.leaves(best)[0])
        best = jax.tree.map(lambda new, old, take=take: jnp.where(take, new, old), candidate, best)
    return best


def _apart(closest: Callable, point_a: Callable, point_b: Callable) -> Callable:
    """The distance ``|x_b - x_a|`` of the closest points of two shapes, and its derivative.

    ``closest(a, b)`` gives the squared distance and a witness of the closest point on each shape
    (coordinates in the shape: a capsule's segment parameter, a box's local point in units of its
    half extents); ``point_a(a, witness)`` places it with the shape. The derivative is
    ``n . (dx_b - dx_a)``, ``n`` the unit vector between the closest points, each point moving with
    its shape (the witness held fixed): the envelope theorem, exact wherever the closest points are
    unique. It is a few products, so a gradient compiles quickly, whereas the derivative of every
    candidate compiles for minutes.
    """

    @jax.custom_jvp
    def distance(a, b):
        return _sqrt(closest(a, b)[0])

    @distance.defjvp
    def distance_jvp(primals, tangents):
        sq, wa, wb = closest(*primals)
        gap, dgap = jax.jvp(lambda a, b: _sub(point_b(b, wb), point_a(a, wa)), primals, tangents)
        length = _sqrt(_dot(gap, gap))
        n = tuple(safe_div(g, length) for g in gap)
        return _sqrt(sq), _dot(n, dgap)

    return distance


def _in_units(local: Vec, h: Vec) -> Vec:
    """A box's local point in units of its half extents (``[-1, 1]`` each; 0 along a flat axis)."""
    return tuple(safe_div(local[k], h[k]) for k in range(3))  # type: ignore[return-value]


def _box_point(box: Box, units: Vec) -> Vec:
    """The point ``units`` (:func:`_in_units`) of ``box``, moving with its pose and its half extents."""
    h = _vec(box.half_extents)
    axes = _rotation(box.pose)
    return tuple(box.pose[..., i, 3] + sum(axes[k][i] * h[k] * units[k] for k in range(3)) for i in range(3))  # type: ignore[return-value]


def _capsule_point(capsule: Capsule, t: jax.Array) -> Vec:
    """The point ``a + t (b - a)`` of the capsule's segment."""
    return tuple(capsule.a[..., i] + t * (capsule.b[..., i] - capsule.a[..., i]) for i in range(3))  # type: ignore[return-value]


# ---------------------------------------------------------------------------------- capsule-box


def _segment_in_box(a: Capsule, b: Box) -> tuple[Vec, Vec, Vec, Vec]:
    """In the box frame: the capsule's end points ``p``, ``q``, its direction ``u = q - p``; the half extents."""
    axes = _rotation(b.pose)
    c = _vec(b.pose[..., :3, 3])
    p, q = _to_frame(axes, _sub(_vec(a.a), c)), _to_frame(axes, _sub(_vec(a.b), c))
    return p, q, _sub(q, p), _vec(b.half_extents)


def _segment_box_separation(a: Capsule, b: Box) -> jax.Array:
    """The largest separation along the box's axes and ``e_i x u``."""
    p, q, u, h = _segment_in_box(a, b)
    mid = tuple(0.5 * (p[i] + q[i]) for i in range(3))
    seps = [jnp.abs(mid[i]) - 0.5 * jnp.abs(u[i]) - h[i] for i in range(3)]
    for i in range(3):
        n, ok = _unit(_cross_axis(i, u))
        sep = jnp.abs(_dot(n, mid)) - sum(jnp.abs(n[m]) * h[m] for m in range(3))
        seps.append(jnp.where(ok, sep, -jnp.inf))
    return _best(seps, jnp.greater)


def _segment_box_closest(a: Capsule, b: Box):
    """The closest points of the segment and the box when apart: the parameter ``t`` on the segment, the box's point.

    Candidates: an end point and the box, a box corner and the segment, or the segment and a box
    edge along a common normal ``e_i x u`` (the box's support edges in that direction).
    """
    p, q, u, h = _segment_in_box(a, b)
    mid = tuple(0.5 * (p[i] + q[i]) for i in range(3))
    uu = _dot(u, u)
    (sq_p, on_p), (sq_q, on_q) = _clamp(p, h), _clamp(q, h)
    candidates = [(sq_p, jnp.zeros_like(uu), on_p), (sq_q, jnp.ones_like(uu), on_q)]
    for signs in itertools.product((-1, 1), repeat=3):
        corner = tuple(signs[m] * h[m] for m in range(3))
        pv = _sub(p, corner)
        t = jnp.clip(safe_div(-_dot(pv, u), uu), 0, 1)
        candidates.append((sum(jnp.square(pv[m] + t * u[m]) for m in range(3)), t, corner))
    for i in range(3):
        n, _ = _unit(_cross_axis(i, u))
        towards = _sign(_dot(n, mid))
        for edge in _support_edges(tuple(towards * n[m] for m in range(3)), i, h):
            sq, s, t = _segment_edge(_sub(p, edge), u, uu, i, h[i])
            candidates.append((sq, s, _with(edge, i, t)))
    sq, t, on_box = _best(candidates, jnp.less)
    return sq, t, _in_units(on_box, h)


_segment_box_apart = _apart(_segment_box_closest, _capsule_point, _box_point)


def capsule_box(a: Capsule, b: Box) -> jax.Array:
    """Segment against box in the box frame (see the module docstring), minus the capsule's radius."""
    sat = _segment_box_separation(a, b)
    return jnp.where(sat > 0, _segment_box_apart(a, b), sat) - a.radius


# ---------------------------------------------------------------------------------- box-box


def _relative(a: Box, b: Box) -> tuple[Vec, Vec, tuple[Vec, Vec, Vec], Vec]:
    """Half extents of ``a`` and ``b``, ``b``'s axes and centre in the frame of ``a``."""
    axes_a = _rotation(a.pose)
    cols = tuple(_to_frame(axes_a, col) for col in _rotation(b.pose))
    c = _to_frame(axes_a, _sub(_vec(b.pose[..., :3, 3]), _vec(a.pose[..., :3, 3])))
    return _vec(a.half_extents), _vec(b.half_extents), cols, c  # type: ignore[return-value]


def _box_box_separation(a: Box, b: Box) -> jax.Array:
    """The largest separation along the axes ``e_i``, ``b_m`` and ``e_i x b_m`` (frame of ``a``)."""
    ha, hb, cols, c = _relative(a, b)
    cb = _to_frame(cols, c)  # b's centre in b's frame
    absR = [[jnp.abs(cols[m][i]) for m in range(3)] for i in range(3)]  # |e_i . b_m|
    seps = [jnp.abs(c[i]) - ha[i] - sum(absR[i][m] * hb[m] for m in range(3)) for i in range(3)]
    seps += [jnp.abs(cb[m]) - sum(absR[i][m] * ha[i] for i in range(3)) - hb[m] for m in range(3)]
    for i, m in itertools.product(range(3), repeat=2):
        n, ok = _unit(_cross_axis(i, cols[m]))
        rb = sum(jnp.abs(_dot(n, cols[k])) * hb[k] for k in range(3))
        sep = jnp.abs(_dot(n, c)) - sum(jnp.abs(n[k]) * ha[k] for k in range(3)) - rb
        seps.append(jnp.where(ok, sep, -jnp.inf))
    return _best(seps, jnp.greater)


def _box_box_closest(a: Box, b: Box):
    """The closest points of two boxes when apart, each in units of its box (:func:`_in_units`).

    Candidates: a corner of one and the other box, or an edge of each along a common normal
    ``e_i x b_m`` (the support edges of ``a`` towards ``b`` and of ``b`` towards ``a``).
    """
    ha, hb, cols, c = _relative(a, b)
    cb = _to_frame(cols, c)
    g = [tuple(hb[m] * cols[m][k] for k in range(3)) for m in range(3)]  # b's half axes in a's frame
    candidates = []
    for s in itertools.product((-1, 1), repeat=3):
        corner_b = tuple(c[k] + s[0] * g[0][k] + s[1] * g[1][k] + s[2] * g[2][k] for k in range(3))
        candidates.append((*_clamp(corner_b, ha), tuple(s[m] * hb[m] for m in range(3))))
        corner_a = tuple(sum(s[i] * ha[i] * cols[m][i] for i in range(3)) - cb[m] for m in range(3))  # in b's frame
        sq, on_b = _clamp(corner_a, hb)
        candidates.append((sq, tuple(s[i] * ha[i] for i in range(3)), on_b))
    for i, m in itertools.product(range(3), repeat=2):
        n, _ = _unit(_cross_axis(i, cols[m]))
        n = tuple(_sign(_dot(n, c)) * n[k] for k in range(3))  # from a towards b
        n_b = tuple(-_dot(cols[k], n) for k in range(3))  # from b towards a, in b's frame (n_b[m] = 0)
        u = tuple(2 * g[m][k] for k in range(3))
        uu = 4 * hb[m] * hb[m]
        for edge_a in _support_edges(n, i, ha):
            for edge_b in _support_edges(n_b, m, hb):
                # b's edge from its start point (in a's frame), relative to a's edge midpoint
                start = tuple(
                    c[k] + sum(edge_b[l] * cols[l][k] for l in range(3) if l != m) - g[m][k] - edge_a[k]
                    for k in range(3)
                )
                sq, s, t = _segment_edge(start, u, uu, i, ha[i])
                candidates.append((sq, _with(edge_a, i, t), _with(edge_b, m, (2 * s - 1) * hb[m])))
    sq, on_a, on_b = _best(candidates, jnp.less)
    return sq, _in_units(on_a, ha), _in_units(on_b, hb)


_box_box_apart = _apart(_box_box_closest, _box_point, _box_point)


def box_box(a: Box, b: Box) -> jax.Array:
    """Box against box in the frame of ``a`` (see the module docstring)."""
    sat = _box_box_separation(a, b)
    return jnp.where(sat > 0, _box_box_apart(a, b), sat)
