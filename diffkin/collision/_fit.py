"""Conservative capsule fits: cylinders, ellipsoids and meshes inside one capsule each (host, NumPy).

A capsule is convex, so containing every vertex of a mesh means containing the mesh (and its
convex hull). Cylinders and ellipsoids are fitted in closed form along their own axis; a mesh's
capsule is searched for (axis and axis line by Nelder-Mead from the principal axes, the smallest
volume for that line in an inner search over the radius), and whatever line is chosen, the radius
and end points are computed so that every vertex is inside: the search only changes how tight it is.
Mesh fits are cached on disk (:mod:`diffkin.collision._fitcache`).
"""

from __future__ import annotations

import functools
import importlib.util

import numpy as np

from diffkin.collision import _fitcache

# The mesh fit's version and settings: part of each cached fit's key, so changing one refits every mesh.
# Change FIT_VERSION with any change to the search that changes its results.
FIT_VERSION = "capsule-1"
GRID = 65  # radii tried on each line
HULL_ABOVE = 400  # more distinct points than this: only their convex hull's vertices are searched
SEARCH = (("xatol", 1e-6), ("fatol", 1e-12), ("maxiter", 400))  # Nelder-Mead's options
MARGIN = 1e-9  # added to the radius, times the points' largest extent (at least 1 mm)


def capsule_volume(radius: float, length: float) -> float:
    """Volume of a capsule of ``radius`` whose axis segment has ``length``."""
    return float(np.pi * radius**2 * length + 4.0 / 3.0 * np.pi * radius**3)


def cylinder(radius: float, half_length: float) -> tuple[float, float]:
    """``(capsule radius, capsule half length)`` of the smallest capsule on a cylinder's axis that contains it.

    The rim ``(r, h)`` must be within ``R`` of the segment ``[-L, L]``: ``R >= r`` and
    ``(h - L)^2 + r^2 <= R^2``; the volume is minimised over ``R`` (a 1-D search; both ends of the
    range are candidates, so a flat disc gets a sphere and a long rod a capsule of radius ``r``).
    """
    r, h = float(radius), float(half_length)
    grid = np.linspace(r, np.hypot(r, h), 2001)
    L = np.maximum(h - np.sqrt(np.maximum(grid**2 - r**2, 0)), 0)
    volume = 2 * np.pi * grid**2 * L + 4 / 3 * np.pi * grid**3
    i = int(np.argmin(volume))
    R = float(grid[i])
    return R, float(max(h - np.sqrt(max(R * R - r * r, 0.0)), 0.0))


def cylinder_overshoot(radius: float, half_length: float, R: float, L: float) -> float:
    """The largest distance from a point of the capsule (``R``, half length ``L``, on the axis) to the cylinder
    (``radius``, ``half_length``): over the capsule's side and end caps, in the axial plane (sampled finely:
    the distance is smooth there)."""
    r, h = float(radius), float(half_length)
    angle = np.linspace(0.0, np.pi / 2, 2001)
    rho = np.concatenate([R * np.sin(angle), np.full(2001, R)])
    z = np.concatenate([L + R * np.cos(angle), np.linspace(0.0, L, 2001)])
    dr, dz = np.maximum(rho - r, 0.0), np.maximum(z - h, 0.0)
    return float(np.max(np.hypot(dr, dz)))


def ellipsoid(semi_axes) -> tuple[int, float, float]:
    """``(axis index, radius, half length)`` of a capsule containing an ellipsoid of ``semi_axes``.

    Along the longest semi-axis ``c``, radius ``R`` = the larger other semi-axis ``a'``, half
    length ``L = c - R``. Containment: the ellipsoid lies in the spheroid of semi-axes ``a', a', c``,
    whose points at height ``|z| <= L`` are within ``a' = R`` of the axis; beyond, the squared
    distance to the segment, ``a'^2 (1 - z^2/c^2) + (|z| - L)^2``, is convex in ``z`` (``c >= a'``),
    so at most its values at ``z = L`` and ``z = c``, both ``<= R^2``. Of the capsules on that axis
    with ``R >= a'`` (needed at ``z = 0``) and ``L >= c - R`` (needed at ``z = c``), the smallest.
    """
    s = np.asarray(semi_axes, dtype=np.float64)
    k = int(np.argmax(s))
    R = float(np.max(np.delete(s, k)))
    return k, R, float(s[k] - R)


