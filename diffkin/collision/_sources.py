"""Collision shapes of robot description files: URDF ``<collision>`` elements and MJCF ``<geom>``s (host).

Each element becomes one :class:`Spec`: a sphere, capsule, box, cylinder or convex polytope in the
frame of the link (URDF) or body (MJCF) that carries it. Spheres, boxes, capsules and cylinders are
kept exactly; a mesh becomes its convex hull (``meshes="hulls"``) or a capsule that contains it
(``meshes="capsules"``), an ellipsoid a capsule that contains it (:mod:`diffkin.collision._fit`),
with the volume of the original and of the fit recorded and how far the fit reaches beyond the
original (:mod:`diffkin.collision._overshoot`). Meshes are read with trimesh (the
``diffkin[collision]`` extra), imported only when a mesh file's fit is not in the cache on disk
(:mod:`diffkin.collision._fitcache`: keyed by the file's bytes, scale, placement, the fit asked for
and :func:`mesh_settings`).
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET

import numpy as np

from diffkin._meshfiles import resolve_mesh
from diffkin.collision import _fit, _fitcache, _overshoot
from diffkin.models.urdf import rpy_matrix

_MJCF_KINDS = ("sphere", "capsule", "box", "cylinder", "ellipsoid", "mesh")
# The version of a mesh file's fit (:func:`fitted`, its overshoot, the mesh reader's use): part of each cached
# mesh fit's key with :func:`mesh_settings`. Change it with any change there that changes results.
MESH_VERSION = "mesh-1"


@dataclasses.dataclass(frozen=True)
class Spec:
    """One collision shape on a frame of the robot.

    Attributes:
        name: the element's name (URDF ``<collision name=>``, else ``link_k``: the k-th collision
            element of the link, as Pinocchio names them; MJCF ``<geom name=>``, else ``geomN``).
        frame: the frame (URDF link, MJCF body) that carries it.
        kind: ``"sphere"``, ``"capsule"``, ``"box"``, ``"cylinder"`` or ``"convex"`` (what it is now).
        source: what the file says (``"cylinder"``, ``"mesh"``, ... or the same as ``kind``).
        params: ``sphere``: centre (3), radius; ``capsule``: a (3), b (3), radius; ``box``: pose
            ``T_frame_box`` (16, row major), half extents (3); ``cylinder``: pose (16), radius, half
            length; ``convex``: its vertices (3 each); all in the frame, metres.
        volume: the original shape's volume (for a mesh: its convex hull's), m^3.
        fitted_volume: the volume of the shape kept (equal to ``volume`` when exact).
        contype, conaffinity: MJCF collision bits (URDF: 1, 1).
        body: MJCF body name (for ``<exclude>``), or the URDF link name.
        overshoot: metres, how far the shape reaches beyond the original (0 when exact).
    """

    name: str
    frame: str
    kind: str
    source: str
    params: tuple[float, ...]
    volume: float
    fitted_volume: float
    contype: int = 1
    conaffinity: int = 1
    body: str = ""
    overshoot: float = 0.0


# --------------------------------------------------------------------------------------- shapes


def _transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def _capsule(name, frame, source, T, radius, half_length, volume, **kw) -> Spec:
    """A capsule along the z axis of ``T`` (in the frame)."""
    a = _transform(T, np.array([0.0, 0.0, -half_length]))
    b = _transform(T, np.array([0.0, 0.0, half_length]))
    fitted = _fit.capsule_volume(radius, 2 * half_length)
    return Spec(name, frame, "capsule", source, (*a, *b, radius), volume, fitted, **kw)


def _primitive(name: str, frame: str, kind: str, T: np.ndarray, size, fit: str, **kw) -> Spec:
    """A shape centred at ``T`` (its axis z): sphere ``(r,)``, capsule/cylinder ``(r, half length)``,
    box ``(3 half extents)``, ellipsoid ``(3 semi-axes)``. A cylinder is exact when ``fit`` is
    ``"hulls"`` (the tight model), else the smallest capsule on its axis that contains it."""
    size = np.asarray(size, dtype=np.float64)
    if np.any(size < 0) or not np.all(np.isfinite(size)):
        raise ValueError(f"collision shape {name!r} on {frame!r}: expected finite sizes >= 0, got {size.tolist()}")
    if kind == "sphere":
        r = float(size[0])
        v = 4 / 3 * np.pi * r**3
        return Spec(name, frame, "sphere", kind, (*T[:3, 3], r), v, v, **kw)
    if kind == "capsule":
        return _capsule(name, frame, kind, T, float(size[0]), float(size[1]), None, **kw)
    if kind == "box":
        v = 8 * float(np.prod(size[:3]))
        return Spec(name, frame, "box", kind, (*T.reshape(-1), *size[:3]), v, v, **kw)
    if kind == "cylinder":
        r, h = float(size[0]), float(size[1])
        v = 2 * np.pi * r * r * h
        if fit == "hulls":
            return Spec(name, frame, "cylinder", kind, (*T.reshape(-1), r, h), v, v, **kw)
        R, L = _fit.cylinder(r, h)
        spec = _capsule(name, frame, kind, T, R, L, v, **kw)
        return dataclasses.replace(spec, overshoot=_fit.cylinder_overshoot(r, h, R, L))
    if kind == "ellipsoid":
        k, R, L = _fit.ellipsoid(size[:3])
        axes = np.roll(np.eye(3), 2 - k, axis=1)  # columns: x, y, z of a frame whose z is axis k
        Tk = T.copy()
        Tk[:3, :3] = T[:3, :3] @ axes
        spec = _capsule(name, frame, kind, Tk, R, L, 4 / 3 * np.pi * float(np.prod(size[:3])), **kw)
        # a bound: every point of the capsule is within R + L of the centre, the ball of the smallest semi-axis inside
        return dataclasses.replace(spec, overshoot=R + L - float(np.min(size[:3])))
    raise AssertionError(kind)


def _fix_volume(spec: Spec) -> Spec:
    if spec.volume is None:  # an exact capsule
        return dataclasses.replace(spec, volume=spec.fitted_volume)
    return spec


def fitted(name: str, frame: str, vertices: np.ndarray, faces: np.ndarray | None, meshes: str, **kw) -> Spec:
    """The fit of a mesh (``vertices (n, 3)`` in the frame, triangles ``faces (m, 3)``, or ``None``: the shape
    is the hull of the points, as MuJoCo takes a mesh geom): its hull or a capsule, with its overshoot."""
    hull_points, hull_faces = _fit.hull(vertices)
    closed = faces is not None and len(faces) > 0 and len(hull_faces) > 0
    if meshes == "hulls":
        overshoot = 0.0
        if closed and faces is not None:
            bridging = _overshoot.new_faces(hull_points, hull_faces, vertices, faces)
            if len(bridging):
                samples = _overshoot.polytope_samples(hull_points, bridging)
                overshoot = float(np.max(_overshoot.to_solid(samples, vertices, faces)))
        volume = _hull_volume(hull_points)
        return Spec(
            name, frame, "convex", "mesh", tuple(hull_points.reshape(-1)), volume, volume, overshoot=overshoot, **kw
        )
    a, b, r = _fit.points(vertices)
    samples = _overshoot.capsule_samples(a, b, r)
    if closed and faces is not None:
        overshoot = float(np.max(_overshoot.to_solid(samples, vertices, faces)))
    else:
        overshoot = float(np.max(_overshoot.to_solid(samples, hull_points, hull_faces))) if len(hull_faces) else r
    volume = _fit.capsule_volume(r, float(np.linalg.norm(b - a)))
    return Spec(
        name, frame, "capsule", "mesh", (*a, *b, r), _hull_volume(hull_points), volume, overshoot=overshoot, **kw
    )


def _mesh(name: str, frame: str, T: np.ndarray, path: str | None, reference: str, scale, meshes: str, **kw) -> Spec:
    """The fit of a mesh file (:func:`fitted`), placed by ``T`` and scaled by ``scale``: read from the cache on
    disk when it holds this file's (no mesh read), else computed and stored (:func:`_fitcache.cached_mesh`)."""
    if path is None:
        raise ValueError(f"collision mesh {reference!r} of {name!r} on {frame!r}: file not found")
    scale = np.asarray(scale, dtype=np.float64)

    def fit() -> _fitcache.MeshFit:
        vertices, faces = _read_mesh(path)
        spec = fitted(name, frame, _transform(T, vertices * scale), faces, meshes)
        return spec.kind, np.asarray(spec.params, np.float64), spec.volume, spec.fitted_volume, spec.overshoot

    kind, params, volume, fitted_volume, overshoot = _fitcache.cached_mesh(path, scale, T, meshes, mesh_settings(), fit)
    return Spec(name, frame, kind, "mesh", tuple(params.tolist()), volume, fitted_volume, overshoot=overshoot, **kw)


