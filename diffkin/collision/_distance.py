"""Signed distances between primitives: positive apart, minus the penetration depth when overlapping.

The penetration depth is the length of the shortest translation that separates the shapes. Each
pair is computed exactly (to rounding):

- Spheres and capsules are points and segments swept by a ball, so their signed distance is the
  distance between the points/segments minus the radii (the Minkowski difference of two segments
  is flat, so this holds inside as well as outside).
- A half-space against a convex shape: the lowest point of the shape along the normal.
- Boxes: a box and a segment (or a box) have a zonotope as Minkowski difference, whose facet
  normals are the box axes and the cross products of the generators. Overlapping: the
  separating-axis test over exactly those axes gives the depth (the largest separation, which is
  negative). Apart: the distance between the two convex sets is attained vertex-to-solid or
  edge-to-edge, so it is the smallest of the corner-to-box distances and the edge-to-edge segment
  distances (computed in the first box's frame).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from diffkin.collision import _closest as cl
from diffkin.collision._shapes import SHAPES, Box, Capsule, Plane, Sphere


def _local(box: Box, p: jax.Array) -> jax.Array:
    """Points ``p (..., 3)`` in the frame of ``box``: ``R^T (p - c)``."""
    R, c = box.pose[..., :3, :3], box.pose[..., :3, 3]
    return jnp.einsum("...ji,...j->...i", R, p - c)


def sphere_sphere(a: Sphere, b: Sphere) -> jax.Array:
    return cl.norm(a.center - b.center) - a.radius - b.radius


def sphere_capsule(a: Sphere, b: Capsule) -> jax.Array:
    return cl.point_segment(a.center, b.a, b.b) - a.radius - b.radius


def capsule_capsule(a: Capsule, b: Capsule) -> jax.Array:
    return cl.segment_segment(a.a, a.b, b.a, b.b) - a.radius - b.radius


def sphere_box(a: Sphere, b: Box) -> jax.Array:
    return cl.point_box(_local(b, a.center), b.half_extents) - a.radius


def sphere_plane(a: Sphere, b: Plane) -> jax.Array:
    return cl.dot(b.normal, a.center) - b.offset - a.radius


def capsule_plane(a: Capsule, b: Plane) -> jax.Array:
    return jnp.minimum(cl.dot(b.normal, a.a), cl.dot(b.normal, a.b)) - b.offset - a.radius


def box_plane(a: Box, b: Plane) -> jax.Array:
    R, c = a.pose[..., :3, :3], a.pose[..., :3, 3]
    n_box = jnp.einsum("...ji,...j->...i", R, b.normal)  # the normal in the box frame
    return cl.dot(b.normal, c) - cl.dot(jnp.abs(n_box), a.half_extents) - b.offset


def plane_plane(a: Plane, b: Plane) -> jax.Array:
    """Two half-spaces overlap unless opposite: ``-(offset_a + offset_b)`` when ``n_a = -n_b`` (the gap,
    or minus the thickness of the common slab); otherwise they share an unbounded wedge and no
    translation separates them: the most negative finite number of the dtype."""
    d = -(a.offset + b.offset)
    opposite = cl.dot(a.normal, b.normal) <= -1 + 4 * jnp.finfo(d.dtype).eps
    return jnp.where(opposite, d, jnp.finfo(d.dtype).min)


# ---------------------------------------------------------------------------- structure of arrays
# Vectors below are tuples of three arrays (one per coordinate) of broadcastable batch shapes: the
# arithmetic is entry by entry, which XLA's CPU backend fuses into one loop over the batch (as the
# rigid transforms of diffkin._rigid), instead of tiny batched matrix products and (..., 12, 12, 3)
# edge arrays.

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


def _outside_sq(p: Vec, h: Vec) -> jax.Array:
    """Squared distance from points ``p`` (box frame) to a box of half extents ``h`` (0 inside)."""
    return sum(jnp.square(jnp.maximum(jnp.abs(p[i]) - h[i], 0)) for i in range(3))  # type: ignore[return-value]


def _segment_edge_sq(r: Vec, u: Vec, uu: jax.Array, i: int, h: jax.Array) -> jax.Array:
    """Squared distance between the segment ``r + s u`` (``0 <= s <= 1``) and the axis-aligned segment
    ``t e_i`` (``|t| <= h``): Ericson's clamped least squares (as :func:`_closest.segment_segment`),
    written for an edge along a coordinate axis."""
    j, k = (i + 1) % 3, (i + 2) % 3
    perp = u[j] * u[j] + u[k] * u[k]  # |u|^2 - u_i^2, the denominator of the unclamped optimum
    s = jnp.clip(cl.safe_div(-(r[j] * u[j] + r[k] * u[k]), perp), 0, 1)
    t = r[i] + s * u[i]
    clamped = jnp.clip(t, -h, h)
    s = jnp.where(t == clamped, s, jnp.clip(cl.safe_div(clamped * u[i] - _dot(r, u), uu), 0, 1))
    w = [r[0] + s * u[0], r[1] + s * u[1], r[2] + s * u[2]]
    w[i] = w[i] - clamped
    return w[0] * w[0] + w[1] * w[1] + w[2] * w[2]


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


def _sqrt(sq: jax.Array) -> jax.Array:
    """``sqrt`` with a zero (not NaN) derivative at 0."""
    ok = sq > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1)), 0)


def _unit(v: Vec) -> tuple[Vec, jax.Array]:
    """``v / |v|`` and a mask of the axes in use (``|v|`` not vanishingly small), as :func:`_closest.unit_axes`."""
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


def capsule_box(a: Capsule, b: Box) -> jax.Array:
    """Segment against box in the box frame (see the module docstring), minus the capsule's radius."""
    axes = _rotation(b.pose)
    c = _vec(b.pose[..., :3, 3])
    h = _vec(b.half_extents)
    p, q = _to_frame(axes, _sub(_vec(a.a), c)), _to_frame(axes, _sub(_vec(a.b), c))
    u = _sub(q, p)
    mid = tuple(0.5 * (p[i] + q[i]) for i in range(3))
    # overlap: separating axes = the box's axes and u x e_i
    seps = [jnp.abs(mid[i]) - 0.5 * jnp.abs(u[i]) - h[i] for i in range(3)]
    normals = []
    for i in range(3):
        n, ok = _unit(_cross_axis(i, u))
        normals.append(n)
        sep = jnp.abs(_dot(n, mid)) - sum(jnp.abs(n[m]) * h[m] for m in range(3))
        seps.append(jnp.where(ok, sep, -jnp.inf))
    sat = functools.reduce(jnp.maximum, seps)
    # apart: the closest points are an end point and the box, a box corner and the segment, or the
    # segment and a box edge along a common normal u x e_i (the box's support edge in that direction)
    uu = _dot(u, u)
    sq = [_outside_sq(p, h), _outside_sq(q, h)]
    for signs in itertools.product((-1, 1), repeat=3):
        pv = tuple(p[m] - signs[m] * h[m] for m in range(3))  # p - corner
        t = jnp.clip(cl.safe_div(-_dot(pv, u), uu), 0, 1)
        sq.append(sum(jnp.square(pv[m] + t * u[m]) for m in range(3)))
    for i in range(3):
        n = normals[i]
        towards = _sign(_dot(n, mid))
        n = tuple(towards * n[m] for m in range(3))
        for edge in _support_edges(n, i, h):
            sq.append(_segment_edge_sq(_sub(p, edge), u, uu, i, h[i]))
    apart = _sqrt(functools.reduce(jnp.minimum, sq))
    return jnp.where(sat > 0, apart, sat) - a.radius


