"""Capsules that contain a robot's polytopes and cylinders, and a world's cylinders.

A capsule's distances to spheres, capsules and boxes are closed forms; a convex polytope's and a
cylinder's go through GJK (:mod:`diffkin.collision._gjk`), whose steps, and a polytope's scan of every
vertex at each, cost far more. A solver that only needs to stay clear (a trajectory's descent:
:mod:`diffkin.traj._descent`) can measure the capsules and leave the exact shapes to what certifies
its result: a capsule contains its shape, so its distances are lower bounds of the shape's.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.collision import _fit, _overshoot, _sources
from diffkin.collision._geometry import KINDS, Geometry
from diffkin.collision._robot import World
from diffkin.collision._shapes import Capsule, unchecked

#: the last few (geometry, its capsules), matched by identity: a solver's every call derives them anew otherwise
_DERIVED: list[tuple[Geometry, Geometry]] = []
_KEEP = 4


def enclosing_capsules(geom: Geometry) -> Geometry:
    """``geom`` (concrete) with every convex polytope and cylinder replaced by a capsule that contains it
    (:func:`diffkin.collision._fit.points`, :func:`diffkin.collision._fit.cylinder`), in the order
    :class:`~diffkin.collision.Geometry` keeps (by kind; the new capsules after the file's own), its
    self-collision pairs renumbered. A replaced shape's :attr:`~diffkin.collision.Geometry.overshoot` grows by
    how far its capsule reaches beyond it (the distance to the original is at most the sum)."""
    for source, derived in _DERIVED:
        if source is geom:
            return derived
    derived = _derive(geom)
    _DERIVED.append((geom, derived))
    del _DERIVED[:-_KEEP]
    return derived


def enclosing_world(world: World) -> World:
    """``world`` (traced or not) with its cylinders as capsules that contain them: of the cylinder's radius, on
    the segment of its axis between its end caps (exact on the side; each end reaches its radius beyond the
    cap's centre), after the world's own capsules."""
    cylinders = world.cylinders
    axis = len(world.batch)  # the obstacle axis
    z, centre = cylinders.pose[..., :3, 2], cylinders.pose[..., :3, 3]
    half = cylinders.half_length[..., None] * z
    capsules = unchecked(
        Capsule,
        **{
            name: jnp.concatenate([getattr(world.capsules, name), new], axis=axis)
            for name, new in (("a", centre - half), ("b", centre + half), ("radius", cylinders.radius))
        },
    )
    none = jax.tree.map(lambda x: jax.lax.slice_in_dim(x, 0, 0, axis=axis), cylinders)
    kinds = list(world.kinds())
    kinds[KINDS.index("capsule")], kinds[KINDS.index("cylinder")] = capsules, none
    return World.tree_unflatten(None, kinds)


def _derive(geom: Geometry) -> Geometry:
    """:func:`enclosing_capsules` without the cache."""
    counts = geom.counts
    starts = np.cumsum((0, *counts))
    kind_of = np.repeat(np.arange(len(KINDS)), counts)  # per shape, its index in KINDS
    capsule, cylinder, convex = KINDS.index("capsule"), KINDS.index("cylinder"), KINDS.index("convex")
    replaced = [i for i in range(len(kind_of)) if kind_of[i] in (cylinder, convex)]
    if not replaced:
        return geom
    dtype = np.asarray(geom.capsules.radius).dtype
    overshoot = geom.overshoot.copy()
    fits = []
    for i in replaced:
        shape = geom.shapes[kind_of[i]]
        k = i - starts[kind_of[i]]
        T = np.asarray(shape.pose[k], np.float64)
        if kind_of[i] == convex:
            points = np.asarray(shape.vertices[k], np.float64) @ T[:3, :3].T + T[:3, 3]
            a, b, r = _fit.points(points)
            hull_points, hull_faces = _fit.hull(points)
            volume = _sources._hull_volume(hull_points)
            if len(hull_faces):
                beyond = np.max(_overshoot.to_solid(_overshoot.capsule_samples(a, b, r), hull_points, hull_faces))
            else:  # a flat polytope: the capsule's radius bounds it
                beyond = r
        else:
            radius, half = float(shape.radius[k]), float(shape.half_length[k])
            R, L = _fit.cylinder(radius, half)
            a, b = T[:3, :3] @ [0.0, 0.0, -L] + T[:3, 3], T[:3, :3] @ [0.0, 0.0, L] + T[:3, 3]
            r, beyond = R, _fit.cylinder_overshoot(radius, half, R, L)
            volume = 2 * np.pi * radius**2 * half
        overshoot[i] += float(beyond)
        fits.append((i, a, b, r, volume))
    old = geom.capsules
    stacked = lambda old, new, tail: jnp.asarray(  # noqa: E731  (cast on the host: no XLA program)
        np.concatenate([np.asarray(old), np.array(new, np.float64).reshape((-1,) + tail)]).astype(dtype)
    )
    new_capsules = Capsule(
        stacked(old.a, [f[1] for f in fits], (3,)),
        stacked(old.b, [f[2] for f in fits], (3,)),
        stacked(old.radius, [f[3] for f in fits], ()),
    )
    # new order: spheres, the file's capsules, the new capsules, boxes (no cylinders, no polytopes)
    order = [*range(starts[0], starts[capsule + 1]), *replaced, *range(starts[capsule + 1], starts[capsule + 2])]
    index = {old_i: new_i for new_i, old_i in enumerate(order)}
    shapes = list(geom.shapes)
    shapes[capsule] = new_capsules
    for kind in (cylinder, convex):
        shapes[kind] = _empty(geom.shapes[kind])
    pick = lambda values: tuple(values[i] for i in order)  # noqa: E731
    names = {geom.shape_names[i] for i in replaced}
    return dataclasses.replace(
        geom,
        shapes=tuple(shapes),
        shape_frames=pick(geom.shape_frames),
        shape_names=pick(geom.shape_names),
        shape_bodies=pick(geom.shape_bodies),
        shape_links=pick(geom.shape_links),
        pair_list=tuple(sorted((min(index[i], index[j]), max(index[i], index[j])) for i, j in geom.pair_list)),
        fits=tuple(f for f in geom.fits if f[0] not in names)
        + tuple(
            (geom.shape_names[i], KINDS[kind_of[i]], volume, _fit.capsule_volume(r, float(np.linalg.norm(b - a))))
            for i, a, b, r, volume in fits
        ),
        shape_overshoot=pick(tuple(float(x) for x in overshoot)),
    )


def _empty(shapes):
    """``shapes`` (one kind, stacked) with none left."""
    return jax.tree.map(lambda x: x[:0], shapes)
