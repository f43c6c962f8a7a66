"""Box-box and capsule-box signed distances, from the closest-feature candidates.

A box and a segment (or a box) have a zonotope as Minkowski difference, whose facet normals are
the box axes and the cross products of the generators.

- Overlapping: the separating-axis test over exactly those axes gives the depth (the largest
  separation, which is negative). Its derivative is that of the winning axis' expression.
- Apart: the distance between two convex sets is attained vertex-to-solid or edge-to-edge, and an
  edge pair can only be closest along its common normal ``e_i x b_m``: the candidates are the
  corners of each shape against the other, and per axis pair the support edge of each shape along
  that normal (one each: :func:`_support_edge` settles ties), and for boxes the face separation
  where two parallel faces overlap (:func:`_faces_apart`). Every candidate is a distance between a
  point of each shape (or, for parallel faces, equal to one), so the smallest is the distance. Its
  derivative comes from the closest points (:func:`_gap`), not from differentiating the candidates.

Vectors in structure of arrays (:mod:`diffkin.collision._closest`).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from diffkin._xla import inverse_sqrt, materialize
from diffkin.collision._closest import (
    Vec,
    dot,
    lerp,
    norm,
    point_box,
    rotation,
    safe_div,
    segment_params,
    sqrt0,
    sub,
    to_frame,
    vec,
)
from diffkin.collision._shapes import Box, Capsule, Sphere


def _sign(x: jax.Array) -> jax.Array:
    """``+1`` where ``x >= 0``, else ``-1`` (never 0: a tie picks a side)."""
    return jnp.where(x >= 0, 1, -1).astype(x.dtype)


def _unit(v: Vec) -> tuple[Vec, jax.Array]:
    """``v / |v|`` and a mask of the axes in use (``|v|`` not vanishingly small)."""
    sq = dot(v, v)
    ok = sq > jnp.sqrt(jnp.finfo(sq.dtype).tiny)
    inv = inverse_sqrt(jnp.where(ok, sq, 1))
    return (v[0] * inv, v[1] * inv, v[2] * inv), ok


def _cross_axis(i: int, v: Vec) -> Vec:
    """``e_i x v``."""
    zero = jnp.zeros_like(v[0])
    if i == 0:
        return (zero, -v[2], v[1])
    if i == 1:
        return (v[2], zero, -v[0])
    return (-v[1], v[0], zero)


def _cross(u: Vec, v: Vec) -> Vec:
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _axis(i: jax.Array, dtype) -> Vec:
    """``e_i`` for an array of axis numbers ``i``."""
    return tuple((i == k).astype(dtype) for k in range(3))  # type: ignore[return-value]


def _clamp(p: Vec, h: Vec) -> tuple[jax.Array, Vec]:
    """The squared distance from points ``p`` (box frame) to a box of half extents ``h``, and the closest point."""
    closest = tuple(jnp.clip(p[i], -h[i], h[i]) for i in range(3))
    return sum(jnp.square(p[i] - closest[i]) for i in range(3)), closest  # type: ignore[return-value]


def _inverse(x: jax.Array) -> jax.Array:
    """``1 / x`` where ``x > 0``, else 0: a division shared by several candidates becomes products."""
    ok = x > 0
    return jnp.where(ok, 1 / jnp.where(ok, x, 1), 0)


def _segment_edge(r: Vec, u: Vec, inv_uu: jax.Array, i: int, h: jax.Array) -> jax.Array:
    """The squared distance between the segment ``r + s u`` (``0 <= s <= 1``) and the axis-aligned segment
    ``t e_i`` (``|t| <= h``): Ericson's clamped least squares (:func:`diffkin.collision._closest.segment_params`),
    written for an edge along a coordinate axis. ``inv_uu``: :func:`_inverse` of ``|u|^2``."""
    j, k = (i + 1) % 3, (i + 2) % 3
    inv_perp = _inverse(u[j] * u[j] + u[k] * u[k])  # |u|^2 - u_i^2, the denominator of the unclamped optimum
    s = jnp.clip(-(r[j] * u[j] + r[k] * u[k]) * inv_perp, 0, 1)
    t = r[i] + s * u[i]
    clamped = jnp.clip(t, -h, h)
    s = jnp.where(t == clamped, s, jnp.clip((clamped * u[i] - dot(r, u)) * inv_uu, 0, 1))
    w = [r[0] + s * u[0], r[1] + s * u[1], r[2] + s * u[2]]
    w[i] = w[i] - clamped
    return w[0] * w[0] + w[1] * w[1] + w[2] * w[2]


#: A component of a common normal at most this many machine epsilons of its larger partner is a
#: tie (a face parallel to the other shape's edge): rounding decides its sign, so the other rule of
#: :func:`_support_edge` does.
TIE = 8


def _support_edge(n: Vec, i: int, h: Vec, other: Vec | None = None) -> Vec:
    """The midpoint of the edge along axis ``i`` of a box of half extents ``h`` closest along ``n`` (``n_i = 0``).

    The edge whose normal cone holds ``n``: the signs of ``n_j`` and ``n_k``. Where the smaller of the two
    is a tie (:data:`TIE`: ``n`` along a face normal), the face holds two such edges, and the one on
    the side of ``other`` (the other shape's edge's midpoint, this box's frame) is taken.

    Why that edge is enough: the closest points of two convex shapes apart are vertex-to-solid (the
    corner candidates) or lie on two edges along their common normal (this candidate). At a tie the
    face of this box is parallel to the other shape's edge (or face), and the closest pairs are where
    that edge crosses the face's border in projection. If it crosses two opposite sides, either edge
    serves. If it cuts a corner, crossing the side along ``e_i`` at ``k = s`` and the side along ``e_k``
    at ``i = s'``, then the edge's midpoint ``M`` has ``sign M_k = s`` or ``sign M_i = s'`` (a point of
    the cut between the crossings is a mean of them, whose two coordinates cannot both fall short;
    beyond them one coordinate is past the face), so the candidate of axis ``i`` or that of axis ``k``
    is a closest pair. A tie on both sides (two parallel faces) has no sure choice of edges (two
    squares crossing as an octagon): the face-face candidate covers it (:func:`_faces_apart`). Near a
    tie the candidate differs from the distance by at most ``2 h_k |n_k| / |n|``.
    """
    j, k = (i + 1) % 3, (i + 2) % 3
    big_j = jnp.abs(n[j]) >= jnp.abs(n[k])
    mid = [jnp.zeros_like(n[j])] * 3
    if other is None:
        mid[j], mid[k] = _sign(n[j]) * h[j], _sign(n[k]) * h[k]
        return tuple(mid)
    tie = jnp.minimum(jnp.abs(n[j]), jnp.abs(n[k])) <= TIE * jnp.finfo(n[j].dtype).eps * jnp.maximum(
        jnp.abs(n[j]), jnp.abs(n[k])
    )
    mid[j] = jnp.where(tie & ~big_j, _sign(other[j]), _sign(n[j])) * h[j]
    mid[k] = jnp.where(tie & big_j, _sign(other[k]), _sign(n[k])) * h[k]
    return tuple(mid)


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


# Candidates are numbered, so that the nearest is one integer (its code) and its closest points are
# computed afterwards from it alone. A corner is numbered by its signs, an edge of a box by its
# axis and the signs of its other two coordinates (the 12 edges).


def _corner_code(signs: tuple[int, ...]) -> int:
    return 4 * (signs[0] > 0) + 2 * (signs[1] > 0) + (signs[2] > 0)


def _corner(code: jax.Array, dtype) -> Vec:
    """The corner of number ``code`` (:func:`_corner_code`) in units of the half extents."""
    return tuple((2 * ((code >> (2 - k)) & 1) - 1).astype(dtype) for k in range(3))  # type: ignore[return-value]


def _edge_code(mid: Vec, i: int) -> jax.Array:
    """The number (0 to 11) of the edge along axis ``i`` of midpoint ``mid``."""
    j, k = (i + 1) % 3, (i + 2) % 3
    return 4 * i + 2 * (mid[j] > 0) + (mid[k] > 0)


def _edge(code: jax.Array, dtype) -> tuple[Vec, Vec]:
    """The end points of the edge of number ``code`` (:func:`_edge_code`) in units of the half extents."""
    i, sj, sk = code // 4, 2 * ((code >> 1) & 1) - 1, 2 * (code & 1) - 1
    ends = []
    for end in (-1, 1):
        # coordinate c is the edge's axis (i = c), its j = i + 1 (i = c - 1) or its k = i + 2 (i = c + 1)
        ends.append(tuple(jnp.where(i == c, end, jnp.where(i == (c + 2) % 3, sj, sk)).astype(dtype) for c in range(3)))
    return ends[0], ends[1]


def _scale(v: Vec, h: Vec) -> Vec:
    return (v[0] * h[0], v[1] * h[1], v[2] * h[2])


def _where(condition: jax.Array, x, y):
    return jax.tree.map(lambda x, y: jnp.where(condition, x, y), x, y)


def _chosen(candidates: Callable, expression: Callable) -> Callable:
    """``f(a, b)``: the best of ``candidates(a, b) -> (value, code of the best)``, with the derivative
    of ``expression(a, b, code)``, a function of the two shapes whose value is the chosen candidate's.

    Only the chosen candidate is differentiated, so a gradient compiles in seconds where the
    derivative of every candidate compiled for minutes; and the code is computed once
    (:func:`diffkin._xla.materialize`), or XLA recomputes the candidates in every consumer.
    """

    @jax.custom_jvp
    def f(a, b):
        return candidates(a, b)[0]

    @f.defjvp
    def f_jvp(primals, tangents):
        code = materialize([candidates(*primals)[1]])[0]
        return jax.jvp(expression(*primals, code), primals, tangents)

    return f


def _gap(witness: Callable, point_a: Callable, point_b: Callable) -> Callable:
    """The distance ``|x_b - x_a|`` of the closest points of candidate ``code``, each moving with its shape.

    ``witness(a, b, code)`` locates the closest point on each shape (coordinates in the shape: a
    capsule's segment parameter, a box's local point in units of its half extents), which is then
    held fixed: the derivative is ``n . (dx_b - dx_a)``, ``n`` the unit vector between the closest
    points (the envelope theorem, exact wherever the closest points are unique).
    """

    def expression(a, b, code):
        leaves, tree = jax.tree.flatten(witness(a, b, code))
        wa, wb = jax.tree.unflatten(tree, list(materialize(leaves)))  # computed once, as the code
        return lambda a, b: norm(sub(point_b(b, wb), point_a(a, wa)))

    return expression


def _in_units(local: Vec, h: Vec) -> Vec:
    """A box's local point in units of its half extents (``[-1, 1]`` each; 0 along a flat axis)."""
    return tuple(safe_div(local[k], h[k]) for k in range(3))  # type: ignore[return-value]


