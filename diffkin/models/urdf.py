"""A small strict URDF reader: the serial chain between two links as a :class:`PoEChain`."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from diffkin.models.poe import PoEChain

_MOVING = {"revolute": "R", "continuous": "R", "prismatic": "P"}
_UNSUPPORTED = ("floating", "planar")


@dataclass(frozen=True)
class _Joint:
    name: str
    kind: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) pose of the joint frame in the parent link frame
    axis: np.ndarray  # (3,) unit axis in the joint frame
    lower: float
    upper: float
    mimic: bool


def _numbers(element: ET.Element, attribute: str, count: int, default: str, where: str) -> np.ndarray:
    text = element.get(attribute, default) if element is not None else default
    try:
        values = np.array([float(x) for x in text.split()], dtype=np.float64)
    except ValueError:
        values = np.array([])
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{where} {attribute}: expected {count} finite numbers, got {text!r}")
    return values


def _rpy(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _parse_joint(el: ET.Element) -> _Joint:
    name = el.get("name")
    if not name:
        raise ValueError("<joint>: missing 'name' attribute")
    where = f"joint {name!r}"
    kind = el.get("type")
    parent, child = el.find("parent"), el.find("child")
    if parent is None or child is None or not parent.get("link") or not child.get("link"):
        raise ValueError(f"{where}: expected <parent link=...> and <child link=...>")
    origin_el = el.find("origin")
    T = np.eye(4)
    T[:3, :3] = _rpy(_numbers(origin_el, "rpy", 3, "0 0 0", f"{where} <origin>"))
    T[:3, 3] = _numbers(origin_el, "xyz", 3, "0 0 0", f"{where} <origin>")
    axis = _numbers(el.find("axis"), "xyz", 3, "1 0 0", f"{where} <axis>")
    lower, upper = -np.inf, np.inf
    if kind in _MOVING:
        norm = np.linalg.norm(axis)
        if norm < 1e-12:
            raise ValueError(f"{where} <axis>: expected a nonzero direction, got {axis.tolist()}")
        axis = axis / norm
    if kind in ("revolute", "prismatic"):
        limit = el.find("limit")
        if limit is None or limit.get("lower") is None or limit.get("upper") is None:
            raise ValueError(f"{where}: a {kind} joint needs <limit lower=... upper=...>")
        lower = float(_numbers(limit, "lower", 1, "", f"{where} <limit>")[0])
        upper = float(_numbers(limit, "upper", 1, "", f"{where} <limit>")[0])
        if lower > upper:
            raise ValueError(f"{where} <limit>: expected lower <= upper, got lower={lower}, upper={upper}")
    return _Joint(name, kind or "", parent.get("link"), child.get("link"), T, axis, lower, upper,
                  el.find("mimic") is not None)


def _read(source) -> ET.Element:
    if not isinstance(source, (str, os.PathLike)):
        raise TypeError(f"source: expected a URDF path or XML string, got {type(source).__name__}")
    text = os.fspath(source)
    if not text.lstrip().startswith("<"):
        if not os.path.isfile(text):
            raise ValueError(f"source: URDF file not found: {text!r}")
        with open(text, encoding="utf-8") as fh:
            text = fh.read()
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise ValueError(f"source: malformed URDF XML ({err})") from err
    if root.tag != "robot":
        raise ValueError(f"source: expected a <robot> root element, got <{root.tag}>")
    return root


def load_urdf(source, end_link: str | None = None, *, base_link: str | None = None) -> PoEChain:
    """Read the serial chain from ``base_link`` to ``end_link`` of a URDF.

    Fixed joints are merged into the neighbouring links; ``continuous`` joints are unlimited
    revolute joints; joint axes may point in any direction (they are normalised).

    Args:
        source: path to a ``.urdf`` file, or the XML text itself.
        end_link: the end-effector link; default the single leaf below ``base_link``.
        base_link: the base link (world frame of the chain); default the root link.

    Returns:
        A :class:`PoEChain` whose ``fk`` is the pose of ``end_link`` in ``base_link``'s frame and
        whose ``link_poses`` are the child links of the moving joints.

    Raises:
        ValueError: a missing file, malformed XML, unknown links (the message lists the
            available ones), several leaves and no ``end_link``, unsupported joint types
            (``floating``, ``planar``, unknown) or ``mimic`` joints on the chain.
    """
    root = _read(source)
    links = [el.get("name") for el in root.findall("link")]
    joints = [_parse_joint(el) for el in root.findall("joint")]
    by_child: dict[str, _Joint] = {}
    children: dict[str, list[str]] = {name: [] for name in links}
    for j in joints:
        for link in (j.parent, j.child):
            if link not in children:
                raise ValueError(f"joint {j.name!r}: link {link!r} is not defined by a <link> element")
        if j.child in by_child:
            raise ValueError(f"link {j.child!r}: child of two joints ({by_child[j.child].name!r}, {j.name!r})")
        by_child[j.child] = j
        children[j.parent].append(j.child)
    roots = [name for name in links if name not in by_child]
    if base_link is None:
        if len(roots) != 1:
            raise ValueError(f"URDF: expected one root link, found {roots}; pass base_link")
        base_link = roots[0]
    elif base_link not in children:
        raise ValueError(f"base_link: unknown link {base_link!r}; available links: {sorted(links)}")
    if end_link is None:
        leaves, stack = [], [base_link]
        while stack:
            link = stack.pop()
            stack.extend(children[link])
            if not children[link]:
                leaves.append(link)
        if len(leaves) != 1:
            raise ValueError(
                f"end_link: the URDF has several leaf links below {base_link!r}, choose one of {sorted(leaves)}"
            )
        end_link = leaves[0]
    elif end_link not in children:
        raise ValueError(f"end_link: unknown link {end_link!r}; available links: {sorted(links)}")

    path: list[_Joint] = []
    link = end_link
    while link != base_link:
        if link not in by_child:
            raise ValueError(f"end_link: {end_link!r} is not below base_link {base_link!r}")
        path.append(by_child[link])
        link = by_child[link].parent
    path.reverse()

    T = np.eye(4)
    screws, link_homes, types, names, lower, upper = [], [], "", [], [], []
    for j in path:
        if j.kind in _UNSUPPORTED:
            raise ValueError(f"joint {j.name!r}: joint type {j.kind!r} is not supported")
        if j.kind != "fixed" and j.kind not in _MOVING:
            raise ValueError(
                f"joint {j.name!r}: unknown joint type {j.kind!r}; expected revolute, continuous, prismatic or fixed"
            )
        if j.mimic:
            raise ValueError(f"joint {j.name!r}: mimic joints are not supported")
        T = T @ j.origin
        if j.kind == "fixed":
            continue
        w = T[:3, :3] @ j.axis
        kind = _MOVING[j.kind]
        v = np.cross(T[:3, 3], w) if kind == "R" else w
        screws.append(np.concatenate([v, w if kind == "R" else np.zeros(3)]))
        link_homes.append(T.copy())
        types += kind
        names.append(j.name)
        lower.append(j.lower)
        upper.append(j.upper)
    if not types:
        raise ValueError(f"URDF: no moving joint between {base_link!r} and {end_link!r}")
    return PoEChain.from_screws(
        np.array(screws), T, types, lower=lower, upper=upper, link_homes=np.array(link_homes),
        joint_names=names, name=root.get("name", ""),
    )
