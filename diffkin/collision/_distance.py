"""Signed distances between primitives: positive apart, minus the penetration depth when overlapping.

The penetration depth is the length of the shortest translation that separates the shapes. Each
pair is computed exactly (to rounding):

- Spheres and capsules are points and segments swept by a ball, so their signed distance is the
  distance between the points/segments minus the radii (the Minkowski difference of two segments
  is flat, so this holds inside as well as outside).
- A half-space against a convex shape: the lowest point of the shape along the normal.
- Box-box and capsule-box: the separating-axis depth when overlapping, the closest features when
  apart (:mod:`diffkin.collision._boxes`).
- A cylinder against a sphere: the point's distance to the cylinder (a rectangle in the axial
  plane); against a half-space: the lowest rim point. Against a capsule, a box or a cylinder, and
  a convex polytope against any solid: the general convex distance (:mod:`diffkin.collision._gjk`):
  exact (to ``_gjk.TOLERANCE``) apart, never shallower than the truth when overlapping; a polytope
  against a half-space: its lowest vertex.

:func:`motion` also gives how a rigid motion of each shape changes the distance, from the witness
points and the normal of the contact (far cheaper than differentiating :func:`distance`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from diffkin._xla import materialize
from diffkin.collision import _closest as cl
from diffkin.collision import _gjk
from diffkin.collision._boxes import (
    box_box,
    box_box_bound,
    box_box_contact,
    capsule_box,
    capsule_box_bound,
    capsule_box_contact,
    sphere_box_contact,
)
from diffkin.collision._shapes import SHAPES, Box, Capsule, Convex, Cylinder, Plane, Sphere, unchecked


def _local(box: Box, p: cl.Vec) -> cl.Vec:
    """Points ``p`` in the frame of ``box``: ``R^T (p - c)``."""
    return cl.to_frame(cl.rotation(box.pose), cl.sub(p, cl.vec(box.pose[..., :3, 3])))


def sphere_sphere(a: Sphere, b: Sphere) -> jax.Array:
    return cl.norm(cl.sub(cl.vec(a.center), cl.vec(b.center))) - a.radius - b.radius


def sphere_capsule(a: Sphere, b: Capsule) -> jax.Array:
    return cl.point_segment(cl.vec(a.center), cl.vec(b.a), cl.vec(b.b)) - a.radius - b.radius


def capsule_capsule(a: Capsule, b: Capsule) -> jax.Array:
    return cl.segment_segment(cl.vec(a.a), cl.vec(a.b), cl.vec(b.a), cl.vec(b.b)) - a.radius - b.radius


def sphere_box(a: Sphere, b: Box) -> jax.Array:
    return cl.point_box(_local(b, cl.vec(a.center)), cl.vec(b.half_extents)) - a.radius


def sphere_plane(a: Sphere, b: Plane) -> jax.Array:
    return cl.dot(cl.vec(b.normal), cl.vec(a.center)) - b.offset - a.radius


def capsule_plane(a: Capsule, b: Plane) -> jax.Array:
    n = cl.vec(b.normal)
    return jnp.minimum(cl.dot(n, cl.vec(a.a)), cl.dot(n, cl.vec(a.b))) - b.offset - a.radius


def box_plane(a: Box, b: Plane) -> jax.Array:
    n = cl.vec(b.normal)
    n_box = cl.to_frame(cl.rotation(a.pose), n)  # the normal in the box frame
    h = cl.vec(a.half_extents)
    return cl.dot(n, cl.vec(a.pose[..., :3, 3])) - sum(jnp.abs(n_box[i]) * h[i] for i in range(3)) - b.offset


def _cylinder_local(c: Cylinder, p: cl.Vec) -> tuple[jax.Array, jax.Array]:
    """Of points ``p``: the distance from the cylinder's axis and the signed axial coordinate."""
    local = cl.to_frame(cl.rotation(c.pose), cl.sub(p, cl.vec(c.pose[..., :3, 3])))
    return cl.sqrt0(local[0] ** 2 + local[1] ** 2), local[2]


def sphere_cylinder(a: Sphere, b: Cylinder) -> jax.Array:
    rho, z = _cylinder_local(b, cl.vec(a.center))
    dr, dz = rho - b.radius, jnp.abs(z) - b.half_length  # the rectangle (rho, z) of the axial plane
    outside = cl.sqrt0(jnp.maximum(dr, 0) ** 2 + jnp.maximum(dz, 0) ** 2)
    return outside + jnp.minimum(jnp.maximum(dr, dz), 0) - a.radius


def cylinder_plane(a: Cylinder, b: Plane) -> jax.Array:
    """The centre's height above the plane less the rim's extent below it (radial and axial parts)."""
    n = cl.vec(b.normal)
    along = cl.dot(n, cl.rotation(a.pose)[2])
    low = a.radius * cl.sqrt0(jnp.maximum(1 - along * along, 0.0)) + a.half_length * jnp.abs(along)
    return cl.dot(n, cl.vec(a.pose[..., :3, 3])) - low - b.offset


