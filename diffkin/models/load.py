"""``load_robot``: a URDF or MJCF description (path or XML text) as a :class:`Robot`."""

from __future__ import annotations

from diffkin.models import _xml
from diffkin.models.robot import Robot
from diffkin.models.urdf import robot_from_urdf


def load_robot(source, *, floating: bool = False) -> Robot:
    """Read a whole robot from a URDF file (root element ``<robot>``).

    Fixed joints are merged (their links become frames of the moving body they are fixed to);
    ``continuous`` joints and revolute or prismatic joints without ``<limit lower= upper=>``
    are unlimited (as urdfdom and Pinocchio read them); ``<mimic joint= multiplier= offset=>``
    makes a joint follow its source, ``q_j = multiplier * q_source + offset``, outside ``q``. A
    ``floating`` joint from the root link makes its child the floating root.

    Args:
        source: path to the file, or the XML text itself.
        floating: make the root a floating base (its pose ``T_world_root`` becomes an argument
            of :func:`diffkin.fk`, and :func:`diffkin.jacobian` can include its six columns).

    Returns:
        The :class:`Robot`: frames are every link, in a depth-first walk from the root;
        ``q`` is the actuated (non-mimic, non-fixed) joints in the same order.

    Raises:
        TypeError: ``source`` is not a path or string.
        ValueError: a missing file, malformed XML, an unknown root element, or anything the
            format's reader rejects (loops, several roots, duplicate names, unsupported joints,
            mimic joints of missing joints or in cycles), with the element named.
    """
    root, _ = _xml.read(source)
    if root.tag == "robot":
        robot = robot_from_urdf(root)
    else:
        raise ValueError(f"source: expected a <robot> (URDF) root element, got <{root.tag}>")
    return robot.replace(floating=True) if floating else robot
