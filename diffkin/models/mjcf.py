"""A strict MJCF (MuJoCo XML) reader: the kinematic tree of a ``<mujoco>`` model as a :class:`Robot`.

What MuJoCo's ``mj_kinematics`` computes is reproduced exactly: a body's frame is its parent's
frame moved by the body's ``pos`` and orientation, then by its joints in order, each about its
anchor ``pos`` and ``axis`` in the body frame (``T_parent_body @ exp([S1] q1) @ exp([S2] q2)``),
by ``qpos - ref``. Lengths are metres; angles are degrees unless ``<compiler angle="radian">``
(Euler angles in ``<compiler eulerseq>``, default ``xyz``: lowercase about moving axes, uppercase
about fixed axes). ``<default>`` classes (nested, ``class``, ``childclass``), ``<frame>``
transforms and ``<include>`` are resolved as MuJoCo does; joint limits follow ``limited``,
``range`` and ``<compiler autolimits>`` (radians in ``q``, ``+-inf`` when unlimited). Body masses
and centres of mass are MuJoCo's ``body_mass`` and ``body_ipos`` (:mod:`diffkin.models._mjcf_mass`).
Geoms (but for their masses), inertia tensors, cameras, lights, actuators, sensors and tendons
that no equality uses do not move anything and are ignored; mocap bodies are fixed at their pose
in the file.

Frames: the world body is ``"world"``; every body is a frame by its name (an unnamed body is
``body{id}``, ``id`` its MuJoCo body id); every named ``<site>`` is a frame (``site:{name}`` if a
body has the same name: MuJoCo keeps bodies and sites in separate namespaces). Unnamed joints
are ``joint{id}`` (MuJoCo joint id). A ``<freejoint>`` (or ``<joint type="free">``) on a
top-level body makes that body the floating root: its pose is ``fk``'s ``base`` (MuJoCo's
``qpos`` position and ``w x y z`` quaternion), and static world bodies and world sites, which are
not part of the robot, are left out.

A ball joint is three entries of ``q``, its rotation vector ``name:rx, name:ry, name:rz`` in the body's
axes (MuJoCo's ``qpos`` quaternion is ``(cos(|r|/2), sin(|r|/2) r/|r|)``), its ``range`` a cone
``|r| <= range[1]`` (:mod:`diffkin.models._ball`).

Equalities: a linear ``<equality><joint polycoef>`` makes ``joint1`` follow ``joint2``,
``q1 - ref1 = c0 + c1 (q2 - ref2)`` (locked at ``c0`` without ``joint2``). A ``<equality><tendon>`` over
fixed tendons (length ``L = sum coef_i q_i``) holds MuJoCo's ``L1 - L1_0 = c0 + c1 (L2 - L2_0)``
(``L_0``: the length at the reference ``q = ref``; ``L1 - L1_0 = c0`` without ``tendon2``): the last
joint of ``tendon1`` follows the others, a linear function of them (a joint following several is one
tree joint per source, ``name`` and ``name:source``: :mod:`diffkin.models._couplings`). Couplings of
coupled joints are substituted. ``<connect>`` and ``<weld body1>`` close loops
(:mod:`diffkin.models._loops`).

Rejected with a ValueError naming the element (and the file, for joint and tendon equalities): free
joints below the top level or with other joints, several free bodies, moving top-level bodies beside a
free one, non-linear couplings (``c2``, ``c3`` or ``c4`` not 0; for a tendon equality, with ``tendon2``),
couplings that cannot be resolved (the last joint of ``tendon1`` with coefficient 0, a joint coupled
twice, couplings in a cycle), spatial tendons in equalities, ``<weld site1 site2>`` and ``<flex>``
equalities, ``<attach>``, ``<replicate>``, ``<composite>``,
``<flexcomp>``, unknown default classes, missing include files, a file included more than once
(MuJoCo's rule). Inactive equalities
(``active="false"``) are ignored. ``<include>`` paths are relative to the main file's folder
(the working directory for XML text), a nested one not found there to the including file's
(as MuJoCo). Bodies, ``<frame>``s and
``<default>`` classes may nest to any depth (walked with explicit stacks; MuJoCo's XML parser
stops at 500 nested elements).
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence

import numpy as np

from diffkin import _xml
from diffkin.models import _ball, _couplings, _mjcf_mass
from diffkin.models._couplings import Coupling
from diffkin.models._loops import Connect, close
from diffkin.models._tree import JointSpec, build
from diffkin.models.robot import Robot

_ORIENTATIONS = ("quat", "axisangle", "euler", "xyaxes", "zaxis")
_REJECTED = ("attach", "replicate", "composite", "flexcomp")
_FROMTO_TYPES = ("capsule", "cylinder", "box", "ellipsoid")


def _describe(el: ET.Element) -> str:
    """``MJCF <tag name='...'>`` (or the attributes that identify an unnamed element)."""
    keys = [
        k for k in ("name", "joint1", "joint2", "tendon1", "tendon2", "body1", "file", "class", "type") if el.get(k)
    ]
    attributes = "".join(f" {k}={el.get(k)!r}" for k in keys[:3])
    return f"MJCF <{el.tag}{attributes}>"


# ------------------------------------------------------------------------------------------- rotations


def _unit(v: np.ndarray, where: str) -> np.ndarray:
    norm = np.linalg.norm(v)
    if norm < 1e-12:
        raise ValueError(f"{where}: expected a nonzero vector, got {v.tolist()}")
    return v / norm


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (radians) about the unit ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _quat(q: np.ndarray, where: str) -> np.ndarray:
    """Rotation of the quaternion ``w x y z`` (normalised, as MuJoCo does)."""
    w, x, y, z = _unit(q, where)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def zaxis(z: np.ndarray, where: str) -> np.ndarray:
    """The minimal rotation taking ``(0, 0, 1)`` to ``z`` (a half turn about x if ``z`` points down)."""
    z = _unit(z, where)
    axis = np.cross([0.0, 0.0, 1.0], z)
    s = np.linalg.norm(axis)
    axis = axis / s if s >= 1e-10 else np.array([1.0, 0.0, 0.0])
    return _axis_angle(axis, np.arctan2(s, z[2]))


def _euler(angles: Sequence[float], seq: str) -> np.ndarray:
    """Euler angles (radians) in MuJoCo's ``eulerseq``: lowercase about the moving axes (post-multiplied),
    uppercase about the fixed axes (pre-multiplied)."""
    R = np.eye(3)
    for angle, axis in zip(angles, seq, strict=True):
        Ri = _axis_angle(np.eye(3)["xyz".index(axis.lower())], angle)
        R = R @ Ri if axis.islower() else Ri @ R
    return R


# ---------------------------------------------------------------------------------------------- reader


@dataclasses.dataclass
class _Part:
    """What one top-level body (or the world itself) contributes: its joints, bodies and sites."""

    joints: list[JointSpec] = dataclasses.field(default_factory=list)
    links: list[str] = dataclasses.field(default_factory=list)
    sites: list[tuple[str, str, np.ndarray]] = dataclasses.field(default_factory=list)
    inertials: dict[str, tuple[float, np.ndarray]] = dataclasses.field(default_factory=dict)
    unknown_masses: list[str] = dataclasses.field(default_factory=list)
    free: ET.Element | None = None


@dataclasses.dataclass(frozen=True)
class BodyGeom:
    """A ``<geom>`` of a body as the model reader walks the body tree, for the readers of its collision
    geometry (:func:`diffkin.collision.load`): the element with where it sits (its attributes are read with
    the :class:`Attributes` the walk returns, :func:`body_geoms`).

    Attributes:
        element: the ``<geom>``.
        body: the name of its body, as the :class:`Robot` names the body's frame (``body{id}`` if unnamed).
        T_body_container: ``(4, 4)`` pose of the geom's container (the body, or a ``<frame>`` in it) in
            the body frame; the geom's own ``pos`` and orientation are in the container.
        cls: the container's default class (the geom's own ``class`` not yet applied).
        id: MuJoCo's geom id (the world body's geoms, left out, first): unnamed geoms are ``geom{id}``.
    """

    element: ET.Element
    body: str
    T_body_container: np.ndarray
    cls: str
    id: int


class Attributes:
    """The compiler settings and ``<default>`` classes of a ``<mujoco>`` element (includes already expanded:
    :func:`expand_includes`): an element's attributes, class, orientation and pose as MuJoCo resolves them.
    The model reader builds on it; with :func:`body_geoms` it is also the interface of the other readers of an
    MJCF (the collision geoms of :func:`diffkin.collision.load`)."""

    def __init__(self, root: ET.Element):
        self.degrees, self.eulerseq, self.autolimits = True, "xyz", True
        for el in root.findall("compiler"):
            self._compiler(el)
        self.classes: dict[str, tuple[str | None, dict[str, dict[str, str]]]] = {"main": (None, {})}
        for el in root.findall("default"):
            name = el.get("class", "main")
            self._defaults(el, name, None if name == "main" else "main")

    def _compiler(self, el: ET.Element) -> None:
        angle, seq, auto = el.get("angle"), el.get("eulerseq"), el.get("autolimits")
        if angle is not None:
            if angle not in ("degree", "radian"):
                raise ValueError(f"{_describe(el)}: angle must be 'degree' or 'radian', got {angle!r}")
            self.degrees = angle == "degree"
        if seq is not None:
            if len(seq) != 3 or any(c not in "xyzXYZ" for c in seq):
                raise ValueError(f"{_describe(el)}: eulerseq must be 3 letters of xyzXYZ, got {seq!r}")
            self.eulerseq = seq
        if auto is not None:
            self.autolimits = self.flag(el, "autolimits", auto) is True

    def _defaults(self, el: ET.Element, name: str, parent: str | None) -> None:
        """Record a ``<default>`` class and the classes nested in it: per element tag, its attributes
        (nested classes inherit). Walked with a stack, in document order: any depth."""
        todo = [(el, name, parent)]
        while todo:
            el, name, parent = todo.pop()
            if name in self.classes and name != "main":
                raise ValueError(f"{_describe(el)}: repeated default class {name!r}")
            tags = self.classes.setdefault(name, (parent, {}))[1]
            nested = []
            for child in el:
                if child.tag == "default":
                    if not child.get("class"):
                        raise ValueError(f"MJCF nested <default> in class {name!r}: missing 'class' attribute")
                    nested.append((child, child.get("class", ""), name))
                else:
                    tags.setdefault(child.tag, {}).update(child.attrib)
            todo.extend(reversed(nested))

    # -- attributes

    def class_of(self, el: ET.Element, inherited: str, attribute: str = "class") -> str:
        """The default class of ``el`` (its ``attribute``: ``class``, or ``childclass`` for its children's),
        else ``inherited``; an unknown class raises."""
        name = el.get(attribute, inherited)
        if name not in self.classes:
            raise ValueError(f"{_describe(el)}: unknown default class {name!r}")
        return name

    def _chain(self, cls: str | None, tag: str):
        """The attribute dicts of ``tag`` in class ``cls`` and its ancestors, most specific first."""
        while cls is not None:
            parent, tags = self.classes[cls]
            yield tags.get(tag, {})
            cls = parent

    def attribute(
        self, el: ET.Element, attribute: str, cls: str | None, default: str | None = None, tag: str | None = None
    ) -> str | None:
        """An attribute from the element, else its class chain, else ``default``."""
        if el.get(attribute) is not None:
            return el.get(attribute)
        for attrs in self._chain(cls, tag or el.tag):
            if attribute in attrs:
                return attrs[attribute]
        return default

    @staticmethod
    def flag(el: ET.Element, attribute: str, text: str | None, allowed=("true", "false")) -> bool | str:
        """The value ``text`` of ``el``'s ``attribute``: ``True``/``False``, or another word of ``allowed``."""
        if text is None or text not in allowed:
            raise ValueError(f"{_describe(el)}: {attribute} must be one of {list(allowed)}, got {text!r}")
        return {"true": True, "false": False}.get(text, text)

    def _angle(self, value: float) -> float:
        return float(np.deg2rad(value)) if self.degrees else float(value)

    def rotation(self, el: ET.Element, cls: str | None = None) -> np.ndarray:
        """The element's orientation (from its class chain if it gives none), as a 3x3 rotation."""
        sources = [el.attrib, *(self._chain(cls, el.tag) if cls is not None else ())]
        attrs: dict[str, str] = next((a for a in sources if any(k in a for k in _ORIENTATIONS)), {})
        given = [k for k in _ORIENTATIONS if k in attrs]
        where = _describe(el)
        if len(given) > 1:
            raise ValueError(f"{where}: several orientations given ({given}); MuJoCo allows one")
        if not given:
            return np.eye(3)
        kind = given[0]
        values = _xml.numbers(
            None, kind, {"quat": 4, "axisangle": 4, "euler": 3, "xyaxes": 6, "zaxis": 3}[kind], attrs[kind], where
        )
        if kind == "quat":
            return _quat(values, f"{where} quat")
        if kind == "axisangle":
            return _axis_angle(_unit(values[:3], f"{where} axisangle"), self._angle(values[3]))
        if kind == "euler":
            return _euler([self._angle(a) for a in values], self.eulerseq)
        if kind == "zaxis":
            return zaxis(values, f"{where} zaxis")
        x = _unit(values[:3], f"{where} xyaxes")
        y = _unit(values[3:] - x * (x @ values[3:]), f"{where} xyaxes")
        return np.column_stack([x, y, np.cross(x, y)])

    def pose(self, el: ET.Element, cls: str | None = None) -> np.ndarray:
        """``(4, 4)`` pose of a body, frame or site in its container's frame (``pos`` in metres)."""
        T = np.eye(4)
        where = _describe(el)
        fromto = self.attribute(el, "fromto", cls) if el.tag == "site" else None
        if fromto is not None:
            kind = self.attribute(el, "type", cls, "sphere")
            if kind not in _FROMTO_TYPES:
                raise ValueError(f"{where}: fromto needs a site of type {list(_FROMTO_TYPES)}, got {kind!r}")
            if self.attribute(el, "pos", cls) is not None:
                raise ValueError(f"{where}: both pos and fromto given (MuJoCo allows one)")
            ends = _xml.numbers(None, "fromto", 6, fromto, where)
            T[:3, :3] = zaxis(ends[:3] - ends[3:], f"{where} fromto")  # z from `to` to `from`, as MuJoCo
            T[:3, 3] = 0.5 * (ends[:3] + ends[3:])
            return T
        T[:3, :3] = self.rotation(el, cls)
        T[:3, 3] = _xml.numbers(None, "pos", 3, self.attribute(el, "pos", cls, "0 0 0"), where)
        return T

    def contents(
        self, el: ET.Element, cls: str, tags: Sequence[str] = ("joint", "freejoint", "site", "body", "geom", "inertial")
    ) -> list[tuple[ET.Element, np.ndarray, str]]:
        """The elements of a body (or the world body) with one of ``tags``, through its ``<frame>``s (any
        depth), in document order, each as ``(element, pose of its container in the body frame, class)``;
        ``cls`` is the body's class (its ``childclass`` resolved). Raises on the elements MuJoCo generates
        from (``<attach>``, ``<replicate>``, ``<composite>``, ``<flexcomp>``): not supported."""
        out = []
        todo = [(child, np.eye(4), cls) for child in reversed(el)]
        while todo:
            child, T, cls = todo.pop()
            if child.tag in _REJECTED:
                raise ValueError(f"{_describe(child)}: <{child.tag}> is not supported")
            if child.tag == "frame":
                inner, T_frame = self.class_of(child, cls, "childclass"), T @ self.pose(child)
                todo.extend((grandchild, T_frame, inner) for grandchild in reversed(child))
            elif child.tag in tags:
                out.append((child, T, cls))
        return out


class _Reader(Attributes):
    """One pass over a ``<mujoco>`` element (includes already expanded)."""

    def __init__(self, root: ET.Element):
        super().__init__(root)
        self.n_bodies, self.n_joints = 1, 0
        self.stiff: set[str] = set()  # joints with stiffness (springs): the last chosen to close a loop
        self.parts: dict[str, _Part] = {"world": _Part(links=["world"])}
        self.mass_rules = _mjcf_mass.Compiler(root, self)
        self.world_geoms = 0  # the world body's geoms (they come first in MuJoCo's geom ids)
        self.geoms: list[tuple[ET.Element, str, np.ndarray, str]] = []  # each body's, in body order

    # -- the body tree

    def _joint(self, el: ET.Element, T: np.ndarray, cls: str, body: str) -> tuple[list[JointSpec], bool]:
        """A hinge or slide joint as a spec from the body's parent side (``origin`` set later), a ball
        joint as three (:mod:`diffkin.models._ball`), or ``([], True)`` for a free joint."""
        jid, self.n_joints = self.n_joints, self.n_joints + 1
        cls = self.class_of(el, cls)
        kind = "free" if el.tag == "freejoint" else self.attribute(el, "type", cls, "hinge")
        if kind == "free":
            return [], True
        where = _describe(el)
        if kind not in ("hinge", "slide", "ball"):
            raise ValueError(
                f"{where}: joint type {kind!r} is not supported (hinge, slide, ball, free on a top-level body)"
            )
        anchor = T[:3, :3] @ _xml.numbers(None, "pos", 3, self.attribute(el, "pos", cls, "0 0 0"), where) + T[:3, 3]
        name = el.get("name") or f"joint{jid}"
        if float(_xml.numbers(None, "stiffness", 1, self.attribute(el, "stiffness", cls, "0"), where)[0]) != 0:
            self.stiff |= {name} if kind != "ball" else {f"{name}:{k}" for k in _ball.AXES}
        if kind == "ball":  # about the anchor, in the body's axes (MuJoCo ignores a ball joint's axis and ref)
            _, upper = self._limits(el, cls, True)
            return [
                JointSpec(
                    f"{name}:{k}", "B", "", body, np.eye(4), np.concatenate([np.cross(anchor, e), e]), -upper, upper
                )
                for k, e in zip(_ball.AXES, np.eye(3), strict=True)
            ], False
        axis = T[:3, :3] @ _unit(
            _xml.numbers(None, "axis", 3, self.attribute(el, "axis", cls, "0 0 1"), where), f"{where} axis"
        )
        hinge = kind == "hinge"
        screw = np.concatenate([np.cross(anchor, axis), axis] if hinge else [axis, np.zeros(3)])
        ref = float(_xml.numbers(None, "ref", 1, self.attribute(el, "ref", cls, "0"), where)[0])
        lower, upper = self._limits(el, cls, hinge)
        spec = JointSpec(
            name,
            "R" if hinge else "P",
            "",
            body,
            np.eye(4),
            screw,
            lower,
            upper,
            offset=-(self._angle(ref) if hinge else ref),
        )
        return [spec], False

    def _limits(self, el: ET.Element, cls: str, hinge: bool) -> tuple[float, float]:
        """``(lower, upper)`` in radians or metres; ``+-inf`` if unlimited (MuJoCo's ``limited`` rules)."""
        where = _describe(el)
        text = self.attribute(el, "range", cls)
        limited = self.flag(el, "limited", self.attribute(el, "limited", cls, "auto"), ("true", "false", "auto"))
        if limited == "auto" and text is not None and not self.autolimits:
            raise ValueError(f"{where}: 'range' without 'limited' needs <compiler autolimits=\"true\">")
        lower, upper = _xml.numbers(None, "range", 2, text or "0 0", where)
        if limited is True and not lower < upper:
            raise ValueError(f"{where}: a limited joint needs range lower < upper, got {text!r}")
        if limited is False or (limited == "auto" and not lower < upper):
            return -np.inf, np.inf
        return (self._angle(lower), self._angle(upper)) if hinge else (float(lower), float(upper))

    def _body(self, el: ET.Element, parent: str, T_parent_body: np.ndarray, cls: str, part: _Part) -> None:
        """Add a body, its joints and sites, then its children: the subtree depth first (MuJoCo's id
        order), sites and child bodies in document order; walked with a stack, any depth."""
        # (body, parent body, pose in the parent, class) or (named site, its body, pose in the body, class)
        todo = [(el, parent, T_parent_body, cls)]
        while todo:
            el, parent, T, cls = todo.pop()
            if el.tag == "site":
                part.sites.append((el.get("name", ""), parent, T))
                continue
            name = self._add_body(el, parent, T, cls, part)
            later = []
            for child, T_body_container, c in self.contents(el, self.class_of(el, cls, "childclass")):
                if child.tag == "site" and child.get("name"):
                    later.append((child, name, T_body_container @ self.pose(child, self.class_of(child, c)), c))
                elif child.tag == "body":
                    later.append((child, name, T_body_container @ self.pose(child), c))
            todo.extend(reversed(later))

    def _add_body(self, el: ET.Element, parent: str, T_parent_body: np.ndarray, cls: str, part: _Part) -> str:
        """Add one body (its name, MuJoCo id and joints) to ``part``; returns its name."""
        bid, self.n_bodies = self.n_bodies, self.n_bodies + 1
        name = el.get("name") or f"body{bid}"
        part.links.append(name)
        moving: list[JointSpec] = []
        contents = self.contents(el, self.class_of(el, cls, "childclass"))
        inertial = _mjcf_mass.body(self, self.mass_rules, el, name, contents)
        if isinstance(inertial, str):
            part.unknown_masses.append(inertial)
        else:
            part.inertials[name] = inertial
        for child, T, c in contents:
            if child.tag == "geom":
                self.geoms.append((child, name, T, c))
            if child.tag in ("joint", "freejoint"):
                specs, free = self._joint(child, T, c, name)
                if free and (parent != "world" or part.free is not None):
                    raise ValueError(f"{_describe(child)}: a free joint must be the only joint of a top-level body")
                if free:
                    part.free = child
                moving += specs
        if part.free is not None and parent == "world" and moving:
            raise ValueError(f"{_describe(part.free)}: a free joint must be the only joint of a top-level body")
        if part.free is None or parent != "world":
            self._connect(parent, name, T_parent_body, moving, part)
        return name

    @staticmethod
    def _connect(parent: str, body: str, T_parent_body: np.ndarray, moving: list[JointSpec], part: _Part) -> None:
        """Chain a body's joints through unnamed intermediate bodies (a fixed joint if it has none)."""
        if not moving:
            part.joints.append(JointSpec(f"{body}\0fixed", "F", parent, body, T_parent_body, np.zeros(6)))
            return
        for k, spec in enumerate(moving):
            child = body if k == len(moving) - 1 else f"{body}\0{k}"
            origin = T_parent_body if k == 0 else np.eye(4)
            part.joints.append(dataclasses.replace(spec, parent=parent, child=child, origin=origin))
            parent = child

    def worldbody(self, el: ET.Element) -> None:
        for child, T, cls in self.contents(el, "main"):
            if child.tag in ("joint", "freejoint"):
                raise ValueError(f"{_describe(child)}: the world body cannot have joints")
            if child.tag == "geom":
                self.world_geoms += 1
            if child.tag == "site" and child.get("name"):
                T_world_site = T @ self.pose(child, self.class_of(child, cls))
                self.parts["world"].sites.append((child.get("name", ""), "world", T_world_site))
            elif child.tag == "body":
                part = _Part()
                self._body(child, "world", T @ self.pose(child), cls, part)
                self.parts[part.links[0]] = part


# ----------------------------------------------------------------------------------------------- equality


def _screw_exp(screw: np.ndarray, theta: float) -> np.ndarray:
    """``exp([screw] theta)`` of a unit hinge ``[c x a; a]`` or slide ``[a; 0]`` screw."""
    v, w = screw[:3], screw[3:]
    T = np.eye(4)
    if np.linalg.norm(w) < 0.5:
        T[:3, 3] = v * theta
    else:
        R = _axis_angle(w, theta)
        T[:3, :3], T[:3, 3] = R, (np.eye(3) - R) @ np.cross(w, v)
    return T


def _equalities(
    reader: _Reader, root: ET.Element, joints: list[JointSpec], path: str | None, site_frames: dict[str, str]
) -> tuple[list[JointSpec], list[Connect]]:
    """Apply the linear couplings of ``<equality><joint>`` and ``<equality><tendon>``
    (:func:`_joint_coupling`, :func:`_tendon_coupling`; :mod:`diffkin.models._couplings`), and read the
    ``<connect>`` and ``<weld>`` ones (closed loops: :mod:`diffkin.models._loops`).

    Args:
        path: the file the model was read from (named in error messages), or ``None``.
        site_frames: the frame name of each site of the robot, by site name (MuJoCo's namespace of sites).
    """
    index = {j.name: k for k, j in enumerate(joints)}
    scalar = {j.name for j in joints if j.kind in ("R", "P")}
    tendons = {t.get("name", ""): t for group in root.findall("tendon") for t in group if t.get("name")}
    couplings: dict[str, Coupling] = {}
    connects = []
    for group in root.findall("equality"):
        for el in group:
            cls = reader.class_of(el, "main")
            if not reader.flag(el, "active", reader.attribute(el, "active", cls, "true", "equality")):
                continue
            where = _describe(el).replace("MJCF <", "MJCF <equality><", 1)
            if el.tag == "connect" and el.get("body1"):
                anchor = _xml.numbers(
                    None, "anchor", 3, reader.attribute(el, "anchor", cls, "0 0 0", "equality"), where
                )
                connects.append(Connect(el.get("body1", ""), el.get("body2") or "world", anchor, where))
                continue
            if el.tag == "weld" and el.get("body1"):
                connects += _weld(reader, el, cls, where)
                continue
            if el.tag == "connect":
                if not (el.get("site1") and el.get("site2")):
                    raise ValueError(f"{where}: expected body1 (and body2, anchor) or site1 and site2")
                zero = np.zeros(3)  # the two sites' origins coincide
                site1, site2 = (_site_frame(site_frames, el.get(key, ""), where) for key in ("site1", "site2"))
                connects.append(Connect(site1, site2, zero, where, zero))
                continue
            if el.tag not in ("joint", "tendon"):
                raise ValueError(
                    f"{where}: <equality><{el.tag}> constraints are not supported (they weld sites or hold "
                    "flexes); linear <joint> and <tendon> equalities, <connect> and <weld body1> loops are"
                )
            where = f"{path}: {where}" if path else where
            c = _xml.numbers(None, "polycoef", 5, reader.attribute(el, "polycoef", cls, "0 1 0 0 0", "equality"), where)
            if el.tag == "joint":
                joint, coupling = _joint_coupling(el, c, scalar, where)
            else:
                joint, coupling = _tendon_coupling(el, c, tendons, scalar, where)
            if joint in couplings:
                raise ValueError(f"{where}: joint {joint!r} is already coupled by {couplings[joint].where}")
            couplings[joint] = coupling
    resolved = _couplings.resolve(couplings)
    for name, (terms, bias) in resolved.items():
        if not terms:  # a locked joint: fixed at theta = bias
            j = joints[index[name]]
            joints[index[name]] = dataclasses.replace(j, kind="F", origin=j.origin @ _screw_exp(j.screw, bias))
    return _couplings.as_mimics(joints, {n: r for n, r in resolved.items() if r[0]}), connects


def _site_frame(site_frames: dict[str, str], site: str, where: str) -> str:
    """The frame of the robot's site ``site`` (``site:{name}`` where a body has its name)."""
    if site not in site_frames:
        raise ValueError(f"{where}: unknown site {site!r}")
    return site_frames[site]


def _joint_coupling(el: ET.Element, c: np.ndarray, scalar: set[str], where: str) -> tuple[str, Coupling]:
    """``<equality><joint>``: ``theta1 = c0 + c1 theta2`` (MuJoCo's ``q1 - ref1 = c0 + c1 (q2 - ref2)``), or
    ``theta1 = c0`` (``joint1`` locked) with ``joint2`` omitted. ``scalar``: the robot's hinges and slides."""
    if np.any(c[2:] != 0):
        raise ValueError(f"{where}: polycoef {c.tolist()} is not linear (c2 = c3 = c4 = 0 is needed)")
    if not el.get("joint1"):
        raise ValueError(f"{where}: missing 'joint1' attribute")
    _check_joints([el.get("joint1", ""), el.get("joint2", "")], scalar, where)
    terms = ((el.get("joint2", ""), float(c[1])),) if el.get("joint2") else ()
    return el.get("joint1", ""), Coupling(terms, float(c[0]), where)


def _tendon_coupling(
    el: ET.Element, c: np.ndarray, tendons: dict[str, ET.Element], scalar: set[str], where: str
) -> tuple[str, Coupling]:
    """``<equality><tendon>``, MuJoCo's ``L1 - L1_0 = c0 + c1 (L2 - L2_0)`` over fixed tendons
    (``L = sum coef_i q_i``, ``L_0`` its value at the reference ``q = ref``), or ``L1 - L1_0 = c0`` with
    ``tendon2`` omitted (``c1 ... c4`` unused, as in MuJoCo): ``sum w_i theta_i = c0`` with
    ``w = coef1 - c1 coef2``, solved for the last joint of ``tendon1``. ``tendons``: the named ``<tendon>``
    elements; ``scalar``: the robot's hinges and slides."""
    if not el.get("tendon1"):
        raise ValueError(f"{where}: missing 'tendon1' attribute")
    if el.get("tendon2") and np.any(c[2:] != 0):
        raise ValueError(f"{where}: polycoef {c.tolist()} is not linear (c2 = c3 = c4 = 0 is needed)")
    if el.get("tendon2") == el.get("tendon1"):
        raise ValueError(f"{where}: tendon1 and tendon2 are the same tendon")
    first = _fixed_tendon(tendons, el.get("tendon1", ""), scalar, where)
    w, scale = dict(first), max(abs(coef) for _, coef in first)
    for joint, coef in _fixed_tendon(tendons, el.get("tendon2", ""), scalar, where) if el.get("tendon2") else ():
        w[joint] = w.get(joint, 0.0) - c[1] * coef
        scale = max(scale, abs(c[1] * coef))
    joint = first[-1][0]
    if abs(w[joint]) <= 1e-12 * scale:  # 0, or 0 but for rounding (its joint would follow at 1e12 times the rest)
        raise ValueError(
            f"{where}: the coefficient of joint {joint!r} is 0 (the last joint of tendon1, which the equality "
            "makes follow the others: it must appear in the coupling)"
        )
    terms = tuple((k, float(-wk / w[joint])) for k, wk in w.items() if k != joint and wk != 0)
    return joint, Coupling(terms, float(c[0] / w[joint]), where)


def _check_joints(names: list[str], scalar: set[str], where: str) -> None:
    """Each of ``names`` (empty ones skipped) is one of the robot's hinges and slides, ``scalar``."""
    for n in filter(None, names):
        if n not in scalar:
            raise ValueError(f"{where}: {n!r} is not a hinge or slide joint of the robot")


def _fixed_tendon(tendons: dict[str, ET.Element], name: str, scalar: set[str], where: str) -> list[tuple[str, float]]:
    """The ``(joint, coef)`` of the ``<tendon><fixed name>`` (its length is ``sum coef_i q_i``), in file order."""
    if name not in tendons:
        raise ValueError(f"{where}: unknown tendon {name!r}")
    tendon = tendons[name]
    if tendon.tag != "fixed":
        raise ValueError(
            f"{where}: tendon {name!r} is a <{tendon.tag}> tendon; only <fixed> tendons (linear in the joints) are"
        )
    terms: list[tuple[str, float]] = []
    for el in tendon.findall("joint"):
        joint = el.get("joint")
        if not joint:
            raise ValueError(f"{where}: a <joint> of tendon {name!r} has no 'joint' attribute")
        if joint in dict(terms):
            raise ValueError(f"{where}: joint {joint!r} is repeated in tendon {name!r}")
        terms.append((joint, float(_xml.numbers(el, "coef", 1, None, f"{where} tendon {name!r} joint {joint!r}")[0])))
    if not terms:
        raise ValueError(f"{where}: tendon {name!r} has no joints")
    _check_joints([joint for joint, _ in terms], scalar, where)
    return terms


WELD_ARM = 0.1  # metres: a weld holds three points of body1, at its origin and this far along its x and y axes


def _weld(reader: _Reader, el: ET.Element, cls: str, where: str) -> list[Connect]:
    """A ``<weld body1 body2 relpose>`` as three connects (:data:`WELD_ARM`): body2's pose in body1 fixed,
    either ``relpose`` (position, quaternion) or, with its quaternion all zero (the default), the relative
    pose at the reference configuration. (Its ``anchor`` and ``torquescale`` shape MuJoCo's forces only.)"""
    relpose = _xml.numbers(None, "relpose", 7, reader.attribute(el, "relpose", cls, "0 1 0 0 0 0 0", "equality"), where)
    points = [np.zeros(3), WELD_ARM * np.eye(3)[0], WELD_ARM * np.eye(3)[1]]
    body2 = el.get("body2") or "world"
    if not np.any(relpose[3:]):
        return [Connect(el.get("body1", ""), body2, x, where) for x in points]
    R = _quat(relpose[3:], f"{where} relpose")  # T_body1_body2 = (R, p): x in body1 is R^T (x - p) in body2
    return [Connect(el.get("body1", ""), body2, x, where, R.T @ (x - relpose[:3])) for x in points]


def _actuated(root: ET.Element) -> set[str]:
    """The joints an ``<actuator>`` drives, directly (``joint``, ``jointinparent``) or through a fixed tendon."""
    tendons = {
        t.get("name"): {j.get("joint", "") for j in t.findall("joint")}
        for g in root.findall("tendon")
        for t in g.findall("fixed")
    }
    driven: set[str] = set()
    for group in root.findall("actuator"):
        for el in group:
            driven |= {el.get(k, "") for k in ("joint", "jointinparent")}
            driven |= tendons.get(el.get("tendon"), set())
    return {n for n in driven if n}


# --------------------------------------------------------------------------------------------- front door


def _included(el: ET.Element, folder: str, inside: tuple[str, ...], seen: set[str]) -> tuple[ET.Element, str]:
    """The ``<mujoco>`` root of the file an ``<include>`` names, and its path.

    Args:
        el: the ``<include>`` element.
        folder: the folder include paths are relative to (the main file's); a nested include not
            found there is looked for next to the file that includes it (as MuJoCo does).
        inside: the paths of the includes that led to ``el`` (a cycle repeats one).
        seen: the real paths of every file included so far (updated).
    """
    if not el.get("file"):
        raise ValueError("MJCF <include>: missing 'file' attribute")
    where = _describe(el)
    path = os.path.normpath(os.path.join(folder, el.get("file", "")))
    if not os.path.isfile(path) and inside:  # a nested include: also next to the file that includes it
        beside = os.path.normpath(os.path.join(os.path.dirname(inside[-1]), el.get("file", "")))
        path = beside if os.path.isfile(beside) else path
    if not os.path.isfile(path):
        raise ValueError(f"{where}: file not found: {path!r}")
    if path in inside:
        raise ValueError(f"{where}: recursive include of {path!r}")
    if os.path.realpath(path) in seen:
        raise ValueError(f"{where}: file {path!r} is included more than once (MuJoCo allows one include of a file)")
    seen.add(os.path.realpath(path))
    included, _ = _xml.read(path, "MJCF")
    if included.tag != "mujoco":
        raise ValueError(f"{where}: expected a <mujoco> root element in {path!r}, got <{included.tag}>")
    return included, path


def expand_includes(root: ET.Element, folder: str) -> None:
    """Replace every ``<include file=...>`` by the children of the included ``<mujoco>``, at any depth.

    Each file may be included once in the whole model (MuJoCo's rule; repeated includes would
    expand exponentially). Walked with a stack: any nesting depth.
    """
    seen: set[str] = set()
    elements: list[tuple[ET.Element, tuple[str, ...]]] = [(root, ())]  # with the includes that led to each
    while elements:
        el, inside = elements.pop()
        children = []
        todo = [(child, inside) for child in reversed(el)]
        while todo:
            child, where = todo.pop()
            if child.tag == "include":
                included, path = _included(child, folder, where, seen)
                todo.extend((grandchild, (*where, path)) for grandchild in reversed(included))
            else:
                children.append(child)
                elements.append((child, where))
        el[:] = children


def _read(root: ET.Element, path: str | None) -> _Reader:
    """The body tree of a parsed ``<mujoco>`` element, walked once (its includes expanded in place first)."""
    expand_includes(root, os.path.dirname(path) if path else os.getcwd())
    reader = _Reader(root)
    for el in root.findall("worldbody"):
        reader.worldbody(el)
    return reader


def body_geoms(root: ET.Element, path: str | None = None) -> tuple[Attributes, list[BodyGeom]]:
    """The geoms of the bodies of a parsed ``<mujoco>`` element, in MuJoCo's geom id order, from the model
    reader's own walk of the body tree (the bodies named as :func:`robot_from_mjcf` names their frames);
    the world body's geoms (the environment) are left out. With the :class:`Attributes` to read them by.

    Args:
        root: the ``<mujoco>`` element (modified: its includes are expanded in place).
        path: the file it was read from (includes are relative to its folder), or ``None``.
    """
    reader = _read(root, path)
    first = reader.world_geoms
    return reader, [BodyGeom(el, body, T, cls, first + k) for k, (el, body, T, cls) in enumerate(reader.geoms)]


def robot_from_mjcf(root: ET.Element, path: str | None = None) -> Robot:
    """The :class:`Robot` of a parsed ``<mujoco>`` element (see the module docstring and :func:`diffkin.load_robot`).

    Args:
        root: the ``<mujoco>`` element (modified: its includes are expanded in place).
        path: the file it was read from (includes are relative to its folder), or ``None``.
    """
    reader = _read(root, path)
    free = [(name, part, part.free) for name, part in reader.parts.items() if part.free is not None]
    if len(free) > 1:
        raise ValueError(
            f"{_describe(free[1][2])}: body {free[1][0]!r} is a second free body (free joints on "
            f"{[n for n, _, _ in free]}); one floating root is supported (a single top-level body with a free joint)"
        )
    parts = list(reader.parts.values())
    if free:
        name, part, _ = free[0]
        for other, p in reader.parts.items():
            moving = [j.name for j in p.joints if j.kind != "F"]
            if p is not part and moving:
                raise ValueError(
                    f"MJCF <body name={other!r}>: its joints {moving} move a second tree beside the "
                    f"floating root {name!r}; one tree is supported"
                )
        parts = [part]
    links = [n for p in parts for n in p.links]
    bodies = set(links)
    site_frames = {n: f"site:{n}" if n in bodies else n for p in parts for n, _, _ in p.sites}
    sites = [(site_frames[n], body, T) for p in parts for n, body, T in p.sites]
    joints, connects = _equalities(reader, root, [j for p in parts for j in p.joints], path, site_frames)
    total = reader.mass_rules.total
    scale = 1.0
    if total is not None:  # settotalmass: over every body of the model (MuJoCo's), including those left out here
        given = sum(m for p in reader.parts.values() for m, _ in p.inertials.values())
        scale = total / given if given > 0 else 1.0
    inertials = {n: (scale * m, c) for p in parts for n, (m, c) in p.inertials.items()}
    robot = build(
        joints,
        links,
        frames=sites,
        inertials=inertials,
        unknown_masses=[u for p in parts for u in p.unknown_masses],
        floating=bool(free),
        name=root.get("model", ""),
        where="MJCF",
    )
    if not connects:
        return robot
    actuated = _actuated(root)
    balls = {n.rsplit(":", 1)[0] for n in robot.joint_names if robot.actuated_types[robot.joint_names.index(n)] == "B"}
    passive = {n for n in robot.joint_names if n not in actuated and n.rsplit(":", 1)[0] not in (actuated & balls)}
    return close(robot, connects, passive, reader.stiff)