def _box_point(box: Box, units: Vec) -> Vec:
    """The point ``units`` (:func:`_in_units`) of ``box``, moving with its pose and its half extents."""
    h = vec(box.half_extents)
    axes = rotation(box.pose)
    return tuple(box.pose[..., i, 3] + sum(axes[k][i] * h[k] * units[k] for k in range(3)) for i in range(3))  # type: ignore[return-value]


def _capsule_point(capsule: Capsule, t: jax.Array) -> Vec:
    """The point ``a + t (b - a)`` of the capsule's segment."""
    return lerp(vec(capsule.a), vec(capsule.b), t)


# ---------------------------------------------------------------------------------- capsule-box


def _segment_in_box(a: Capsule, b: Box) -> tuple[Vec, Vec, Vec, Vec]:
    """In the box frame: the capsule's end points ``p``, ``q``, its direction ``u = q - p``; the half extents."""
    axes = rotation(b.pose)
    c = vec(b.pose[..., :3, 3])
    p, q = to_frame(axes, sub(vec(a.a), c)), to_frame(axes, sub(vec(a.b), c))
    return p, q, sub(q, p), vec(b.half_extents)


def _segment_face_separations(mid: Vec, u: Vec, h: Vec) -> list[jax.Array]:
    """The separations of a segment (midpoint ``mid``, direction ``u``, box frame) and a box of half
    extents ``h`` along the box's axes ``e_i``."""
    return [jnp.abs(mid[i]) - 0.5 * jnp.abs(u[i]) - h[i] for i in range(3)]


