"""Data drawn over the robot: reachability maps as coloured points, a colour map, and obstacles as primitives."""

from __future__ import annotations

import dataclasses

import numpy as np

from diffkin.viewer._visuals import z_to

#: thickness of the slab that draws a half-space (its top face is the boundary plane), metres
PLANE_SLAB = 0.01

# viridis at five stops (matplotlib's values), interpolated linearly
_VIRIDIS = np.array(
    [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]]
)

QUANTITIES = ("counts", "manipulability", "dexterity")


def colormap(values: np.ndarray) -> np.ndarray:
    """``(n, 3)`` uint8 viridis colours of ``values`` scaled to their own min..max."""
    values = np.asarray(values, dtype=np.float64)
    lo, hi = (values.min(), values.max()) if values.size else (0.0, 1.0)
    t = (values - lo) / (hi - lo) if hi > lo else np.full_like(values, 0.5)
    x = t * (len(_VIRIDIS) - 1)
    i = np.clip(np.floor(x).astype(int), 0, len(_VIRIDIS) - 2)
    f = (x - i)[:, None]
    return np.round(255 * ((1 - f) * _VIRIDIS[i] + f * _VIRIDIS[i + 1])).astype(np.uint8)


def map_points(wmap, quantity: str = "counts") -> tuple[np.ndarray, np.ndarray]:
    """The centres of the reached voxels of a reachability map and their colours.

    Args:
        wmap: a ``dk.workspace.ReachabilityMap`` (or anything with ``counts``, ``manipulability``,
            ``dexterity`` ``(nx, ny, nz)``, ``origin (3,)`` and ``voxel_size``).
        quantity: ``counts``, ``manipulability`` or ``dexterity``: what the colour shows.

    Returns:
        ``points (n, 3)`` metres in the robot's base frame and ``colors (n, 3)`` uint8.
    """
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity: expected one of {QUANTITIES}, got {quantity!r}")
    counts = np.asarray(wmap.counts)
    index = np.argwhere(counts > 0)
    points = np.asarray(wmap.origin, dtype=np.float64) + (index + 0.5) * float(wmap.voxel_size)
    values = np.asarray(getattr(wmap, quantity), dtype=np.float64)[tuple(index.T)]
    return points, colormap(values)


@dataclasses.dataclass(frozen=True)
class Primitive:
    """One shape drawn for an obstacle.

    Attributes:
        name: its scene-tree path (``/obstacles/sphere0``, ``/obstacles/capsule1/a``, ...).
        kind: ``"sphere"`` (``size``: radius), ``"cylinder"`` (radius, height along its z axis),
            ``"box"`` (edge lengths along its x, y, z axes) or ``"mesh"`` (``mesh``).
        position: ``(3,)`` centre in the world, metres.
        rotation: ``(3, 3)`` orientation ``R_world_shape``.
        size: as ``kind`` says, metres.
        mesh: for ``"mesh"``: ``(vertices (n, 3), faces (m, 3))`` in the shape's frame.
    """

    name: str
    kind: str
    position: np.ndarray
    rotation: np.ndarray
    size: tuple[float, ...]
    mesh: tuple[np.ndarray, np.ndarray] | None = None


def shape_primitives(shapes, names: list[str]) -> list[Primitive]:
    """The primitives that draw solids (``dk.collision`` shapes: each kind stacked), in their own frame.

    A sphere is a sphere; a capsule a cylinder between its end points and a sphere at each end; a
    box a box; a cylinder a cylinder; a convex polytope the mesh of its hull.

    Args:
        shapes: the stacked kinds in the order of ``dk.collision``'s solids (spheres, capsules, boxes,
            cylinders, convex polytopes): a :class:`~diffkin.collision.World`'s, or a robot's
            :class:`~diffkin.collision.Geometry`'s ``shapes`` in the frames that carry them.
        names: the scene-tree path of each shape, in that order (a capsule's three primitives are
            ``<name>/axis``, ``<name>/a``, ``<name>/b``).
    """
    out: list[Primitive] = []
    eye = np.eye(3)

    def host(x) -> np.ndarray:
        return np.asarray(x, dtype=np.float64)

    spheres, capsules, boxes, cylinders, convexes = shapes
    paths = iter(names)
    for x, r in zip(host(spheres.center), host(spheres.radius), strict=True):
        out.append(Primitive(next(paths), "sphere", x, eye, (float(r),)))
    for a, e, r in zip(host(capsules.a), host(capsules.b), host(capsules.radius), strict=True):
        name, length = next(paths), float(np.linalg.norm(e - a))
        out.append(Primitive(f"{name}/axis", "cylinder", (a + e) / 2, z_to(e - a), (float(r), length)))
        out.append(Primitive(f"{name}/a", "sphere", a, eye, (float(r),)))
        out.append(Primitive(f"{name}/b", "sphere", e, eye, (float(r),)))
    for T, h in zip(host(boxes.pose), host(boxes.half_extents), strict=True):
        out.append(Primitive(next(paths), "box", T[:3, 3], T[:3, :3], tuple(float(v) for v in 2 * h)))
    for T, r, h in zip(host(cylinders.pose), host(cylinders.radius), host(cylinders.half_length), strict=True):
        out.append(Primitive(next(paths), "cylinder", T[:3, 3], T[:3, :3], (float(r), 2 * float(h))))
    for T, V in zip(host(convexes.pose), host(convexes.vertices), strict=True):
        out.append(Primitive(next(paths), "mesh", T[:3, 3], T[:3, :3], (), _hull_mesh(V)))
    return out


def _hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, faces)`` of the convex hull of ``points`` (a flat or tiny set: no faces)."""
    from diffkin.collision.interface import hull

    return hull(points)


def obstacle_primitives(world, center, extent: float) -> list[Primitive]:
    """The primitives that draw the obstacles of a ``dk.collision.World`` (:func:`shape_primitives`), and a
    half-space ``n . x <= offset`` as a square slab ``extent`` wide and :data:`PLANE_SLAB` thick whose top
    face is the boundary plane, centred below ``center``.

    Args:
        world: the obstacles (world frame).
        center: ``(3,)`` the point of the scene the slabs are centred on (projected on each plane).
        extent: edge length of the slabs, metres.
    """
    kinds = ("sphere", "capsule", "box", "cylinder", "convex")
    solids = world.kinds()[:-1]
    counts = [int(np.shape(getattr(shape, next(iter(type(shape).TRAILING))))[0]) for shape in solids]
    names = [f"/obstacles/{kind}{i}" for kind, n in zip(kinds, counts, strict=True) for i in range(n)]
    out = shape_primitives(solids, names)
    center = np.asarray(center, dtype=np.float64)
    normals, offsets = np.asarray(world.planes.normal, np.float64), np.asarray(world.planes.offset, np.float64)
    for i, (n, d) in enumerate(zip(normals, offsets, strict=True)):
        on_plane = center - (float(n @ center) - float(d)) * n
        position = on_plane - n * PLANE_SLAB / 2
        out.append(Primitive(f"/obstacles/plane{i}", "box", position, z_to(n), (extent, extent, PLANE_SLAB)))
    return out
