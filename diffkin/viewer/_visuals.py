"""Visual geometry of robot description files: URDF ``<visual>`` and MJCF ``<geom>`` elements.

Reads, per frame (URDF link or MJCF body), the shapes to draw with their pose in that frame, and
loads mesh files through trimesh (paths resolved by :func:`diffkin._meshfiles.resolve_mesh`).
Nothing here is differentiable: it only feeds the viewer.
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET

import numpy as np

from diffkin._meshfiles import resolve_mesh
from diffkin.models.urdf import rpy_matrix

DEFAULT_RGBA = (0.72, 0.74, 0.78, 1.0)


@dataclasses.dataclass(frozen=True)
class Visual:
    """One shape attached to a frame.

    Attributes:
        frame: name of the frame (URDF link or MJCF body) that carries the shape.
        T_frame_visual: ``(4, 4)`` pose of the shape in that frame.
        kind: ``"mesh"``, ``"box"``, ``"cylinder"``, ``"sphere"`` or ``"capsule"``.
        size: ``box``: ``(x, y, z)`` edge lengths; ``cylinder``/``capsule``: ``(radius, length)``
            along the shape's z axis; ``sphere``: ``(radius,)``; ``mesh``: ``(sx, sy, sz)`` scale.
        filename: the mesh reference as written in the file (``mesh`` only).
        path: the resolved mesh file, or ``None`` if it could not be found.
        rgba: colour, components in ``[0, 1]``.
    """

    frame: str
    T_frame_visual: np.ndarray
    kind: str
    size: tuple[float, ...]
    filename: str | None = None
    path: str | None = None
    rgba: tuple[float, float, float, float] = DEFAULT_RGBA


def _floats(text: str | None, count: int, default: tuple[float, ...]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=np.float64)
    values = np.array([float(x) for x in text.split()], dtype=np.float64)
    if values.shape != (count,):
        raise ValueError(f"expected {count} numbers, got {text!r}")
    return values


def _quat(wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = wxyz / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def urdf_visuals(root: ET.Element, base_dir: str | None) -> list[Visual]:
    """Every ``<link><visual>`` of a URDF, with named ``<material>`` colours resolved."""
    colors: dict[str, tuple] = {}
    for named in root.findall("material"):
        named_color, name = named.find("color"), named.get("name")
        if name and named_color is not None:
            colors[name] = tuple(_floats(named_color.get("rgba"), 4, DEFAULT_RGBA))
    visuals = []
    for link in root.findall("link"):
        for visual in link.findall("visual"):
            origin = visual.find("origin")
            T = _pose(
                rpy_matrix(_floats(origin.get("rpy") if origin is not None else None, 3, (0, 0, 0))),
                _floats(origin.get("xyz") if origin is not None else None, 3, (0, 0, 0)),
            )
            rgba = DEFAULT_RGBA
            material = visual.find("material")
            if material is not None:
                color = material.find("color")
                if color is not None:
                    rgba = tuple(_floats(color.get("rgba"), 4, DEFAULT_RGBA))
                else:
                    rgba = colors.get(material.get("name", ""), DEFAULT_RGBA)
            geometry = visual.find("geometry")
            shape = geometry[0] if geometry is not None and len(geometry) else None
            if shape is None:
                continue
            frame = link.get("name", "")
            if shape.tag == "mesh":
                filename = shape.get("filename", "")
                visuals.append(
                    Visual(
                        frame,
                        T,
                        "mesh",
                        tuple(_floats(shape.get("scale"), 3, (1, 1, 1))),
                        filename,
                        resolve_mesh(filename, base_dir),
                        rgba,
                    )
                )
            elif shape.tag == "box":
                visuals.append(Visual(frame, T, "box", tuple(_floats(shape.get("size"), 3, (0, 0, 0))), rgba=rgba))
            elif shape.tag in ("cylinder", "capsule"):
                size = (float(shape.get("radius", 0)), float(shape.get("length", 0)))
                visuals.append(Visual(frame, T, shape.tag, size, rgba=rgba))
            elif shape.tag == "sphere":
                visuals.append(Visual(frame, T, "sphere", (float(shape.get("radius", 0)),), rgba=rgba))
    return visuals


def mjcf_visuals(root: ET.Element, base_dir: str | None) -> list[Visual]:
    """The ``<geom>`` elements of an MJCF ``<worldbody>`` tree, each on its body (``world`` for the world body).

    Supports ``pos``, ``quat`` and ``euler`` (radians, ``xyz`` sequence) orientations, the
    ``box``, ``sphere``, ``cylinder``, ``capsule`` and ``mesh`` types with ``size`` or
    ``fromto``, ``rgba``, and ``<asset><mesh file= scale=>`` with ``<compiler meshdir=>``.
    Defaults classes are not expanded (geoms keep their own attributes only); geoms of
    collision-only groups (``group`` 3 and above) are skipped.
    """
    compiler = root.find("compiler")
    meshdir = compiler.get("meshdir", "") if compiler is not None else ""
    mesh_dir = os.path.join(base_dir, meshdir) if base_dir is not None else (meshdir or None)
    meshes = {}
    for asset in root.findall("asset"):
        for mesh in asset.findall("mesh"):
            file = mesh.get("file")
            if file:
                name = mesh.get("name") or os.path.splitext(os.path.basename(file))[0]
                meshes[name] = (file, resolve_mesh(file, mesh_dir), tuple(_floats(mesh.get("scale"), 3, (1, 1, 1))))
    visuals: list[Visual] = []

    def add_geoms(body: ET.Element, name: str) -> None:
        for geom in body.findall("geom"):
            if int(geom.get("group", "0")) >= 3:
                continue
            kind = geom.get("type", "sphere")
            rgba = tuple(_floats(geom.get("rgba"), 4, DEFAULT_RGBA))
            size = _floats(geom.get("size"), len(geom.get("size", "").split()), ()) if geom.get("size") else None
            R, p = np.eye(3), _floats(geom.get("pos"), 3, (0, 0, 0))
            if geom.get("quat"):
                R = _quat(_floats(geom.get("quat"), 4, (1, 0, 0, 0)))
            elif geom.get("euler"):
                a, b, c = _floats(geom.get("euler"), 3, (0, 0, 0))
                R = rpy_matrix(np.array([a, 0, 0])) @ rpy_matrix(np.array([0, b, 0])) @ rpy_matrix(np.array([0, 0, c]))
            length = None
            if geom.get("fromto") and kind in ("capsule", "cylinder", "box"):
                ends = _floats(geom.get("fromto"), 6, (0,) * 6)
                axis = ends[3:] - ends[:3]
                length = float(np.linalg.norm(axis))
                p = (ends[:3] + ends[3:]) / 2
                R = z_to(axis)
            mesh = geom.get("mesh", "")
            if kind == "mesh" and mesh in meshes:
                file, path, scale = meshes[mesh]
                visuals.append(Visual(name, _pose(R, p), "mesh", scale, file, path, rgba))
            elif kind == "box" and size is not None and size.size >= 3:
                visuals.append(Visual(name, _pose(R, p), "box", tuple(2 * size[:3]), rgba=rgba))
            elif kind == "sphere" and size is not None:
                visuals.append(Visual(name, _pose(R, p), "sphere", (float(size[0]),), rgba=rgba))
            elif kind in ("capsule", "cylinder") and size is not None:
                half = length / 2 if length is not None else float(size[1]) if size.size > 1 else 0.0
                visuals.append(Visual(name, _pose(R, p), kind, (float(size[0]), 2 * half), rgba=rgba))

    todo = [(worldbody, "world") for worldbody in reversed(root.findall("worldbody"))]
    while todo:  # depth first in document order, with a stack: any nesting depth
        body, name = todo.pop()
        add_geoms(body, name)
        todo.extend((child, child.get("name", "")) for child in reversed(body.findall("body")))
    return visuals


def z_to(direction: np.ndarray) -> np.ndarray:
    """A rotation taking the z axis to ``direction`` (the identity for a zero vector)."""
    n = np.linalg.norm(direction)
    if n < 1e-12:
        return np.eye(3)
    z = direction / n
    helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def read_visuals(source) -> list[Visual]:
    """The visuals of a URDF or MJCF file (a path or the XML text)."""
    text = os.fspath(source)
    base_dir = None
    if text.lstrip().startswith("<"):
        root = ET.fromstring(text)
    else:
        root = ET.parse(text).getroot()
        base_dir = os.path.dirname(os.path.abspath(text))
    if root.tag == "robot":
        return urdf_visuals(root, base_dir)
    if root.tag == "mujoco":
        return mjcf_visuals(root, base_dir)
    raise ValueError(f"source: expected a <robot> (URDF) or <mujoco> (MJCF) root element, got <{root.tag}>")


def load_trimesh(visual: Visual):
    """The ``trimesh.Trimesh`` of a visual (scaled, coloured), or ``None`` if its mesh cannot be read."""
    import trimesh

    if visual.kind == "box":
        mesh = trimesh.creation.box(extents=visual.size)
    elif visual.kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=visual.size[0])
    elif visual.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=visual.size[0], height=visual.size[1], sections=24)
    elif visual.kind == "capsule":
        mesh = trimesh.creation.capsule(radius=visual.size[0], height=visual.size[1], count=(12, 24))
    else:
        if visual.path is None:
            return None
        try:
            mesh = trimesh.load(visual.path, force="mesh")
        except Exception:  # a format trimesh cannot read here (e.g. DAE without pycollada)
            return None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            return None
        mesh.apply_scale(np.asarray(visual.size, dtype=np.float64))
        kind = getattr(mesh.visual, "kind", None)
        if kind in ("texture", "vertex") or (kind == "face" and visual.rgba == DEFAULT_RGBA):
            return mesh  # the file's own colours
    rgba = np.round(np.asarray(visual.rgba) * 255).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=rgba)
    return mesh
