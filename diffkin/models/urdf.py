"""A small strict URDF reader: the whole tree as a :class:`Robot`, or one serial chain as a :class:`PoEChain`."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from diffkin import _xml
from diffkin.models._tree import JointSpec, build
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

_KINDS = {"revolute": "R", "continuous": "R", "prismatic": "P", "fixed": "F"}


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """The rotation of a URDF ``rpy`` (fixed-axis roll-pitch-yaw, radians): ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _parse_joint(el: ET.Element) -> JointSpec:
    name = el.get("name")
    if not name:
        raise ValueError("URDF <joint>: missing 'name' attribute")
    where = f"URDF joint {name!r}"
    kind = el.get("type")
    parent, child = el.find("parent"), el.find("child")
    if parent is None or child is None or not parent.get("link") or not child.get("link"):
        raise ValueError(f"{where}: expected <parent link=...> and <child link=...>")
    if kind == "floating":
        kind_letter = "floating"
    elif kind not in _KINDS:
        raise ValueError(
            f"{where}: joint type {kind!r} is not supported; expected revolute, continuous, "
            "prismatic, fixed (or floating from the root link)"
        )
    else:
        kind_letter = _KINDS[kind]
    origin_el = el.find("origin")
    T = np.eye(4)
    T[:3, :3] = rpy_matrix(_xml.numbers(origin_el, "rpy", 3, "0 0 0", f"{where} <origin>"))
    T[:3, 3] = _xml.numbers(origin_el, "xyz", 3, "0 0 0", f"{where} <origin>")
    axis = _xml.numbers(el.find("axis"), "xyz", 3, "1 0 0", f"{where} <axis>")
    screw = np.zeros(6)
    lower, upper = -np.inf, np.inf
    if kind_letter in ("R", "P"):
        norm = np.linalg.norm(axis)
        if norm < 1e-12:
            raise ValueError(f"{where} <axis>: expected a nonzero direction, got {axis.tolist()}")
        axis = axis / norm
        screw = np.concatenate([np.zeros(3), axis]) if kind_letter == "R" else np.concatenate([axis, np.zeros(3)])
    limit = el.find("limit")
    if kind in ("revolute", "prismatic") and limit is not None:  # urdfdom's defaults: 0 each
        lower = float(_xml.numbers(limit, "lower", 1, "0", f"{where} <limit>")[0])
        upper = float(_xml.numbers(limit, "upper", 1, "0", f"{where} <limit>")[0])
        if lower > upper:
            raise ValueError(f"{where} <limit>: expected lower <= upper, got lower={lower}, upper={upper}")
    velocity = np.inf
    if kind_letter in ("R", "P") and limit is not None:
        velocity = _velocity(limit, where)
    mimic = None
    mimic_el = el.find("mimic")
    if mimic_el is not None and kind_letter in ("R", "P"):
        source = mimic_el.get("joint")
        if not source:
            raise ValueError(f"{where} <mimic>: missing 'joint' attribute")
        mimic = (
            source,
            float(_xml.numbers(mimic_el, "multiplier", 1, "1", f"{where} <mimic>")[0]),
            float(_xml.numbers(mimic_el, "offset", 1, "0", f"{where} <mimic>")[0]),
        )
    parent_link, child_link = parent.get("link", ""), child.get("link", "")
    return JointSpec(name, kind_letter, parent_link, child_link, T, screw, lower, upper, mimic, velocity=velocity)


def _velocity(limit: ET.Element, where: str) -> float:
    """A ``<limit>``'s ``velocity`` (rad/s, m/s): ``inf`` when absent or 0.

    urdfdom requires the attribute and Pinocchio copies it, 0 included; but 0 is how files without
    velocity limits fill the required attribute (44 ``<limit>``s of example-robot-data: the double
    pendulums', Kinova's, Romeo's), and read literally it would hold the joint still, so 0 means none (as
    gazebo_ros2_control reads it).
    """
    v = float(_xml.numbers(limit, "velocity", 1, "0", f"{where} <limit>")[0])
    if not v >= 0:
        raise ValueError(f"{where} <limit> velocity: expected a limit >= 0 (rad/s or m/s), got {v}")
    return np.inf if v == 0 else v


def _read(source) -> ET.Element:
    root, _ = _xml.read(source, "URDF")
    if root.tag != "robot":
        raise ValueError(f"source: expected a <robot> root element, got <{root.tag}>")
    return root


