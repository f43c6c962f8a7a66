"""A robot's collision geometry: shapes on its frames, and the self-collision pairs to check.

:func:`load` reads the shapes of a URDF or MJCF file (:mod:`diffkin.collision._sources`) and
chooses the pairs: every pair of shapes except those of one body, of a body and its parent
(MJCF: MuJoCo's parent filter, which never filters against the world body; ``<option><flag
filterparent="disable">`` turns it off), MJCF pairs whose ``contype``/``conaffinity`` bits do not
meet, MJCF ``<contact><exclude>`` bodies, and the link pairs of SRDF ``<disable_collisions>``.
Bodies are the robot's moving bodies (fixed links merged onto the body they are fixed to, as
:func:`diffkin.load_robot` merges them, and as MuJoCo welds bodies without joints).
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _xml
from diffkin._pytree import pytree_dataclass, static
from diffkin.collision import _sources
from diffkin.collision._shapes import SOLIDS, Box, Capsule, Convex, Cylinder, Sphere
from diffkin.models.robot import Robot

KINDS = ("sphere", "capsule", "box", "cylinder", "convex")  # a Spec's kind, per class of SOLIDS


@pytree_dataclass
class Geometry:
    """A robot's collision shapes in the frames that carry them, and its self-collision pairs.

    Shapes are ordered by kind: every sphere, then every capsule, box, cylinder and convex polytope
    (the order of the ``S`` axis of :func:`diffkin.collision.world_distances`); :attr:`shape_names`
    names them.

    Attributes:
        shapes: each kind stacked (:data:`diffkin.collision._shapes.SOLIDS` order, possibly 0 of a
            kind), in the frame of each shape; also as :attr:`spheres`, :attr:`capsules`,
            :attr:`boxes`, :attr:`cylinders`, :attr:`convexes`.
        shape_frames: static, per shape, the index of its frame in ``robot.frame_names``.
        shape_names: static, per shape, its name in the file.
        shape_bodies: static, per shape, the name of its moving body (the first frame of that body).
        shape_links: static, per shape, the frame (URDF link, MJCF body) that carries it.
        pair_list: static, the self-collision pairs ``(i, j)``, ``i < j`` (see :attr:`pairs`).
        fits: static, per shape that was fitted (meshes, ellipsoids): ``(name, source, volume of the
            original (for a mesh: its convex hull), volume of the fit)``.
        shape_overshoot: static, per shape, :attr:`overshoot`.
    """

    shapes: tuple
    shape_frames: tuple[int, ...] = static()
    shape_names: tuple[str, ...] = static()
    shape_bodies: tuple[str, ...] = static()
    shape_links: tuple[str, ...] = static()
    pair_list: tuple[tuple[int, int], ...] = static()
    fits: tuple[tuple[str, str, float, float], ...] = static(default=())
    shape_overshoot: tuple[float, ...] = static(default=())

    spheres = property(lambda self: self.shapes[0])
    capsules = property(lambda self: self.shapes[1])
    boxes = property(lambda self: self.shapes[2])
    cylinders = property(lambda self: self.shapes[3])
    convexes = property(lambda self: self.shapes[4])

    @property
    def overshoot(self) -> np.ndarray:
        """``(S,)`` metres: per shape, how far its fit reaches beyond what it replaces (the largest distance
        from a point of the fitted shape to the mesh or shape of the file); 0 for exact primitives."""
        return np.array(self.shape_overshoot or (0.0,) * len(self.shape_names), dtype=np.float64)

    @property
    def pairs(self) -> np.ndarray:
        """``(P, 2)`` int: the shape indices of each self-collision pair."""
        return np.array(self.pair_list, dtype=np.int64).reshape(-1, 2)

    @property
    def pair_bodies(self) -> tuple[tuple[str, str], ...]:
        """Per pair, the names of the two shapes' bodies."""
        return tuple((self.shape_bodies[i], self.shape_bodies[j]) for i, j in self.pair_list)

    @property
    def counts(self) -> tuple[int, ...]:
        """Numbers of shapes of each kind (spheres, capsules, boxes, cylinders, convex polytopes)."""
        return tuple(int(np.shape(shape.pose if hasattr(shape, "pose") else shape.radius)[0]) for shape in self.shapes)

    def volume_overhead(self) -> dict[str, float]:
        """Per link with fitted shapes: the fits' total volume over the originals' (a ratio minus one, ``>= 0``)."""
        out: dict[str, list[float]] = {}
        links = dict(zip(self.shape_names, self.shape_links, strict=True))
        for name, _, original, fitted in self.fits:
            total = out.setdefault(links[name], [0.0, 0.0])
            total[0] += original
            total[1] += fitted
        return {link: fitted / original - 1.0 for link, (original, fitted) in out.items()}

    def replace_pairs(self, pairs: Iterable[tuple[int, int]]) -> Geometry:
        """A copy with other self-collision pairs (e.g. after :func:`diffkin.collision.sample_pairs`)."""
        return dataclasses.replace(
            self, pair_list=tuple(sorted((min(int(i), int(j)), max(int(i), int(j))) for i, j in pairs))
        )


