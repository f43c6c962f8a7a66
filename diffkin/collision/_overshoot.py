"""How far a fitted shape reaches beyond the solid it replaces (host, NumPy): ``Geometry.overshoot``.

The overshoot of a fit is the largest distance from a point of the fit to the solid of the original
(a closed triangle mesh: inside by its winding number). It is measured at points spread over the fit's
surface (its vertices, edges and a grid on each face for a polytope; rings and caps for a capsule),
brute force over the mesh's triangles: a close lower bound of the supremum, tight at the vertices and
edges of a polytope fit, where a hull's overshoot is largest.
"""

from __future__ import annotations

import numpy as np

#: per face of a polytope fit, the grid of barycentric samples is this many steps along each edge
FACE_STEPS = 4
_CHUNK = 512


def _point_triangle(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``(n,)``: the distance from each point of ``P`` to the nearest of the triangles ``A, B, C (m, 3)``."""
    out = np.empty(len(P))
    ab, ac = B - A, C - A
    normal = np.cross(ab, ac)
    nn = np.maximum(np.einsum("mi,mi->m", normal, normal), 1e-300)

    def segment(p, a, b):
        d = b - a
        t = np.clip(np.einsum("nmi,mi->nm", p - a, d) / np.maximum(np.einsum("mi,mi->m", d, d), 1e-300), 0, 1)
        return np.linalg.norm(p - a - t[..., None] * d, axis=-1)

    for s in range(0, len(P), _CHUNK):
        p = P[s : s + _CHUNK, None, :]
        ap = p - A
        u = np.einsum("nmi,mi->nm", np.cross(ap, ac), normal) / nn
        v = np.einsum("nmi,mi->nm", np.cross(ab, ap), normal) / nn
        inside = (u >= 0) & (v >= 0) & (u + v <= 1)
        plane = np.abs(np.einsum("nmi,mi->nm", ap, normal)) / np.sqrt(nn)
        edges = np.minimum(np.minimum(segment(p, A, B), segment(p, B, C)), segment(p, C, A))
        out[s : s + _CHUNK] = np.where(inside, plane, edges).min(axis=1)
    return out


def _winding(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``(n,)``: the winding number of a closed triangle mesh about each point (1 inside, 0 outside)."""
    out = np.empty(len(P))
    for s in range(0, len(P), _CHUNK):
        a, b, c = (X - P[s : s + _CHUNK, None, :] for X in (A, B, C))
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("nmi,nmi->nm", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("nmi,nmi->nm", a, b) * lc
        den = den + np.einsum("nmi,nmi->nm", b, c) * la + np.einsum("nmi,nmi->nm", c, a) * lb
        out[s : s + _CHUNK] = np.arctan2(num, den).sum(axis=1) / (2 * np.pi)
    return out


def to_solid(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(n,)`` metres: the distance of each point to the solid of a closed mesh (0 inside)."""
    A, B, C = (vertices[faces[:, k]] for k in range(3))
    distance = _point_triangle(points, A, B, C)
    return np.where(np.abs(_winding(points, A, B, C)) > 0.5, 0.0, distance)


def new_faces(points: np.ndarray, faces: np.ndarray, mesh_vertices: np.ndarray, mesh_faces: np.ndarray) -> np.ndarray:
    """The triangles of a hull (``points``, ``faces``) that are not triangles of the mesh it wraps: where the hull
    bridges a concavity (the rest of its surface is the mesh's own, at distance 0)."""
    _, index = np.unique(np.concatenate([mesh_vertices, points]), axis=0, return_inverse=True)
    index = index.reshape(-1)
    on_mesh, on_hull = index[: len(mesh_vertices)], index[len(mesh_vertices) :]
    known = {frozenset(f) for f in on_mesh[mesh_faces].tolist()}
    return np.array([f for f in faces if frozenset(on_hull[f].tolist()) not in known], dtype=np.int64).reshape(-1, 3)


def polytope_samples(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Points spread over triangles of a polytope: a barycentric grid on each (corners excluded: they are
    points of the original)."""
    k = FACE_STEPS
    triples = [(i, j, k - i - j) for i in range(k + 1) for j in range(k + 1 - i)]
    grid = np.array([g for g in triples if max(g) < k], dtype=np.float64) / k
    return np.einsum("gk,mki->mgi", grid, vertices[faces]).reshape(-1, 3)


def capsule_samples(a: np.ndarray, b: np.ndarray, radius: float, rings: int = 24) -> np.ndarray:
    """Points spread over a capsule's surface: rings along the axis and a lattice on each end cap."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
    x = np.cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    angle = np.linspace(0, 2 * np.pi, rings, endpoint=False)
    ring = radius * (np.cos(angle)[:, None] * x + np.sin(angle)[:, None] * y)
    side = (a + np.linspace(0, 1, rings)[:, None, None] * axis + ring[None]).reshape(-1, 3)
    k = np.arange(4 * rings) + 0.5
    polar = np.arccos(1 - k / (4 * rings))  # a half sphere
    turn = np.pi * (1 + 5**0.5) * k
    cap = np.column_stack([np.cos(turn) * np.sin(polar), np.sin(turn) * np.sin(polar), np.cos(polar)])
    frame = np.column_stack([x, y, z])
    top = b + radius * cap @ frame.T
    bottom = a - radius * cap @ frame.T
    return np.concatenate([side, top, bottom])