def box_box(a: Box, b: Box) -> jax.Array:
    """Box against box in the frame of ``a`` (see the module docstring)."""
    ha, hb = _vec(a.half_extents), _vec(b.half_extents)
    axes_a = _rotation(a.pose)
    cols = tuple(_to_frame(axes_a, col) for col in _rotation(b.pose))  # b's axes in a's frame
    c = _to_frame(axes_a, _sub(_vec(b.pose[..., :3, 3]), _vec(a.pose[..., :3, 3])))  # b's centre in a's frame
    cb = _to_frame(cols, c)  # (the same offset in b's frame)
    R = [[cols[m][i] for m in range(3)] for i in range(3)]  # R[i][m] = e_i . b_m
    absR = [[jnp.abs(R[i][m]) for m in range(3)] for i in range(3)]
    # overlap: the separating axes e_i, b_m and e_i x b_m
    seps = [jnp.abs(c[i]) - ha[i] - sum(absR[i][m] * hb[m] for m in range(3)) for i in range(3)]
    seps += [jnp.abs(cb[m]) - sum(absR[i][m] * ha[i] for i in range(3)) - hb[m] for m in range(3)]
    normals = {}
    for i in range(3):
        for m in range(3):
            n, ok = _unit(_cross_axis(i, cols[m]))
            normals[i, m] = n
            rb = sum(jnp.abs(_dot(n, cols[k])) * hb[k] for k in range(3))
            sep = jnp.abs(_dot(n, c)) - sum(jnp.abs(n[k]) * ha[k] for k in range(3)) - rb
            seps.append(jnp.where(ok, sep, -jnp.inf))
    sat = functools.reduce(jnp.maximum, seps)
    # apart: the closest points are a corner of one and the other box, or an edge of each along a
    # common normal e_i x b_m (the support edges of a towards b and of b towards a)
    g = [tuple(hb[m] * cols[m][k] for k in range(3)) for m in range(3)]  # b's half axes in a's frame
    sq = []
    for s in itertools.product((-1, 1), repeat=3):
        corner_b = tuple(c[k] + s[0] * g[0][k] + s[1] * g[1][k] + s[2] * g[2][k] for k in range(3))
        sq.append(_outside_sq(corner_b, ha))
        corner_a = tuple(sum(s[i] * ha[i] * R[i][m] for i in range(3)) - cb[m] for m in range(3))  # in b's frame
        sq.append(_outside_sq(corner_a, hb))
    for (i, m), n in normals.items():
        towards = _sign(_dot(n, c))
        n = tuple(towards * n[k] for k in range(3))
        n_b = tuple(-_dot(cols[k], n) for k in range(3))  # towards a, in b's frame (n_b[m] = 0)
        u = tuple(2 * g[m][k] for k in range(3))
        uu = 4 * hb[m] * hb[m]
        for edge_a in _support_edges(n, i, ha):
            for edge_b in _support_edges(n_b, m, hb):
                # b's edge from its start point (in a's frame), relative to a's edge midpoint
                start = tuple(
                    c[k] + sum(edge_b[l] * cols[l][k] for l in range(3) if l != m) - g[m][k] - edge_a[k]
                    for k in range(3)
                )
                sq.append(_segment_edge_sq(start, u, uu, i, ha[i]))
    apart = _sqrt(functools.reduce(jnp.minimum, sq))
    return jnp.where(sat > 0, apart, sat)