def _stack(specs: list[_sources.Spec], kind: type, dtype):
    """The shapes of one kind stacked (none: an empty stack)."""
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.dtype(dtype)))  # noqa: E731  (cast on the host: no XLA program)
    P = [np.asarray(s.params, dtype=np.float64) for s in specs]
    if kind is Sphere:
        P_ = np.array(P).reshape(len(specs), 4)
        return Sphere(f(P_[:, :3]), f(P_[:, 3]))
    if kind is Capsule:
        P_ = np.array(P).reshape(len(specs), 7)
        return Capsule(f(P_[:, :3]), f(P_[:, 3:6]), f(P_[:, 6]))
    if kind is Box:
        P_ = np.array(P).reshape(len(specs), 19)
        return Box(f(P_[:, :16].reshape(-1, 4, 4)), f(P_[:, 16:19]))
    if kind is Cylinder:
        P_ = np.array(P).reshape(len(specs), 18)
        return Cylinder(f(P_[:, :16].reshape(-1, 4, 4)), f(P_[:, 16]), f(P_[:, 17]))
    # convex: params are the vertices in the frame; padded to the most with copies of the first
    most = max((len(p) // 3 for p in P), default=1)
    V = np.zeros((len(specs), most, 3))
    for i, p in enumerate(P):
        v = p.reshape(-1, 3)
        V[i] = np.concatenate([v, np.repeat(v[:1], most - len(v), axis=0)])
    return Convex(f(np.tile(np.eye(4), (len(specs), 1, 1))), f(V))


def _parent_bodies(robot: Robot) -> list[int | None]:
    """Per body, its parent body that carries frames (skipping the unnamed bodies between the joints
    of an MJCF body with several joints); ``None`` for the root."""
    real = set(robot.frame_bodies)
    out: list[int | None] = [None]
    for j in range(len(robot.parents)):
        p = robot.parents[j]
        while p not in real and p > 0:
            p = robot.parents[p - 1]
        out.append(p)
    return out


def _srdf_disabled(srdf, links: set[str]) -> set[frozenset[str]]:
    """Link pairs of ``<disable_collisions link1= link2=>`` of an SRDF (a path or the XML text), or of several.

    Raises a ValueError naming the file for XML that does not parse, a root other than ``<robot>``, a
    URDF given as the SRDF, an element without ``link1`` or ``link2``, and links the robot has no frame
    of (``links``: a misspelt name would otherwise disable nothing, silently).
    """
    if isinstance(srdf, (list, tuple)):
        return set().union(*(_srdf_disabled(s, links) for s in srdf))
    text = os.fspath(srdf)
    inline = text.lstrip().startswith("<")
    where = "srdf" if inline else f"srdf {text!r}"
    try:
        root = ET.fromstring(text) if inline else ET.parse(text).getroot()
    except ET.ParseError as err:
        raise ValueError(f"{where}: not well-formed XML ({err})") from None
    if root.tag != "robot":
        raise ValueError(f"{where}: expected a <robot> root element (SRDF), got <{root.tag}>")
    if root.find("link") is not None or root.find("joint") is not None:
        raise ValueError(f"{where}: has <link>/<joint> elements: a URDF, not an SRDF (pass the SRDF as srdf=)")
    pairs = set()
    for k, el in enumerate(root.iter("disable_collisions")):
        names = (el.get("link1"), el.get("link2"))
        if None in names:
            raise ValueError(f"{where}: <disable_collisions> {k} needs link1 and link2, got {dict(el.attrib)}")
        unknown = [n for n in names if n not in links]
        if unknown:
            raise ValueError(
                f"{where}: <disable_collisions link1={names[0]!r} link2={names[1]!r}>: the robot has no link "
                f"{unknown[0]!r} ({len(links)} links, e.g. {sorted(links)[:4]})"
            )
        pairs.add(frozenset((str(names[0]), str(names[1]))))
    return pairs


def load(source, robot: Robot, *, meshes: str = "capsules", srdf=None, dtype=None) -> Geometry:
    """The collision geometry of a robot from the file it was loaded from.

    Args:
        source: the URDF or MJCF (path or XML text) that ``robot`` was loaded from
            (:func:`diffkin.load_robot`): its ``<collision>`` elements (URDF) or geoms (MJCF; those
            of the world body itself are the environment and are left out, as are geoms with
            ``contype = conaffinity = 0``).
        robot: the :class:`diffkin.Robot`: shapes are placed on its frames.
        meshes: the model's tightness. ``"capsules"`` (default): every mesh and cylinder becomes
            one capsule that contains it (cheap distances, loose: :attr:`Geometry.overshoot`);
            ``"hulls"``: every mesh becomes its convex hull (:class:`Convex`, as MuJoCo collides
            meshes: as tight as the mesh where it is convex) and every cylinder an exact
            :class:`Cylinder` (their distances go through the general convex distance, whose
            programs take longer to compile). Spheres, capsules and boxes are exact; an ellipsoid
            becomes a capsule that contains it.
        srdf: an SRDF (path or XML text) whose ``<disable_collisions>`` link pairs are not checked,
            or a list of them (the file's own and one from :func:`diffkin.collision.sample_pairs`).
        dtype: float dtype of the arrays (default: JAX's default float).

    Returns:
        The :class:`Geometry`.

    Raises:
        TypeError, ValueError: a source that is not a robot description, a shape on a frame the
            robot lacks, unsupported geometry (named), or an unknown ``meshes``.
        ImportError: the file has meshes and trimesh is missing (the ``diffkin[collision]`` extra).
    """
    if meshes not in ("hulls", "capsules"):
        raise ValueError(f"meshes: expected 'hulls' or 'capsules', got {meshes!r}")
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected a diffkin.Robot (dk.load_robot), got {type(robot).__name__}")
    root, path = _xml.read(source)
    excludes: set[frozenset[str]] = set()
    filterparent, mjcf = True, root.tag == "mujoco"
    if root.tag == "robot":
        specs = _sources.urdf_specs(root, os.path.dirname(path) if path else None, meshes)
    elif mjcf:
        specs, excludes, filterparent = _sources.mjcf_specs(root, path, meshes)
    else:
        raise ValueError(f"source: expected a <robot> (URDF) or <mujoco> (MJCF) root element, got <{root.tag}>")
    disabled = _srdf_disabled(srdf, set(robot.frame_names)) if srdf is not None else set()
    order = sorted(range(len(specs)), key=lambda i: KINDS.index(specs[i].kind))
    specs = [specs[i] for i in order]
    frames = [robot.frame_index(s.frame) for s in specs]
    bodies = [robot.frame_bodies[f] for f in frames]
    body_names: dict[int, str] = {}
    for name, b in zip(robot.frame_names, robot.frame_bodies, strict=True):
        body_names.setdefault(b, name)
    parent = _parent_bodies(robot)
    world = 0 if mjcf and not robot.floating else None  # MuJoCo never parent-filters against the world
    pairs = []
    for i in range(len(specs)):
        for j in range(i + 1, len(specs)):
            bi, bj = bodies[i], bodies[j]
            if bi == bj:
                continue
            if filterparent and (parent[bi] == bj or parent[bj] == bi) and world not in (bi, bj):
                continue
            if mjcf:
                si, sj = specs[i], specs[j]
                if not (si.contype & sj.conaffinity or sj.contype & si.conaffinity):
                    continue
                if frozenset((si.body, sj.body)) in excludes:
                    continue
            if frozenset((specs[i].frame, specs[j].frame)) in disabled:
                continue
            pairs.append((i, j))
    dtype = dtype or jnp.result_type(float)
    return Geometry(
        tuple(
            _stack([s for s in specs if s.kind == name], cls, dtype) for name, cls in zip(KINDS, SOLIDS, strict=True)
        ),
        shape_frames=tuple(frames),
        shape_names=tuple(s.name for s in specs),
        shape_bodies=tuple(body_names[b] for b in bodies),
        shape_links=tuple(s.frame for s in specs),
        pair_list=tuple(pairs),
        fits=tuple((s.name, s.source, float(s.volume), float(s.fitted_volume)) for s in specs if s.source != s.kind),
        shape_overshoot=tuple(float(s.overshoot) for s in specs),
    )


def placed(robot: Robot, geom: Geometry, q, base=None) -> tuple:
    """The shapes in the world at ``q``: each kind with batch axes ``(..., n_kind)``."""
    from diffkin.kinematics import link_poses

    return moved(geom, link_poses(robot, q, base=base), geom.shape_frames)


def moved(geom: Geometry, T_world_frames: jax.Array, slots) -> tuple:
    """The shapes placed by their frames' poses ``T_world_frames`` ``(..., F, 4, 4)``, shape ``s`` by
    ``T_world_frames[..., slots[s]]``: each kind with batch axes ``(..., n_kind)``."""
    idx = np.asarray(slots, dtype=np.int64)
    starts = np.cumsum((0, *geom.counts))
    return tuple(
        shape.moved_by(T_world_frames[..., idx[lo:hi], :, :])
        for shape, lo, hi in zip(geom.shapes, starts[:-1], starts[1:], strict=True)
    )