def mesh_settings() -> str:
    """What a mesh file's fit depends on besides the file, scale, placement and ``meshes``: :data:`MESH_VERSION`,
    the overshoot's sampling and the capsule fit's settings (:func:`_fit.settings`: scipy's presence too)."""
    return f"{MESH_VERSION} face_steps={_overshoot.FACE_STEPS} {_fit.settings()}"


def _read_mesh(path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (n, 3), faces (m, 3))`` of a mesh file."""
    try:
        import trimesh
    except ImportError as err:
        raise ImportError(
            f'reading collision meshes needs trimesh: pip install "diffkin[collision]" ({path}: {err})'
        ) from err
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as err:  # formats trimesh cannot read here (e.g. DAE without pycollada)
        raise ValueError(f"collision mesh {path!r}: trimesh cannot read it ({err})") from err
    vertices = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if vertices.size == 0:
        raise ValueError(f"collision mesh {path!r}: no vertices")
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    return vertices, faces


def _hull_volume(vertices: np.ndarray) -> float:
    try:
        from scipy.spatial import ConvexHull

        return float(ConvexHull(vertices).volume)
    except Exception:  # no scipy, or a flat mesh
        return float("nan")


# ------------------------------------------------------------------------------------------ URDF


def _numbers(el: ET.Element | None, attribute: str, count: int, default: str, where: str) -> np.ndarray:
    text = el.get(attribute, default) if el is not None else default
    try:
        values = np.array([float(x) for x in text.split()], dtype=np.float64)
    except ValueError:
        values = np.zeros(0)
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{where} {attribute}: expected {count} finite numbers, got {text!r}")
    return values


def urdf_specs(root: ET.Element, base_dir: str | None, meshes: str) -> list[Spec]:
    """Every ``<link><collision>`` of a URDF (sphere, box, cylinder, capsule, mesh), in document order."""
    specs = []
    for link in root.findall("link"):
        frame = link.get("name", "")
        for k, collision in enumerate(link.findall("collision")):
            name = collision.get("name") or f"{frame}_{k}"
            where = f"URDF <link name={frame!r}> <collision> {k}"
            origin = collision.find("origin")
            T = np.eye(4)
            T[:3, :3] = rpy_matrix(_numbers(origin, "rpy", 3, "0 0 0", where))
            T[:3, 3] = _numbers(origin, "xyz", 3, "0 0 0", where)
            geometry = collision.find("geometry")
            shape = geometry[0] if geometry is not None and len(geometry) else None
            if shape is None:
                raise ValueError(f"{where}: missing <geometry>")
            kw = {"body": frame}
            if shape.tag == "sphere":
                spec = _primitive(name, frame, "sphere", T, _numbers(shape, "radius", 1, "", where), meshes, **kw)
            elif shape.tag == "box":
                spec = _primitive(name, frame, "box", T, 0.5 * _numbers(shape, "size", 3, "", where), meshes, **kw)
            elif shape.tag in ("cylinder", "capsule"):
                r = _numbers(shape, "radius", 1, "", where)[0]
                length = _numbers(shape, "length", 1, "", where)[0]
                spec = _primitive(name, frame, shape.tag, T, (r, 0.5 * length), meshes, **kw)
            elif shape.tag == "mesh":
                reference = shape.get("filename", "")
                path = resolve_mesh(reference, base_dir)
                scale = _numbers(shape, "scale", 3, "1 1 1", where)
                spec = _mesh(name, frame, T, path, reference, scale, meshes, **kw)
            else:
                raise ValueError(f"{where}: <{shape.tag}> is not a supported collision geometry")
            specs.append(_fix_volume(spec))
    return specs


# ------------------------------------------------------------------------------------------ MJCF


def _inline_vertices(text: str, where: str) -> np.ndarray:
    """``(n, 3)`` the points of an MJCF mesh's ``vertex`` attribute: finite numbers, three per point, at least 4."""
    words = text.split()
    try:
        values = np.array([float(x) for x in words], dtype=np.float64)
    except ValueError:
        bad = next(w for w in words if not _is_number(w))
        raise ValueError(f"{where} vertex: expected numbers, got {bad[:40]!r}") from None
    if values.size % 3 or values.size < 12:
        raise ValueError(f"{where} vertex: expected at least 4 points of 3 numbers each, got {values.size} numbers")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{where} vertex: expected finite numbers, got {values[~np.isfinite(values)][0]}")
    return values.reshape(-1, 3)


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def mjcf_specs(root: ET.Element, path: str | None, fit: str) -> tuple[list[Spec], set[frozenset[str]], bool]:
    """The geoms of an MJCF's bodies (world-body geoms are the environment, left out).

    Returns:
        The specs; the ``<contact><exclude>`` body pairs; whether MuJoCo's parent filter is on
        (``<option><flag filterparent>``, default enabled).
    """
    from diffkin.models import mjcf  # the model reader's walk of the bodies, its default classes and orientations

    reader, body_geoms = mjcf.body_geoms(root, path)
    compiler = root.find("compiler")
    base_dir = os.path.dirname(path) if path else None
    meshdir = compiler.get("meshdir", compiler.get("assetdir", "")) if compiler is not None else ""
    mesh_dir = os.path.join(base_dir, meshdir) if base_dir is not None else (meshdir or None)
    assets: dict[str, tuple[str | None, str, np.ndarray, np.ndarray | None]] = {}
    for asset in root.findall("asset"):
        for mesh in asset.findall("mesh"):
            cls = reader.class_of(mesh, "main")
            file = mesh.get("file")
            name = mesh.get("name") or (os.path.splitext(os.path.basename(file))[0] if file else "")
            scale = _numbers(None, "scale", 3, reader.attribute(mesh, "scale", cls, "1 1 1") or "1 1 1", "MJCF mesh")
            vertex = mesh.get("vertex")
            inline = (
                _inline_vertices(vertex, f"MJCF <mesh name={name!r}>{f' of {path!r}' if path else ''}")
                if vertex
                else None
            )
            assets[name] = (resolve_mesh(file, mesh_dir) if file else None, file or name, scale, inline)
    specs: list[Spec] = []

    def geom(g: mjcf.BodyGeom) -> None:
        el, body = g.element, g.body
        cls = reader.class_of(el, g.cls)
        name = el.get("name") or f"geom{g.id}"
        where = f"MJCF <geom name={name!r}> on body {body!r}"
        contype = int(reader.attribute(el, "contype", cls, "1") or 1)
        conaffinity = int(reader.attribute(el, "conaffinity", cls, "1") or 1)
        if contype == 0 and conaffinity == 0:
            return  # visual only: MuJoCo never collides it
        kind = reader.attribute(el, "type", cls, "sphere") or "sphere"
        if kind not in _MJCF_KINDS:
            raise ValueError(f"{where}: type {kind!r} is not supported on a moving body (supported: {_MJCF_KINDS})")
        size_text = reader.attribute(el, "size", cls, "0 0 0") or "0 0 0"
        size = np.array([float(x) for x in size_text.split()] + [0.0, 0.0, 0.0])[:3]
        fromto = reader.attribute(el, "fromto", cls)
        T = np.eye(4)
        if fromto is not None and kind != "mesh":
            ends = _numbers(None, "fromto", 6, fromto, where)
            T[:3, :3] = (
                mjcf.zaxis(ends[:3] - ends[3:], f"{where} fromto") if np.any(ends[:3] != ends[3:]) else np.eye(3)
            )
            T[:3, 3] = 0.5 * (ends[:3] + ends[3:])
            half = 0.5 * float(np.linalg.norm(ends[3:] - ends[:3]))
            size = (
                np.array([size[0], half, 0.0])
                if kind in ("capsule", "cylinder")
                else np.array([size[0], size[1], half])
            )
        else:
            T[:3, :3] = reader.rotation(el, cls)
            T[:3, 3] = _numbers(None, "pos", 3, reader.attribute(el, "pos", cls, "0 0 0") or "0 0 0", where)
        T = g.T_body_container @ T
        kw: dict = {"contype": contype, "conaffinity": conaffinity, "body": body}
        if kind == "mesh":
            mesh_name = reader.attribute(el, "mesh", cls) or ""
            if mesh_name not in assets:
                raise ValueError(f"{where}: unknown mesh {mesh_name!r}")
            mesh_path, reference, scale, inline = assets[mesh_name]
            if inline is not None:  # MuJoCo collides with the hull of the points
                spec = fitted(name, body, _transform(T, inline * scale), None, fit, **kw)
            else:
                spec = _mesh(name, body, T, mesh_path, reference, scale, fit, **kw)
        else:
            spec = _primitive(name, body, kind, T, size, fit, **kw)
        specs.append(_fix_volume(spec))

    for g in body_geoms:
        geom(g)
    excludes = set()
    for contact in root.findall("contact"):
        for ex in contact.findall("exclude"):
            excludes.add(frozenset((ex.get("body1", ""), ex.get("body2", ""))))
    flags = [f for option in root.findall("option") for f in option.findall("flag")]
    filterparent = all(f.get("filterparent", "enable") == "enable" for f in flags)
    return specs, excludes, filterparent
