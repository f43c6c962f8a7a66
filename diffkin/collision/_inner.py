"""Polytopes of fewer vertices inside a geometry's own: cheaper distances for a search.

GJK's support function scans every vertex of a polytope, and a batch of pairs pads every shape in it
to its largest polytope (:mod:`diffkin.collision._near`): a mesh's hull of 150 vertices costs that on
both sides of each pair. A search that needs distances near the true ones, not certain ones (the
descent of :mod:`diffkin.traj`, whose certificate measures the geometry itself), can measure
polytopes of a few of those vertices instead.

:func:`inner` chooses them greedily on the support function ``h(n) = max_v n . v``: the next vertex is
the original's support along the direction (of :data:`DIRECTIONS` spread over the sphere) where the
chosen ones fall shortest. Their hull lies inside the original, so a distance measured on it is never
below the true one, and above it by at most the hulls' Hausdorff distance (the most the support falls
short along any direction).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

#: directions spread over the sphere along which the chosen vertices' shortfall is minimised
DIRECTIONS = 2000


def _sphere(count: int) -> np.ndarray:
    """``(count, 3)`` unit directions of a Fibonacci lattice."""
    i = np.arange(count) + 0.5
    polar, azimuth = np.arccos(1 - 2 * i / count), np.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


def chosen(vertices: np.ndarray, count: int) -> np.ndarray:
    """``(count, 3)``: at most ``count`` of the distinct ``vertices`` ``(V, 3)`` (all of them if there are no
    more), padded by repeating the first (which leaves their hull as it is)."""
    V = np.unique(np.asarray(vertices, np.float64), axis=0)
    if len(V) > count:
        h = V @ _sphere(DIRECTIONS).T  # (V, D): each vertex's support value along each direction
        full = h.max(axis=0)
        picked = [int(np.argmax(h[:, 0]))]
        have = h[picked[0]]
        while len(picked) < count:
            picked.append(int(np.argmax(h[:, int(np.argmax(full - have))])))
            have = np.maximum(have, h[picked[-1]])
        V = V[picked]
    return np.concatenate([V, np.repeat(V[:1], count - len(V), axis=0)])


def inner(geom, count: int):
    """``geom`` (a :class:`diffkin.collision.Geometry`) with each convex polytope replaced by the hull of at most
    ``count`` of its vertices (:func:`chosen`); ``geom`` itself where none has more."""
    polytopes = geom.convexes
    if polytopes.vertices.shape[-2] <= count:
        return geom
    vertices = np.array([chosen(v, count) for v in np.asarray(polytopes.vertices)])
    shapes = geom.shapes[:4] + (polytopes.replace(vertices=jnp.asarray(vertices, polytopes.vertices.dtype)),)
    return dataclasses.replace(geom, shapes=shapes)