def support_plane(a, b: Plane) -> jax.Array:
    """Any solid against a half-space: its core's lowest point along the normal, less its rounding."""
    return jnp.sum(b.normal * a.core_support(-b.normal), axis=-1) - b.offset - a.rounding()


def plane_plane(a: Plane, b: Plane) -> jax.Array:
    """Two half-spaces overlap unless opposite: ``-(offset_a + offset_b)`` when ``n_a = -n_b`` (the gap,
    or minus the thickness of the common slab); otherwise they share an unbounded wedge and no
    translation separates them: the most negative finite number of the dtype."""
    d = -(a.offset + b.offset)
    opposite = cl.dot(cl.vec(a.normal), cl.vec(b.normal)) <= -1 + 4 * jnp.finfo(d.dtype).eps
    return jnp.where(opposite, d, jnp.finfo(d.dtype).min)


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
    (Sphere, Cylinder): sphere_cylinder,
    (Capsule, Cylinder): _gjk.distance,
    (Box, Cylinder): _gjk.distance,
    (Cylinder, Cylinder): _gjk.distance,
    (Cylinder, Plane): cylinder_plane,
    (Sphere, Convex): _gjk.distance,
    (Capsule, Convex): _gjk.distance,
    (Box, Convex): _gjk.distance,
    (Cylinder, Convex): _gjk.distance,
    (Convex, Convex): _gjk.distance,
    (Convex, Plane): support_plane,
}

#: Each pair function compiled once per shape and dtype (``jax.jit``; inlined when the caller is
#: itself jitted). Measured (2 shared cores, float64, 6 configurations of a 5-shape robot against a
#: box): ``jax.grad`` of :func:`diffkin.collision.clearance` outside ``jit`` took 32 s op by op.
_TABLE = {kinds: jax.jit(fn) for kinds, fn in _PAIRS.items()}


def distance(shape_a, shape_b) -> jax.Array:
    """Signed distance between two primitives: positive apart, minus the penetration depth when overlapping.

    Args:
        shape_a, shape_b: a :class:`Sphere`, :class:`Capsule`, :class:`Box`, :class:`Cylinder`,
            :class:`Convex` or :class:`Plane` each, of any kinds and order, in one frame (e.g. the
            world); their batch axes broadcast.

    Returns:
        ``(...,)`` the distance in metres, in the promoted dtype of the two shapes. Differentiable
        wherever the closest features are unique; finite (with finite derivatives) everywhere. Two
        half-spaces that are not opposite overlap without bound: the dtype's most negative finite
        number.

    Raises:
        TypeError: an argument is not one of the primitives.
    """
    for name, value in (("shape_a", shape_a), ("shape_b", shape_b)):
        if not isinstance(value, SHAPES):
            raise TypeError(
                f"{name}: expected a Sphere, Capsule, Box, Cylinder, Convex or Plane of diffkin.collision, "
                f"got {type(value).__name__}"
            )
    kinds = (type(shape_a), type(shape_b))
    if kinds in _TABLE:
        return _TABLE[kinds](shape_a, shape_b)
    return _TABLE[kinds[::-1]](shape_b, shape_a)


#: the pairs whose distance is the general convex one (:mod:`diffkin.collision._gjk`)
GENERAL = frozenset(kinds for kinds, fn in _PAIRS.items() for kinds in (kinds, kinds[::-1]) if fn is _gjk.distance)
#: the pairs of kinds whose :func:`lower_bound` is cheaper than their :func:`distance`
BOUNDED = frozenset({(Box, Box), (Capsule, Box), (Box, Capsule)}) | GENERAL


def lower_bound(a, b) -> jax.Array:
    """A lower bound of :func:`distance` that is much cheaper for box-box and capsule-box (the face
    axes' separation) and the general pairs (the larger of the distance of balls around the shapes
    and the face axes' separation of boxes around them: a shelf's board is far from most of a link's
    ball); the distance itself for the other pairs (already cheap)."""
    kinds = (type(a), type(b))
    if kinds == (Box, Box):
        return box_box_bound(a, b)
    if kinds == (Capsule, Box):
        return capsule_box_bound(a, b)
    if kinds == (Box, Capsule):
        return capsule_box_bound(b, a)
    if kinds in GENERAL:  # the balls around them, and the boxes around them
        gap = jnp.sqrt(jnp.sum((a.centre() - b.centre()) ** 2, axis=-1))
        return jnp.maximum(
            gap - a.bounding_radius() - b.bounding_radius(), box_box_bound(a.bounding_box(), b.bounding_box())
        )
    return distance(a, b)


def _cores(a: Sphere | Capsule, b: Sphere | Capsule) -> tuple[cl.Vec, cl.Vec]:
    """Closest points of the cores (centres, segments) of two round shapes."""
    if isinstance(a, Sphere) and isinstance(b, Sphere):
        return cl.vec(a.center), cl.vec(b.center)
    if isinstance(a, Sphere):
        q, p = _cores(b, a)  # type: ignore[arg-type]
        return p, q
    if isinstance(b, Sphere):
        p = cl.vec(b.center)
        s, _ = cl.segment_params(cl.vec(a.a), cl.vec(a.b), p, p)
        return cl.lerp(cl.vec(a.a), cl.vec(a.b), s), p
    s, t = cl.segment_params(cl.vec(a.a), cl.vec(a.b), cl.vec(b.a), cl.vec(b.b))
    return cl.lerp(cl.vec(a.a), cl.vec(a.b), s), cl.lerp(cl.vec(b.a), cl.vec(b.b), t)


