"""Body masses and centres of mass of an MJCF model, as MuJoCo's compiler sets ``body_mass`` and ``body_ipos``.

A body's ``<inertial>`` gives them; without one (``<compiler inertiafromgeom="auto">``, the default)
or always (``"true"``) they come from its geoms whose ``group`` lies in ``inertiagrouprange``: each
geom's mass is its ``mass`` or ``density`` (default 1000) times its volume, at the geom's centre.
``boundmass`` raises each body's mass to at least that value (a massless body's centre is then its
``pos`` attribute, as MuJoCo leaves it); ``settotalmass`` scales every mass to
that total. A mesh geom's centre of mass is its mesh's (not computed here): such bodies are
reported as unknown, unless they have an ``<inertial>``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from diffkin import _xml

_VOLUMES = {  # volume of a primitive from its size (r, half-length, ...), as MuJoCo computes it
    "sphere": lambda s: 4.0 / 3.0 * np.pi * s[0] ** 3,
    "capsule": lambda s: np.pi * s[0] ** 2 * 2.0 * s[1] + 4.0 / 3.0 * np.pi * s[0] ** 3,
    "cylinder": lambda s: np.pi * s[0] ** 2 * 2.0 * s[1],
    "ellipsoid": lambda s: 4.0 / 3.0 * np.pi * s[0] * s[1] * s[2],
    "box": lambda s: 8.0 * s[0] * s[1] * s[2],
    "plane": lambda s: 0.0,
}


class Compiler:
    """The ``<compiler>`` settings that decide masses."""

    def __init__(self, root: ET.Element, reader):
        self.from_geom, self.groups, self.bound, self.total = "auto", (0, 5), 0.0, None
        for el in root.findall("compiler"):
            where = "MJCF <compiler>"
            text = el.get("inertiafromgeom")
            if text is not None:
                self.from_geom = reader.flag(el, "inertiafromgeom", text, ("true", "false", "auto"))
            if el.get("inertiagrouprange") is not None:
                lo, hi = _xml.numbers(el, "inertiagrouprange", 2, None, where)
                self.groups = (int(lo), int(hi))
            if el.get("boundmass") is not None:
                self.bound = float(_xml.numbers(el, "boundmass", 1, None, where)[0])
            if el.get("settotalmass") is not None:
                total = float(_xml.numbers(el, "settotalmass", 1, None, where)[0])
                self.total = total if total > 0 else None  # MuJoCo: -1 (the default) leaves masses as they are


def body(reader, compiler: Compiler, el: ET.Element, name: str, contents) -> tuple[float, np.ndarray] | str:
    """``(mass, centre of mass in the body frame)`` of the body ``el``, or why it is unknown.

    Args:
        reader: the model's :class:`diffkin.models.mjcf.Attributes` (classes, poses).
        compiler: the model's :class:`Compiler`.
        el: the ``<body>`` element; ``name``: its frame name.
        contents: its ``(element, pose of its container in the body frame, class)`` (frames resolved).
    """
    inertial = next((child for child, _, _ in contents if child.tag == "inertial"), None)
    if inertial is not None and compiler.from_geom is not True:
        where = f"MJCF <inertial> of body {name!r}"
        mass = float(_xml.numbers(inertial, "mass", 1, None, where)[0])
        if mass < 0:
            raise ValueError(f"{where} mass: expected a non-negative mass (kg), got {mass}")
        return _bounded(compiler, mass, _xml.numbers(inertial, "pos", 3, None, where))
    # a body without mass keeps its own ``pos`` attribute as its centre (MuJoCo's ``body_ipos``):
    # that counts only when ``boundmass`` gives it a mass
    massless = _xml.numbers(el, "pos", 3, "0 0 0", f"MJCF <body name={name!r}>")
    if compiler.from_geom is False:
        return _bounded(compiler, 0.0, massless)
    total, moment = 0.0, np.zeros(3)
    for child, T, cls in contents:
        if child.tag != "geom":
            continue
        cls = reader.class_of(child, cls)
        get = lambda attribute, default=None, child=child, cls=cls: reader.attribute(child, attribute, cls, default)  # noqa: E731
        where = f"MJCF <geom name={child.get('name', '')!r}> of body {name!r}"
        group = int(_xml.numbers(None, "group", 1, get("group", "0"), where)[0])
        if not compiler.groups[0] <= group <= compiler.groups[1]:
            continue
        kind = get("type", "sphere")
        size = np.concatenate([[float(x) for x in (get("size", "0") or "0").split()], np.zeros(3)])[:3]
        fromto = get("fromto")
        if fromto is not None and kind in ("capsule", "cylinder", "box", "ellipsoid"):
            ends = _xml.numbers(None, "fromto", 6, fromto, where)
            centre = 0.5 * (ends[:3] + ends[3:])
            size[1 if kind in ("capsule", "cylinder") else 2] = 0.5 * np.linalg.norm(ends[3:] - ends[:3])
        else:
            centre = reader.pose(child, cls)[:3, 3]
        given = get("mass")
        if kind not in _VOLUMES:  # a mesh (or height field): its centre is not computed here
            if given is not None and float(_xml.numbers(None, "mass", 1, given, where)[0]) == 0.0:
                continue
            return f"body {name!r}: the mass of its {kind} geom (give the body an <inertial>)"
        if given is not None:
            mass = float(_xml.numbers(None, "mass", 1, given, where)[0])
        else:
            mass = float(_xml.numbers(None, "density", 1, get("density", "1000"), where)[0]) * _VOLUMES[kind](size)
        total += mass
        moment += mass * (T[:3, :3] @ centre + T[:3, 3])
    return _bounded(compiler, total, moment / total if total > 0 else massless)


def _bounded(compiler: Compiler, mass: float, com: np.ndarray) -> tuple[float, np.ndarray]:
    return max(mass, compiler.bound), com