_PAIRS: dict[tuple[type, type], Callable[[Any, Any], jax.Array]] = {
    (Sphere, Sphere): sphere_sphere,
    (Sphere, Capsule): sphere_capsule,
    (Sphere, Box): sphere_box,
    (Sphere, Plane): sphere_plane,
    (Capsule, Capsule): capsule_capsule,
    (Capsule, Box): capsule_box,
    (Capsule, Plane): capsule_plane,
    (Box, Box): box_box,
    (Box, Plane): box_plane,
    (Plane, Plane): plane_plane,
}

#: Each pair function compiled once per shape and dtype (``jax.jit``; inlined when the caller is
#: itself jitted). Measured (2 shared cores, float64, 6 configurations of a 5-shape robot against a
#: box): ``jax.grad`` of :func:`diffkin.collision.clearance` outside ``jit`` took 32 s op by op.
_TABLE = {kinds: jax.jit(fn) for kinds, fn in _PAIRS.items()}


def distance(shape_a, shape_b) -> jax.Array:
    """Signed distance between two primitives: positive apart, minus the penetration depth when overlapping.

    Args:
        shape_a, shape_b: a :class:`Sphere`, :class:`Capsule`, :class:`Box` or :class:`Plane`
            each, of any kinds and order, in one frame (e.g. the world); their batch axes broadcast.

    Returns:
        ``(...,)`` the distance in metres, in the promoted dtype of the two shapes. Differentiable
        wherever the closest features are unique; finite (with finite derivatives) everywhere. Two
        half-spaces that are not opposite overlap without bound: the dtype's most negative finite
        number.

    Raises:
        TypeError: an argument is not one of the four primitives.
    """
    for name, value in (("shape_a", shape_a), ("shape_b", shape_b)):
        if not isinstance(value, SHAPES):
            raise TypeError(
                f"{name}: expected a Sphere, Capsule, Box or Plane of diffkin.collision, got {type(value).__name__}"
            )
    kinds = (type(shape_a), type(shape_b))
    if kinds in _TABLE:
        return _TABLE[kinds](shape_a, shape_b)
    return _TABLE[kinds[::-1]](shape_b, shape_a)
