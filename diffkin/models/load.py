"""``load_robot``: a URDF or MJCF description (path or XML text) as a :class:`Robot`."""

from __future__ import annotations

import dataclasses

from diffkin import _xml
from diffkin.models.mjcf import robot_from_mjcf
from diffkin.models.robot import Robot
from diffkin.models.urdf import robot_from_urdf


def load_robot(source, *, floating: bool = False) -> Robot:
    """Read a whole robot from a URDF (root element ``<robot>``) or MJCF (root ``<mujoco>``) file.

    URDF: fixed joints are merged (their links become frames of the moving body they are fixed
    to); ``continuous`` joints are unlimited; a revolute or prismatic joint's ``<limit lower=
    upper=>`` limits it, each attribute 0 if absent (as urdfdom and Pinocchio read it). A
    revolute or prismatic joint without ``<limit>`` is unlimited: urdfdom (so Pinocchio and ROS)
    rejects such a file, diffkin reads it (wheels are often written so). ``<limit velocity=>``
    gives :attr:`Robot.velocity` (rad/s, m/s; 0 or absent: ``inf``, none). ``<mimic joint=
    multiplier= offset=>`` makes a joint follow its source, ``q_j = multiplier * q_source +
    offset``, outside ``q``. A ``floating`` joint from the root link makes its child the
    floating root.

    MJCF (see :mod:`diffkin.models.mjcf`): bodies (with ``pos`` and ``quat``/``axisangle``/
    ``euler``/``xyaxes``/``zaxis``, in ``<compiler angle= eulerseq=>`` units), ``<frame>``s,
    ``<default>`` classes, hinge and slide joints (several per body, applied in order; ``ref``,
    ``range``, ``limited``), ball joints (three entries of ``q``), named sites as frames,
    ``<include>``; a linear ``<equality><joint polycoef=>`` makes ``joint1`` follow ``joint2``,
    ``q1 - ref1 = c0 + c1 (q2 - ref2)``; a linear ``<equality><tendon>`` over fixed tendons makes the
    last joint of ``tendon1`` follow the others (MuJoCo's ``L1 - L1_0 = c0 + c1 (L2 - L2_0)``,
    ``L = sum coef_i q_i``); ``<equality><connect>`` and ``<weld body1>`` close loops (their dependent
    joints, ``robot.dependent_names``, are solved from ``q`` in every pass: :func:`diffkin.loop_closure`);
    a free joint on a top-level body makes it the floating root. The world body is the frame
    ``"world"``; angles in ``q`` and limits are radians. MJCF has no joint velocity limits
    (``velocity``: ``inf``).

    Args:
        source: path to the file, or the XML text itself.
        floating: make the root a floating base (its pose ``T_world_root`` becomes an argument
            of :func:`diffkin.fk`, and :func:`diffkin.jacobian` can include its six columns).

    Returns:
        The :class:`Robot`: frames are every link (or body), in a depth-first walk from the
        root, then the extra frames (MJCF sites); ``q`` is the actuated (non-mimic, non-fixed)
        joints in the same order.

    Raises:
        TypeError: ``source`` is not a path or string.
        ValueError: a missing file, malformed XML, an unknown root element, or anything the
            format's reader rejects (a URDF's loops, several roots, duplicate names, unsupported joints
            or elements, mimic joints of missing joints or in cycles), with the element named.
    """
    root, path = _xml.read(source)
    if root.tag == "robot":
        robot = robot_from_urdf(root)
    elif root.tag == "mujoco":
        robot = robot_from_mjcf(root, path)
    else:
        raise ValueError(f"source: expected a <robot> (URDF) or <mujoco> (MJCF) root element, got <{root.tag}>")
    return dataclasses.replace(robot, floating=True) if floating else robot