def _segment_box_separations(a: Capsule, b: Box) -> tuple[jax.Array, jax.Array]:
    """The largest separation along the box's axes ``e_i`` (code ``i``) and ``e_i x u`` (``3 + i``), and its code."""
    p, q, u, h = _segment_in_box(a, b)
    mid = tuple(0.5 * (p[i] + q[i]) for i in range(3))
    seps = [(sep, i) for i, sep in enumerate(_segment_face_separations(mid, u, h))]
    for i in range(3):
        n, ok = _unit(_cross_axis(i, u))
        sep = jnp.abs(dot(n, mid)) - sum(jnp.abs(n[m]) * h[m] for m in range(3))
        seps.append((jnp.where(ok, sep, -jnp.inf), 3 + i))
    return _best(seps, jnp.greater)


def _segment_box_axis(a: Capsule, b: Box, code: jax.Array) -> Callable:
    """The separation along axis ``code`` (:func:`_segment_box_separations`) as a function of the shapes."""
    e = _axis(code % 3, a.radius.dtype)

    def separation(a, b):
        p, q, u, h = _segment_in_box(a, b)
        mid = tuple(0.5 * (p[i] + q[i]) for i in range(3))
        n = _unit(_where(code < 3, e, _cross(e, u)))[0]
        return jnp.abs(dot(n, mid)) - 0.5 * jnp.abs(dot(n, u)) - sum(jnp.abs(n[m]) * h[m] for m in range(3))

    return separation


_segment_box_separation = _chosen(_segment_box_separations, _segment_box_axis)