def _inertial(el: ET.Element, link: str) -> tuple[float, np.ndarray] | None:
    """``(mass, centre of mass in the link frame)`` of a link's ``<inertial>`` (``None`` without one)."""
    inertial = el.find("inertial")
    if inertial is None:
        return None
    where = f"URDF link {link!r} <inertial>"
    mass = float(_xml.numbers(inertial.find("mass"), "value", 1, None, f"{where} <mass>")[0])
    if mass < 0:
        raise ValueError(f"{where} <mass> value: expected a non-negative mass (kg), got {mass}")
    return mass, _xml.numbers(inertial.find("origin"), "xyz", 3, "0 0 0", f"{where} <origin>")


def _parse(root: ET.Element) -> tuple[list[JointSpec], list[str], dict[str, tuple[float, np.ndarray]]]:
    links, inertials = [], {}
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            raise ValueError("URDF <link>: missing 'name' attribute")
        links.append(name)
        inertial = _inertial(el, name)
        if inertial is not None:
            inertials[name] = inertial
    joints = [_parse_joint(el) for el in root.findall("joint")]
    known = set(links)
    for j in joints:
        for link in (j.parent, j.child):
            if link not in known:
                raise ValueError(f"URDF joint {j.name!r}: link {link!r} is not defined by a <link> element")
    return joints, links, inertials


def robot_from_urdf(root: ET.Element, *, floating: bool = False) -> Robot:
    """The :class:`Robot` of a parsed URDF (see :func:`diffkin.load_robot`)."""
    return _robot(root, *_parse(root), floating=floating)


def _robot(
    root: ET.Element,
    joints: list[JointSpec],
    links: list[str],
    inertials: dict[str, tuple[float, np.ndarray]],
    *,
    floating: bool = False,
) -> Robot:
    """The :class:`Robot` of the joints and links read from ``root`` (a floating root joint made the base)."""
    free = [j for j in joints if j.kind == "floating"]
    if free:
        children = {j.child for j in joints}
        j = free[0]
        if len(free) > 1 or j.parent in children or sum(k.parent == j.parent for k in joints) > 1:
            raise ValueError(
                f"URDF joint {j.name!r}: a floating joint is supported only as the single joint "
                "of the root link (the floating base)"
            )
        joints, links, floating = [k for k in joints if k is not j], [n for n in links if n != j.parent], True
    return build(joints, links, inertials=inertials, floating=floating, name=root.get("name", ""), where="URDF")


def load_urdf(source, end_link: str | None = None, *, base_link: str | None = None) -> PoEChain:
    """Read the serial chain from ``base_link`` to ``end_link`` of a URDF.

    Fixed joints are merged into the neighbouring links; joint limits are read as in
    :func:`diffkin.load_robot`; joint axes may point in any direction (they are normalised). A
    mimic joint on the chain is folded into its source joint (see :meth:`Robot.chain`).

    Args:
        source: path to a ``.urdf`` file, or the XML text itself.
        end_link: the end-effector link; default the single leaf below ``base_link``.
        base_link: the base link (world frame of the chain); default the root link.

    Returns:
        A :class:`PoEChain` whose ``fk`` is the pose of ``end_link`` in ``base_link``'s frame and
        whose ``link_poses`` are the child links of the moving joints.

    Raises:
        ValueError: a missing file, malformed XML, a link tree with loops, several roots or
            duplicate names, unknown links (the message lists the available ones), several leaves
            and no ``end_link``, unsupported joint types, or a mimic coupling a chain cannot hold.
    """
    root = _read(source)
    joints, links, inertials = _parse(root)
    robot = _robot(root, joints, links, inertials)
    for arg, link in (("base_link", base_link), ("end_link", end_link)):
        if link is not None and link not in links:
            raise ValueError(f"{arg}: unknown link {link!r}; available links: {sorted(links)}")
    if end_link is None:
        start = base_link if base_link is not None else robot.frame_names[0]
        children: dict[str, list[str]] = {}
        for j in joints:
            children.setdefault(j.parent, []).append(j.child)
        leaves, stack = [], [start]
        while stack:
            link = stack.pop()
            stack.extend(children.get(link, []))
            if not children.get(link):
                leaves.append(link)
        if len(leaves) != 1:
            raise ValueError(
                f"end_link: the URDF has several leaf links below {start!r}, choose one of {sorted(leaves)}"
            )
        end_link = leaves[0]
    return robot.chain(end_link, base_link)