def _wrench(n: cl.Vec, p: cl.Vec) -> jax.Array:
    """``[n; p x n]`` stacked on a last axis."""
    m = (p[1] * n[2] - p[2] * n[1], p[2] * n[0] - p[0] * n[2], p[0] * n[1] - p[1] * n[0])
    return jnp.stack(jnp.broadcast_arrays(*n, *m), axis=-1)


def motion(a, b) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The signed distance of two shapes (not both half-spaces) and how each shape's rigid motion changes it.

    Returns:
        ``(d, W_a, W_b)``: ``d (...,)`` as :func:`distance`; ``W_a``, ``W_b`` ``(..., 6)`` wrenches
        ``[f; tau]`` such that moving shape ``a`` by the space twist ``[v; w]`` (a point ``p`` by ``v + w
        x p``) changes ``d`` by ``W_a . [v; w]`` (and ``b`` likewise; a half-space's wrench is zero: it
        is an obstacle here). Both come from the contact: the unit normal ``n`` from ``a`` to ``b`` and a
        point ``p`` on the line through the witness points, ``W_b = [n; p x n] = -W_a`` (for boxes,
        :func:`diffkin.collision._boxes.capsule_box_contact`). They equal the derivative of
        :func:`distance` wherever it is unique. Where the closest points coincide (concentric spheres,
        crossing core segments, shapes just touching) the direction is undefined and the wrenches are
        zero (finite).
    """
    if isinstance(a, Plane):
        d, W_b, W_a = motion(b, a)
        return d, W_a, W_b
    if isinstance(b, Plane):
        n = cl.vec(b.normal)
        if isinstance(a, (Cylinder, Convex)):  # its lowest point
            d = _PAIRS[type(a), Plane](a, b)
            return d, _wrench(n, cl.vec(a.core_support(-b.normal))), jnp.zeros(jnp.shape(d) + (6,), d.dtype)
        if isinstance(a, Sphere):
            p = cl.vec(a.center)
        elif isinstance(a, Capsule):
            lower = cl.dot(n, cl.vec(a.a)) <= cl.dot(n, cl.vec(a.b))
            p = tuple(jnp.where(lower, u, v) for u, v in zip(cl.vec(a.a), cl.vec(a.b), strict=True))
        else:  # the box's lowest point along n (the middle of a face or an edge on ties)
            p = cl.vec(a.pose[..., :3, 3])
            for k, axis in enumerate(cl.rotation(a.pose)):
                w = -jnp.sign(cl.dot(n, axis)) * a.half_extents[..., k]
                p = tuple(p[i] + w * axis[i] for i in range(3))
        radius = 0.0 if isinstance(a, Box) else a.radius
        d = cl.dot(n, p) - b.offset - radius
        return d, _wrench(n, p), jnp.zeros(jnp.shape(d) + (6,), d.dtype)
    kinds = (type(a), type(b))
    if kinds not in _PAIRS and (Cylinder in kinds or Convex in kinds):  # the pair table's order
        d, W_b, W_a = motion(b, a)
        return d, W_a, W_b
    if kinds in GENERAL or kinds == (Sphere, Cylinder):
        if kinds == (Sphere, Cylinder):  # along the outward normal (the closed form's gradient)
            d = sphere_cylinder(a, b)
            grad = jax.grad(lambda c: jnp.sum(sphere_cylinder(unchecked(Sphere, center=c, radius=a.radius), b)))
            g = jnp.broadcast_to(jax.lax.stop_gradient(grad(a.center)), jnp.shape(d) + (3,))
            u = cl.vec(-g)
            p = q = cl.vec(jnp.broadcast_to(a.center, g.shape))
        else:
            d, normal, pa, pb = _gjk.contact(a, b)
            u, p, q = cl.vec(normal), cl.vec(pa), cl.vec(pb)
        return d, _wrench(tuple(-c for c in u), p), _wrench(u, q)
    if isinstance(a, Box) and not isinstance(b, Box):
        d, W_b, W_a = motion(b, a)
        return d, W_a, W_b
    if isinstance(b, Box):
        if isinstance(a, Box):
            d, n, p = box_box_contact(a, b)
        elif isinstance(a, Sphere):
            d, n, p = sphere_box_contact(a, b)
        else:
            d, n, p = capsule_box_contact(a, b)
        line = materialize([*n, *p])  # read by twelve wrench entries: computed once
        n, p = tuple(line[:3]), tuple(line[3:])
        return d, _wrench(tuple(-c for c in n), p), _wrench(n, p)
    p, q = _cores(a, b)
    gap = cl.norm(cl.sub(q, p))
    u = tuple(cl.safe_div(c, gap) for c in cl.sub(q, p))  # from a to b
    d = gap - a.radius - b.radius
    return d, _wrench(tuple(-c for c in u), p), _wrench(u, q)