def _segment_box_closest(a: Capsule, b: Box) -> tuple[jax.Array, jax.Array]:
    """The distance of the segment and the box when apart, and the code of the nearest candidate.

    Candidates: an end point and the box (codes 0, 1), a box corner and the segment (2 + the
    corner's), or the segment and a box edge along a common normal ``e_i x u`` (the box's support
    edge in that direction, :func:`_support_edge`; 10 + the edge's).
    """
    p, q, u, h = _segment_in_box(a, b)
    mid = tuple(0.5 * (p[i] + q[i]) for i in range(3))
    inv_uu = _inverse(dot(u, u))
    candidates: list[tuple[Any, Any]] = [(_clamp(p, h)[0], 0), (_clamp(q, h)[0], 1)]
    for signs in itertools.product((-1, 1), repeat=3):
        pv = sub(p, tuple(signs[m] * h[m] for m in range(3)))
        t = jnp.clip(-dot(pv, u) * inv_uu, 0, 1)
        candidates.append((sum(jnp.square(pv[m] + t * u[m]) for m in range(3)), 2 + _corner_code(signs)))
    for i in range(3):
        n = _cross_axis(i, u)  # (only its direction matters: no need to normalise)
        towards = _sign(dot(n, mid))
        edge = _support_edge(tuple(towards * n[m] for m in range(3)), i, h, mid)
        candidates.append((_segment_edge(sub(p, edge), u, inv_uu, i, h[i]), 10 + _edge_code(edge, i)))
    sq, code = _best(candidates, jnp.less)
    return sqrt0(sq), code


def _segment_box_witness(a: Capsule, b: Box, code: jax.Array) -> tuple[jax.Array, Vec]:
    """The closest points of candidate ``code`` (:func:`_segment_box_closest`): ``t`` on the segment, the box's."""
    p, q, u, h = _segment_in_box(a, b)
    dtype = u[0].dtype
    end = _where(code == 0, p, q)
    on_box = _clamp(end, h)[1]
    corner = _corner(code - 2, dtype)
    feature = _where(code < 10, (corner, corner), _edge(code - 10, dtype))  # a corner or an edge, in units
    t, s = segment_params(p, q, _scale(feature[0], h), _scale(feature[1], h))
    ends = code < 2
    return jnp.where(ends, code.astype(dtype), t), _where(ends, _in_units(on_box, h), lerp(feature[0], feature[1], s))


_segment_box_apart = _chosen(_segment_box_closest, _gap(_segment_box_witness, _capsule_point, _box_point))


def capsule_box_bound(a: Capsule, b: Box) -> jax.Array:
    """A lower bound of :func:`capsule_box`: the largest separation along the box's face axes (a few
    operations: the projection on any axis separates no more than the distance or the depth)."""
    p, q, u, h = _segment_in_box(a, b)
    seps = _segment_face_separations(tuple(0.5 * (p[i] + q[i]) for i in range(3)), u, h)
    return jnp.maximum(jnp.maximum(seps[0], seps[1]), seps[2]) - a.radius


def capsule_box(a: Capsule, b: Box) -> jax.Array:
    """Segment against box in the box frame (see the module docstring), minus the capsule's radius."""
    sat = _segment_box_separation(a, b)
    return jnp.where(sat > 0, _segment_box_apart(a, b), sat) - a.radius


# ---------------------------------------------------------------------------------- box-box


def _relative(a: Box, b: Box) -> tuple[Vec, Vec, tuple[Vec, Vec, Vec], Vec]:
    """Half extents of ``a`` and ``b``, ``b``'s axes and centre in the frame of ``a``."""
    axes_a = rotation(a.pose)
    cols = tuple(to_frame(axes_a, col) for col in rotation(b.pose))
    c = to_frame(axes_a, sub(vec(b.pose[..., :3, 3]), vec(a.pose[..., :3, 3])))
    return vec(a.half_extents), vec(b.half_extents), cols, c  # type: ignore[return-value]


def _box_face_separations(ha: Vec, hb: Vec, cols: tuple[Vec, Vec, Vec], c: Vec) -> list[jax.Array]:
    """The separations of two boxes (:func:`_relative`) along ``a``'s axes ``e_i``, then ``b``'s ``b_m``."""
    cb = to_frame(cols, c)  # b's centre in b's frame
    absR = [[jnp.abs(cols[m][i]) for m in range(3)] for i in range(3)]  # |e_i . b_m|
    seps = [jnp.abs(c[i]) - ha[i] - sum(absR[i][m] * hb[m] for m in range(3)) for i in range(3)]
    return seps + [jnp.abs(cb[m]) - sum(absR[i][m] * ha[i] for i in range(3)) - hb[m] for m in range(3)]