def _segments_for(t: np.ndarray, rho: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each radius of ``R``: the shortest axis segment ``[lo, hi]`` (``lo <= hi``) whose capsule of
    that radius contains points at axial positions ``t`` and radial distances ``rho <= R`` (arrays like ``R``)."""
    reach = R[:, None] * R[:, None] - rho * rho
    np.sqrt(np.maximum(reach, 0, out=reach), out=reach)
    hi = np.max(t - reach, axis=1)
    lo = np.min(np.add(t, reach, out=reach), axis=1)
    sphere = lo > hi  # a sphere suffices: any point of [hi, lo] is within reach of every point
    mid = 0.5 * (lo + hi)
    return np.where(sphere, mid, lo), np.where(sphere, mid, hi)


@functools.cache
def _unit_grid(n: int) -> np.ndarray:
    """``n`` values from 0 to 1, denser near 0 (squares of equal steps): the radius grid's shape."""
    grid = np.linspace(0, 1, n) ** 2
    grid.flags.writeable = False
    return grid


def _best_on_line(points: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Smallest-volume capsule on the line ``origin + s axis`` containing the points: ``(volume, a, b)``.

    The radius is the best of a grid of ``GRID`` values from the points' largest distance to the line
    up to half their extent along it more (the first of equal volumes), all evaluated at once.
    """
    d = points - origin
    t = d @ axis
    rho = np.linalg.norm(d - t[:, None] * axis, axis=1)
    r0 = float(rho.max())
    span = float(t.max() - t.min())
    grid = r0 + _unit_grid(GRID) * (0.5 * span + 1e-12)
    lo, hi = _segments_for(t, rho, grid)
    volume = np.pi * grid**2 * (hi - lo) + 4.0 / 3.0 * np.pi * grid**3  # capsule_volume, elementwise
    volume = np.where(volume < np.inf, volume, np.inf)  # NaN (non-finite points) never wins
    i = int(np.argmin(volume))  # the first of equal volumes
    if volume[i] == np.inf:
        return float(np.inf), origin, origin
    return float(volume[i]), origin + float(lo[i]) * axis, origin + float(hi[i]) * axis


def points(vertices) -> tuple[np.ndarray, np.ndarray, float]:
    """``(a, b, radius)``: a capsule containing every point of ``vertices (n, 3)``, searched for a small volume.

    The radius is computed from the final segment (every point's distance to it), plus ``MARGIN`` of the
    points' extent, so that no vertex is outside in float64. Fits are cached on disk
    (:mod:`diffkin.collision._fitcache`): one found there is used once it is checked to contain every point.
    """
    P = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64).reshape(-1, 3))
    return _fitcache.cached(P, settings(), _search, contains)


def settings() -> str:
    """What the fit of given points depends on besides them: its version, constants and whether scipy searches."""
    search = importlib.util.find_spec("scipy") is not None
    return f"{FIT_VERSION} grid={GRID} hull>{HULL_ABOVE} search={SEARCH if search else None} margin={MARGIN}"


def contains(P: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float) -> bool:
    """Whether every point of ``P (n, 3)`` is within ``radius`` of the segment ``[a, b]`` (float64)."""
    return bool(np.max(_point_segment(P, a, b), initial=0.0) <= radius)


def _search(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`points` without the cache."""
    P = np.unique(P, axis=0)
    if len(P) > HULL_ABOVE:  # the hull's vertices decide containment; fewer points make the search fast
        try:
            from scipy.spatial import ConvexHull

            P = P[ConvexHull(P).vertices]
        except Exception:  # flat or degenerate point sets, or no scipy: keep every point
            pass
    center = 0.5 * (P.min(axis=0) + P.max(axis=0))
    _, _, axes = np.linalg.svd(P - P.mean(axis=0), full_matrices=False)
    candidates = []
    for axis in axes:
        u, v = _perpendicular(axis)

        def volume(x, axis=axis, u=u, v=v):
            n = axis + x[0] * u + x[1] * v
            return _best_on_line(P, center + x[2] * u + x[3] * v, n / np.linalg.norm(n))[0]

        x = np.zeros(4)
        try:
            from scipy.optimize import minimize

            x = minimize(volume, x, method="Nelder-Mead", options=dict(SEARCH)).x
        except ImportError:  # no search without scipy: the principal axes through the box centre
            pass
        n = axis + x[0] * u + x[1] * v
        candidates.append(_best_on_line(P, center + x[2] * u + x[3] * v, n / np.linalg.norm(n)))
    _, a, b = min(candidates, key=lambda c: c[0])
    radius = float(np.max(_point_segment(P, a, b)))
    return a, b, radius + MARGIN * max(float(np.ptp(P, axis=0).max()), 1e-3)


def hull(vertices) -> tuple[np.ndarray, np.ndarray]:
    """``(points, faces)``: the convex hull of ``vertices (n, 3)``: its vertices and triangles (indices into them).

    A flat or degenerate point set (no volume) keeps its points, with no faces.
    """
    P = np.unique(np.asarray(vertices, dtype=np.float64).reshape(-1, 3), axis=0)
    try:
        from scipy.spatial import ConvexHull

        h = ConvexHull(P)
    except Exception:  # fewer than 4 points, a flat set, or no scipy
        return P, np.zeros((0, 3), np.int64)
    keep = h.vertices
    index = np.full(len(P), -1)
    index[keep] = np.arange(len(keep))
    return P[keep], index[h.simplices]


def _perpendicular(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def _point_segment(P: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    dd = float(d @ d)
    t = np.clip((P - a) @ d / dd, 0, 1) if dd > 0 else np.zeros(len(P))
    return np.linalg.norm(P - a - t[:, None] * d, axis=1)
