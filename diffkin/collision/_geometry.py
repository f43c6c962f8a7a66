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

from diffkin._pytree import pytree_dataclass, static
from diffkin.collision import _sources
from diffkin.collision._shapes import Box, Capsule, Sphere, unchecked
from diffkin.models.robot import Robot

KINDS = ("sphere", "capsule", "box")


@pytree_dataclass
class Geometry:
    """A robot's collision shapes in the frames that carry them, and its self-collision pairs.

    Shapes are ordered by kind: every sphere, then every capsule, then every box (the order of
    the ``S`` axis of :func:`diffkin.collision.world_distances`); :attr:`shape_names` names them.

    Attributes:
        spheres: :class:`Sphere` ``(n_spheres,)``, centres in the frame of each shape.
        capsules: :class:`Capsule` ``(n_capsules,)``, end points in the frame of each shape.
        boxes: :class:`Box` ``(n_boxes,)``, poses ``T_frame_box``.
        shape_frames: static, per shape, the index of its frame in ``robot.frame_names``.
        shape_names: static, per shape, its name in the file.
        shape_bodies: static, per shape, the name of its moving body (the first frame of that body).
        shape_links: static, per shape, the frame (URDF link, MJCF body) that carries it.
        pair_list: static, the self-collision pairs ``(i, j)``, ``i < j`` (see :attr:`pairs`).
        fits: static, per shape that was fitted (cylinders, ellipsoids, meshes): ``(name, source,
            volume of the original (for a mesh: its convex hull), volume of the capsule)``.
    """

    spheres: Sphere
    capsules: Capsule
    boxes: Box
    shape_frames: tuple[int, ...] = static()
    shape_names: tuple[str, ...] = static()
    shape_bodies: tuple[str, ...] = static()
    shape_links: tuple[str, ...] = static()
    pair_list: tuple[tuple[int, int], ...] = static()
    fits: tuple[tuple[str, str, float, float], ...] = static(default=())

    @property
    def pairs(self) -> np.ndarray:
        """``(P, 2)`` int: the shape indices of each self-collision pair."""
        return np.array(self.pair_list, dtype=np.int64).reshape(-1, 2)

    @property
    def pair_bodies(self) -> tuple[tuple[str, str], ...]:
        """Per pair, the names of the two shapes' bodies."""
        return tuple((self.shape_bodies[i], self.shape_bodies[j]) for i, j in self.pair_list)

    @property
    def counts(self) -> tuple[int, int, int]:
        """Numbers of spheres, capsules and boxes."""
        return (self.spheres.radius.shape[0], self.capsules.radius.shape[0], self.boxes.half_extents.shape[0])

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


def _stack(specs: list[_sources.Spec], kind: str, dtype):
    width = {"sphere": 4, "capsule": 7, "box": 19}[kind]
    P = np.array([s.params for s in specs], dtype=np.float64).reshape(len(specs), width)
    f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    if kind == "sphere":
        return Sphere(f(P[:, :3].reshape(-1, 3)), f(P[:, 3].reshape(-1)))
    if kind == "capsule":
        return Capsule(f(P[:, :3].reshape(-1, 3)), f(P[:, 3:6].reshape(-1, 3)), f(P[:, 6].reshape(-1)))
    return Box(f(P[:, :16].reshape(-1, 4, 4)), f(P[:, 16:19].reshape(-1, 3)))


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


def _srdf_disabled(srdf) -> set[frozenset[str]]:
    """Link pairs of ``<disable_collisions link1= link2=>`` of an SRDF (a path or the XML text), or of several."""
    if isinstance(srdf, (list, tuple)):
        return set().union(*(_srdf_disabled(s) for s in srdf))
    text = os.fspath(srdf)
    root = ET.fromstring(text) if text.lstrip().startswith("<") else ET.parse(text).getroot()
    return {frozenset((el.get("link1", ""), el.get("link2", ""))) for el in root.iter("disable_collisions")}


def load(source, robot: Robot, *, meshes: str = "capsules", srdf=None, dtype=None) -> Geometry:
    """The collision geometry of a robot from the file it was loaded from.

    Args:
        source: the URDF or MJCF (path or XML text) that ``robot`` was loaded from
            (:func:`diffkin.load_robot`): its ``<collision>`` elements (URDF) or geoms (MJCF; those
            of the world body itself are the environment and are left out, as are geoms with
            ``contype = conaffinity = 0``).
        robot: the :class:`diffkin.Robot`: shapes are placed on its frames.
        meshes: ``"capsules"``: every mesh, cylinder and ellipsoid becomes one capsule that
            contains all its vertices (the only fit for now).
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
    from diffkin.models import _xml

    if meshes != "capsules":
        raise ValueError(f"meshes: expected 'capsules', got {meshes!r}")
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected a diffkin.Robot (dk.load_robot), got {type(robot).__name__}")
    root, path = _xml.read(source)
    excludes: set[frozenset[str]] = set()
    filterparent, mjcf = True, root.tag == "mujoco"
    if root.tag == "robot":
        specs = _sources.urdf_specs(root, os.path.dirname(path) if path else None)
    elif mjcf:
        specs, excludes, filterparent = _sources.mjcf_specs(root, path)
    else:
        raise ValueError(f"source: expected a <robot> (URDF) or <mujoco> (MJCF) root element, got <{root.tag}>")
    disabled = _srdf_disabled(srdf) if srdf is not None else set()
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
    by_kind = {k: [s for s in specs if s.kind == k] for k in KINDS}
    return Geometry(
        _stack(by_kind["sphere"], "sphere", dtype),
        _stack(by_kind["capsule"], "capsule", dtype),
        _stack(by_kind["box"], "box", dtype),
        shape_frames=tuple(frames),
        shape_names=tuple(s.name for s in specs),
        shape_bodies=tuple(body_names[b] for b in bodies),
        shape_links=tuple(s.frame for s in specs),
        pair_list=tuple(pairs),
        fits=tuple((s.name, s.source, float(s.volume), float(s.fitted_volume)) for s in specs if s.source != s.kind),
    )


def placed(robot: Robot, geom: Geometry, q, base=None) -> tuple[Sphere, Capsule, Box]:
    """The shapes in the world at ``q``: each kind with batch axes ``(..., n_kind)``."""
    from diffkin.kinematics import link_poses

    return moved(geom, link_poses(robot, q, base=base), geom.shape_frames)


def moved(geom: Geometry, T_world_frames: jax.Array, slots) -> tuple[Sphere, Capsule, Box]:
    """The shapes placed by their frames' poses ``T_world_frames`` ``(..., F, 4, 4)``, shape ``s`` by
    ``T_world_frames[..., slots[s]]``: each kind with batch axes ``(..., n_kind)``."""
    T = T_world_frames
    ns, nc, _ = geom.counts
    idx = np.asarray(slots, dtype=np.int64)
    Ts, Tc, Tb = T[..., idx[:ns], :, :], T[..., idx[ns : ns + nc], :, :], T[..., idx[ns + nc :], :, :]

    def move(T, p):
        return jnp.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]

    s, c, b = geom.spheres, geom.capsules, geom.boxes
    return (
        unchecked(Sphere, center=move(Ts, s.center), radius=s.radius),
        unchecked(Capsule, a=move(Tc, c.a), b=move(Tc, c.b), radius=c.radius),
        unchecked(Box, pose=Tb @ b.pose, half_extents=b.half_extents),
    )