def _box_box_separations(a: Box, b: Box) -> tuple[jax.Array, jax.Array]:
    """The largest separation along the axes ``e_i`` (code ``i``), ``b_m`` (``3 + m``) and ``e_i x b_m``
    (``6 + 3 i + m``) (frame of ``a``), and its code."""
    ha, hb, cols, c = _relative(a, b)
    seps = [(sep, k) for k, sep in enumerate(_box_face_separations(ha, hb, cols, c))]
    for i, m in itertools.product(range(3), repeat=2):
        n, ok = _unit(_cross_axis(i, cols[m]))
        rb = sum(jnp.abs(dot(n, cols[k])) * hb[k] for k in range(3))
        sep = jnp.abs(dot(n, c)) - sum(jnp.abs(n[k]) * ha[k] for k in range(3)) - rb
        seps.append((jnp.where(ok, sep, -jnp.inf), 6 + 3 * i + m))
    return _best(seps, jnp.greater)


def _box_box_axis(a: Box, b: Box, code: jax.Array) -> Callable:
    """The separation along axis ``code`` (:func:`_box_box_separations`) as a function of the boxes."""
    e = _axis(jnp.where(code < 6, code, (code - 6) // 3), a.pose.dtype)
    m = jnp.where(code < 6, code - 3, (code - 6) % 3)

    def separation(a, b):
        ha, hb, cols, c = _relative(a, b)
        b_m = _where(m == 0, cols[0], _where(m == 1, cols[1], cols[2]))
        n = _unit(_where(code < 3, e, _where(code < 6, b_m, _cross(e, b_m))))[0]
        rb = sum(jnp.abs(dot(n, cols[k])) * hb[k] for k in range(3))
        return jnp.abs(dot(n, c)) - sum(jnp.abs(n[k]) * ha[k] for k in range(3)) - rb

    return separation


_box_box_separation = _chosen(_box_box_separations, _box_box_axis)


def _box_box_closest(a: Box, b: Box) -> tuple[jax.Array, jax.Array]:
    """The distance of two boxes when apart, and the code of the nearest candidate.

    Candidates: a corner of ``b`` and box ``a`` (twice the corner's code), a corner of ``a`` and box
    ``b`` (one more), an edge of each along a common normal ``e_i x b_m``: the support edge of ``a``
    towards ``b`` and of ``b`` towards ``a`` (16 + 12 ``a``'s edge's + ``b``'s), or two parallel faces
    that overlap (:func:`_faces_apart`).
    """
    ha, hb, cols, c = _relative(a, b)
    g = [tuple(hb[m] * cols[m][k] for k in range(3)) for m in range(3)]  # b's half axes in a's frame
    candidates = _corners(ha, hb, cols, c)
    for i, m in itertools.product(range(3), repeat=2):
        n = _cross_axis(i, cols[m])  # (only its direction matters: no need to normalise)
        n = tuple(_sign(dot(n, c)) * n[k] for k in range(3))  # from a towards b
        n_b = tuple(-dot(cols[k], n) for k in range(3))  # from b towards a, in b's frame (n_b[m] = 0)
        u = tuple(2 * g[m][k] for k in range(3))
        inv_uu = _inverse(4 * hb[m] * hb[m])

        def in_a(edge_b, m=m):  # b's edge midpoint (b's frame, its axis m zero) in a's frame
            return tuple(c[k] + sum(edge_b[l] * cols[l][k] for l in range(3) if l != m) for k in range(3))

        mid_a, mid_b = _support_edge(n, i, ha), _support_edge(n_b, m, hb)  # by the signs alone, for ties
        edge_a = _support_edge(n, i, ha, in_a(mid_b))
        edge_b = _support_edge(n_b, m, hb, to_frame(cols, sub(mid_a, c)))
        start = tuple(in_a(edge_b)[k] - g[m][k] - edge_a[k] for k in range(3))  # b's edge start, from a's edge midpoint
        code = 16 + 12 * _edge_code(edge_a, i) + _edge_code(edge_b, m)
        candidates.append((_segment_edge(start, u, inv_uu, i, ha[i]), code))
    candidates += _faces_apart(cols, _box_face_separations(ha, hb, cols, c))
    sq, code = _best(candidates, jnp.less)
    return sqrt0(sq), code


def _corners(ha: Vec, hb: Vec, cols: tuple[Vec, Vec, Vec], c: Vec) -> list[tuple[jax.Array, jax.Array | int]]:
    """The corner candidates of :func:`_box_box_closest` (boxes as :func:`_relative`): squared distances and codes."""
    cb = to_frame(cols, c)
    out: list[tuple[jax.Array, jax.Array | int]] = []
    for s in itertools.product((-1, 1), repeat=3):
        corner_b = tuple(c[k] + sum(s[m] * hb[m] * cols[m][k] for m in range(3)) for k in range(3))
        out.append((_clamp(corner_b, ha)[0], 2 * _corner_code(s)))
        corner_a = tuple(sum(s[i] * ha[i] * cols[m][i] for i in range(3)) - cb[m] for m in range(3))  # in b's frame
        out.append((_clamp(corner_a, hb)[0], 2 * _corner_code(s) + 1))
    return out


#: The first code of the face-face candidates of :func:`_box_box_closest` (after the 16 corners and 144 edge pairs).
_FACES = 16 + 144


def _faces_apart(cols: tuple[Vec, Vec, Vec], seps: list[jax.Array]) -> list[tuple[jax.Array, jax.Array | int]]:
    """The face-face candidates of two boxes: code ``_FACES + 3 j + l`` (``cols``: ``b``'s axes in ``a``'s
    frame; ``seps``: :func:`_box_face_separations`).

    Where ``a``'s face ``j`` is parallel to ``b``'s face ``l`` (within :data:`TIE`) and the two faces
    overlap seen along their normal (the separations along the other four face axes, the faces'
    edge normals, are not positive: the separating-axis test in their plane), the distance is the
    separation along ``e_j``. This is the case that :func:`_support_edge` leaves: both edges of a
    pair on parallel faces, where the closest pairs are crossings of the faces' borders. The
    squares are raised by a few roundings, so that a corner or edge candidate of the same value
    (whose closest points are unique) wins the tie.
    """
    eps = jnp.finfo(seps[0].dtype).eps
    out: list[tuple[jax.Array, jax.Array | int]] = []
    for j, l in itertools.product(range(3), repeat=2):
        off = [jnp.abs(cols[l][i]) for i in range(3) if i != j]  # b_l's tilt out of e_j
        parallel = jnp.maximum(off[0], off[1]) <= 4 * TIE * eps
        others = [seps[i] for i in range(3) if i != j] + [seps[3 + m] for m in range(3) if m != l]
        overlap = functools.reduce(jnp.maximum, others) <= 0
        sq = jnp.square(seps[j]) * (1 + TIE * eps)
        out.append((jnp.where(parallel & overlap, sq, jnp.inf), _FACES + 3 * j + l))
    return out


def _faces_closest(ha: Vec, hb: Vec, cols: tuple[Vec, Vec, Vec], c: Vec, code: jax.Array) -> jax.Array:
    """The corner or edge-pair code (:func:`_box_box_closest`) of a closest pair of the face-face candidate
    ``code``: the nearest of the corners and of the 16 pairs of an edge of each face (a corner of one
    face over the other, or two crossing borders)."""
    j, l = (code - _FACES) // 3, (code - _FACES) % 3
    dtype = c[0].dtype
    side_a = _sign(jnp.where(j == 0, c[0], jnp.where(j == 1, c[1], c[2])))  # a's face towards b
    cb = to_frame(cols, c)
    side_b = -_sign(jnp.where(l == 0, cb[0], jnp.where(l == 1, cb[1], cb[2])))  # b's face towards a

    def code_of(i, face, face_side, other_side):  # the edge along i of a face with normal axis ``face``
        positive = lambda axis: jnp.where(axis == face, face_side, other_side) > 0  # noqa: E731
        return 4 * i + 2 * positive((i + 1) % 3) + positive((i + 2) % 3)

    pairs = _corners(ha, hb, cols, c)
    for p, q, sa, sb in itertools.product((1, 2), (1, 2), (-1, 1), (-1, 1)):
        code_a, code_b = code_of((j + p) % 3, j, side_a, sa), code_of((l + q) % 3, l, side_b, sb)
        pairs.append((_edge_pair(ha, hb, cols, c, code_a, code_b, dtype)[0], 16 + 12 * code_a + code_b))
    return _best(pairs, jnp.less)[1]


def _edge_pair(ha: Vec, hb: Vec, cols, c: Vec, code_a: jax.Array, code_b: jax.Array, dtype):
    """The squared distance of ``a``'s edge ``code_a`` and ``b``'s ``code_b`` (:func:`_edge_code`), and the
    closest points, each in units of its box."""
    edge_a, edge_b = _edge(code_a, dtype), _edge(code_b, dtype)
    ends_b = [tuple(c[k] + sum(e[m] * hb[m] * cols[m][k] for m in range(3)) for k in range(3)) for e in edge_b]
    ends_a = [_scale(e, ha) for e in edge_a]
    s, t = segment_params(*ends_a, *ends_b)
    gap = sub(lerp(ends_b[0], ends_b[1], t), lerp(ends_a[0], ends_a[1], s))
    return dot(gap, gap), (lerp(edge_a[0], edge_a[1], s), lerp(edge_b[0], edge_b[1], t))


def _box_box_witness(a: Box, b: Box, code: jax.Array) -> tuple[Vec, Vec]:
    """The closest points of candidate ``code`` (:func:`_box_box_closest`), each in units of its box."""
    ha, hb, cols, c = _relative(a, b)
    dtype = c[0].dtype
    faces = code >= _FACES  # rare (exactly parallel faces): the search for their closest pair only when needed
    code = jax.lax.cond(
        jnp.any(faces), lambda: jnp.where(faces, _faces_closest(ha, hb, cols, c, code), code), lambda: code
    )
    corner = _corner(code // 2, dtype)
    in_a = tuple(c[k] + sum(corner[m] * hb[m] * cols[m][k] for m in range(3)) for k in range(3))  # b's corner
    in_b = to_frame(cols, sub(_scale(corner, ha), c))  # a's corner
    corner_b = (_in_units(_clamp(in_a, ha)[1], ha), corner)
    corner_a = (corner, _in_units(_clamp(in_b, hb)[1], hb))
    edges = _edge_pair(ha, hb, cols, c, (code - 16) // 12, (code - 16) % 12, dtype)[1]
    return _where(code < 16, _where(code % 2 == 0, corner_b, corner_a), edges)


_box_box_apart = _chosen(_box_box_closest, _gap(_box_box_witness, _box_point, _box_point))


def box_box_bound(a: Box, b: Box) -> jax.Array:
    """A lower bound of :func:`box_box`: the largest separation along the six face axes (as
    :func:`capsule_box_bound`)."""
    seps = _box_face_separations(*_relative(a, b))
    out = seps[0]
    for sep in seps[1:]:
        out = jnp.maximum(out, sep)
    return out


def box_box(a: Box, b: Box) -> jax.Array:
    """Box against box in the frame of ``a`` (see the module docstring)."""
    sat = _box_box_separation(a, b)
    return jnp.where(sat > 0, _box_box_apart(a, b), sat)


# ---------------------------------------------------------------------------------- contact lines


def _once(*value_codes: tuple[jax.Array, jax.Array]) -> list[tuple[jax.Array, jax.Array]]:
    """Values and integer codes of candidate searches, each computed once (:func:`diffkin._xla.materialize`:
    otherwise XLA copies the whole search into every consumer)."""
    values = materialize([v for v, _ in value_codes])
    codes = materialize([c for _, c in value_codes])
    return [(values[k], codes[k]) for k in range(len(value_codes))]


def _flat(tree) -> list:
    return jax.tree.leaves(tree)


def _halves(values: jax.Array) -> tuple[Vec, Vec]:
    """Six stacked coordinates as two vectors."""
    return tuple(values[:3]), tuple(values[3:])  # type: ignore[return-value]


def _pick(code: jax.Array, columns: tuple[Vec, Vec, Vec]) -> Vec:
    """The column ``code`` (0, 1 or 2, an array) of three vectors."""
    return _where(code == 0, columns[0], _where(code == 1, columns[1], columns[2]))


def _towards(n: Vec, direction: Vec) -> Vec:
    """``n`` flipped where it points away from ``direction``."""
    s = _sign(dot(n, direction))
    return (s * n[0], s * n[1], s * n[2])


def _support(centre: Vec, axes: tuple[Vec, Vec, Vec], h: Vec, n: Vec, sign: float, skip=None) -> Vec:
    """``centre + sign * sum_k sgn(n . axis_k) h_k axis_k`` (over ``k != skip``): the support point (or the
    support edge's midpoint) of a box in direction ``sign * n``; a tie (``n . axis_k = 0``) takes the
    middle of that face."""
    out = list(centre)
    for k in range(3):
        w = sign * jnp.sign(dot(n, axes[k])) * h[k]
        if skip is not None:
            w = jnp.where(skip == k, 0, w)
        out = [out[i] + w * axes[k][i] for i in range(3)]
    return tuple(out)


def _line_point(p: Vec, u: Vec, q: Vec, v: Vec) -> Vec:
    """The point of the line ``q + t v`` closest to the line ``p + s u`` (not parallel)."""
    w = sub(p, q)
    uu, uv, vv, uw, vw = dot(u, u), dot(u, v), dot(v, v), dot(u, w), dot(v, w)
    t = safe_div(uu * vw - uv * uw, uu * vv - uv * uv)
    return lerp(q, tuple(q[i] + v[i] for i in range(3)), t)


def _contact(apart: jax.Array, pa: Vec, pb: Vec, n_sat: Vec, p_sat: Vec) -> tuple[Vec, Vec]:
    """The unit normal (from ``a`` to ``b``) and a point of the contact line: apart, through the closest
    points ``pa``, ``pb`` (zero where they coincide); overlapping, the winning axis ``n_sat`` through ``p_sat``."""
    gap = sub(pb, pa)
    length = norm(gap)
    n_apart = tuple(safe_div(g, length) for g in gap)
    return _where(apart, n_apart, n_sat), _where(apart, pb, p_sat)


def sphere_box_contact(a: Sphere, b: Box) -> tuple[jax.Array, Vec, Vec]:
    """The signed distance of a sphere and a box with its contact line ``(d, n, p)`` (as
    :func:`capsule_box_contact`): apart, through the centre and its closest point of the box; inside,
    the nearest face's normal through the centre."""
    axes, c = rotation(b.pose), vec(b.pose[..., :3, 3])
    h, centre = vec(b.half_extents), vec(a.center)
    local = to_frame(axes, sub(centre, c))
    over = [jnp.abs(local[i]) - h[i] for i in range(3)]
    d = point_box(local, h) - a.radius
    face = jnp.where(over[0] >= jnp.maximum(over[1], over[2]), 0, jnp.where(over[1] >= over[2], 1, 2))
    axis = _pick(face, axes)
    side = -_sign(jnp.where(face == 0, local[0], jnp.where(face == 1, local[1], local[2])))  # into the box
    n_inside = (side * axis[0], side * axis[1], side * axis[2])
    closest = _box_point(b, _in_units(_clamp(local, h)[1], h))
    n, p = _contact(jnp.maximum(jnp.maximum(over[0], over[1]), over[2]) > 0, centre, closest, n_inside, centre)
    return d, n, p


def capsule_box_contact(a: Capsule, b: Box) -> tuple[jax.Array, Vec, Vec]:
    """:func:`capsule_box` with its contact line: ``(d, n, p)``, ``n`` the unit normal from ``a`` to ``b``
    and ``p`` a point of the line along ``n`` through the two witness points (world frame).

    Moving the shapes rigidly changes ``d`` by ``n . (v_b(p) - v_a(p))`` (``v(p)``: the velocity of the
    point ``p`` moving with that shape). Apart, the witness points are the closest points; overlapping,
    along the winning axis: a box face (which turns with the box) through the segment's support point,
    or ``e_i x u`` through the closest points of the box's support edge and the segment's line (the
    derivative of the axis is orthogonal to the line between them).
    """
    (sat, axis), (gap, code) = _once(_segment_box_separations(a, b), _segment_box_closest(a, b))
    apart = sat > 0
    t, *rest = materialize(_flat(_segment_box_witness(a, b, code)))
    units = tuple(rest)
    P, Q = vec(a.a), vec(a.b)
    u = sub(Q, P)
    mid = tuple(0.5 * (P[i] + Q[i]) for i in range(3))
    axes, c, h = rotation(b.pose), vec(b.pose[..., :3, 3]), vec(b.half_extents)
    e = _pick(axis % 3, axes)
    n = tuple(materialize(list(_towards(_where(axis < 3, e, _unit(_cross(e, u))[0]), sub(c, mid)))))
    face = lerp(mid, Q, jnp.sign(dot(n, u)))  # the segment's support point towards n
    edge = _line_point(P, u, _support(c, axes, h, n, -1.0, skip=axis % 3), e)
    n, p = _contact(apart, _capsule_point(a, t), _box_point(b, units), n, _where(axis < 3, face, edge))
    return jnp.where(apart, gap, sat) - a.radius, n, p


def box_box_contact(a: Box, b: Box) -> tuple[jax.Array, Vec, Vec]:
    """:func:`box_box` with its contact line ``(d, n, p)`` (as :func:`capsule_box_contact`): overlapping,
    a face of ``a`` through ``b``'s support point, a face of ``b`` through ``a``'s, or ``a_i x b_m`` through
    the closest points of the two support edges."""
    (sat, axis), (gap, code) = _once(_box_box_separations(a, b), _box_box_closest(a, b))
    apart = sat > 0
    wa, wb = _halves(materialize(_flat(_box_box_witness(a, b, code))))
    axes_a, c_a, h_a = rotation(a.pose), vec(a.pose[..., :3, 3]), vec(a.half_extents)
    axes_b, c_b, h_b = rotation(b.pose), vec(b.pose[..., :3, 3]), vec(b.half_extents)
    i = jnp.where(axis < 3, axis, (axis - 6) // 3)
    m = jnp.where(axis < 6, axis - 3, (axis - 6) % 3)
    e_a, e_b = _pick(i, axes_a), _pick(m, axes_b)
    n = _where(axis < 3, e_a, _where(axis < 6, e_b, _unit(_cross(e_a, e_b))[0]))
    n = tuple(materialize(list(_towards(n, sub(c_b, c_a)))))
    on_b = _support(c_b, axes_b, h_b, n, -1.0)  # b's support point towards -n
    on_a = _support(c_a, axes_a, h_a, n, 1.0)
    edge_a = _support(c_a, axes_a, h_a, n, 1.0, skip=i)  # the support edges' midpoints
    edge = _line_point(edge_a, e_a, _support(c_b, axes_b, h_b, n, -1.0, skip=m), e_b)
    p_sat = _where(axis < 3, on_b, _where(axis < 6, on_a, edge))
    n, p = _contact(apart, _box_point(a, wa), _box_point(b, wb), n, p_sat)
    return jnp.where(apart, gap, sat), n, p
