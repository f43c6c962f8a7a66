"""Built-in robot models, each from a cited published table, and URDFs shipped with the package."""

from __future__ import annotations

from importlib import resources

import numpy as np

from diffkin.models.dh import DHChain

_PI2 = np.pi / 2
_IIWA_LIMITS_DEG = np.array([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])
_URDFS = ("iiwa7", "iiwa14")
#: The built-in robots by name (``dk.robots.<name>()``: the CLI's and the viewer's robot names).
BUILTIN = ("iiwa7", "iiwa14", "panda", "ur5", "puma560")


def _iiwa(d_bs: float, d_se: float, d_ew: float, d_wf: float, name: str) -> DHChain:
    alpha = [-_PI2, _PI2, _PI2, -_PI2, -_PI2, _PI2, 0.0]
    d = [d_bs, 0.0, d_se, 0.0, d_ew, 0.0, d_wf]
    table = np.stack([np.zeros(7), alpha, d, np.zeros(7)], axis=1)
    limits = np.deg2rad(_IIWA_LIMITS_DEG)
    return DHChain.from_table(
        table, lower=-limits, upper=limits, name=name, joint_names=[f"{name}_joint_{i + 1}" for i in range(7)]
    )


def iiwa7() -> DHChain:
    """KUKA LBR iiwa 7 R800, standard DH, base at the mounting flange, end at the media flange.

    Lengths ``d_bs, d_se, d_ew, d_wf = 0.34, 0.40, 0.40, 0.126`` m and limits ``±170, ±120, ±170,
    ±120, ±170, ±120, ±175`` degrees from KUKA's LBR iiwa specification (KUKA Roboter GmbH,
    "LBR iiwa 7 R800, LBR iiwa 14 R820 Specifications", 2015); frame assignment as in Faria et
    al., Mechanism and Machine Theory 2018, with the joint signs and zeros of KUKA's controller.
    """
    return _iiwa(0.34, 0.40, 0.40, 0.126, "iiwa7")


def iiwa14() -> DHChain:
    """KUKA LBR iiwa 14 R820, standard DH, base at the mounting flange, end at the media flange.

    Lengths ``d_bs, d_se, d_ew, d_wf = 0.36, 0.42, 0.40, 0.126`` m and limits ``±170, ±120, ±170,
    ±120, ±170, ±120, ±175`` degrees (KUKA Roboter GmbH, "LBR iiwa 7 R800, LBR iiwa 14 R820
    Specifications", 2015); frames as in :func:`iiwa7`.
    """
    return _iiwa(0.36, 0.42, 0.40, 0.126, "iiwa14")


def panda() -> DHChain:
    """Franka Emika Panda, modified (Craig) DH, from Franka's published table, flange included.

    Table and limits from Franka Emika, "Robot and interface specifications" (FCI documentation,
    frames ``O_0 ... O_7`` and ``F``): ``a = [0, 0, 0, 0.0825, -0.0825, 0, 0.088]``,
    ``d = [0.333, 0, 0.316, 0, 0.384, 0, 0]``, ``alpha = [0, -pi/2, pi/2, pi/2, -pi/2, pi/2, pi/2]``;
    the flange frame ``F`` is ``d = 0.107`` along the last z axis (the ``tool``).
    """
    a = [0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088]
    d = [0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0]
    alpha = [0.0, -_PI2, _PI2, _PI2, -_PI2, _PI2, _PI2]
    table = np.stack([a, alpha, d, np.zeros(7)], axis=1)
    tool = np.eye(4)
    tool[2, 3] = 0.107
    return DHChain.from_table(
        table,
        modified=True,
        tool=tool,
        name="panda",
        lower=[-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973],
        upper=[2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973],
        joint_names=[f"panda_joint{i + 1}" for i in range(7)],
    )


def ur5() -> DHChain:
    """Universal Robots UR5 (CB-series), standard DH, base frame to tool flange.

    From Universal Robots, "DH parameters for calculations of kinematics and dynamics" (UR
    support article): ``d = [0.089159, 0, 0, 0.10915, 0.09465, 0.0823]``,
    ``a = [0, -0.425, -0.39225, 0, 0, 0]``, ``alpha = [pi/2, 0, 0, pi/2, -pi/2, 0]``;
    every joint ``±360`` degrees.
    """
    a = [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0]
    d = [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823]
    alpha = [_PI2, 0.0, 0.0, _PI2, -_PI2, 0.0]
    table = np.stack([a, alpha, d, np.zeros(6)], axis=1)
    lim = np.full(6, 2 * np.pi)
    names = [
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    ]
    return DHChain.from_table(table, lower=-lim, upper=lim, name="ur5", joint_names=names)


def puma560() -> DHChain:
    """Unimation PUMA 560, standard DH.

    Kinematic table of Corke and Armstrong-Helouvry, "A search for consensus among model
    parameters reported for the PUMA 560 robot", ICRA 1994 (as in Corke's Robotics Toolbox):
    ``a = [0, 0.4318, 0.0203, 0, 0, 0]``, ``d = [0, 0, 0.15005, 0.4318, 0, 0]``,
    ``alpha = [pi/2, 0, -pi/2, pi/2, -pi/2, 0]``; limits (degrees) ``[-160, 160], [-45, 225],
    [-225, 45], [-110, 170], [-100, 100], [-266, 266]``.
    """
    a = [0.0, 0.4318, 0.0203, 0.0, 0.0, 0.0]
    d = [0.0, 0.0, 0.15005, 0.4318, 0.0, 0.0]
    alpha = [_PI2, 0.0, -_PI2, _PI2, -_PI2, 0.0]
    table = np.stack([a, alpha, d, np.zeros(6)], axis=1)
    lower = np.deg2rad([-160.0, -45.0, -225.0, -110.0, -100.0, -266.0])
    upper = np.deg2rad([160.0, 225.0, 45.0, 170.0, 100.0, 266.0])
    return DHChain.from_table(table, lower=lower, upper=upper, name="puma560")


def planar(lengths) -> DHChain:
    """Planar arm of revolute joints about parallel z axes (the textbook nR arm), unlimited joints.

    Standard DH with ``a = lengths``, ``alpha = d = theta_offset = 0``: for two links
    ``x = a1 cos t1 + a2 cos(t1 + t2)``, ``y = a1 sin t1 + a2 sin(t1 + t2)``.

    Args:
        lengths: ``(n,)`` positive link lengths, metres.
    """
    a = np.asarray(lengths, dtype=np.float64)
    if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ValueError(f"lengths: expected a non-empty list of positive link lengths, got {lengths!r}")
    n = a.size
    table = np.stack([a, np.zeros(n), np.zeros(n), np.zeros(n)], axis=1)
    return DHChain.from_table(table, name=f"planar{n}R")


def urdf_path(name: str) -> str:
    """Path of a URDF shipped with diffkin for the built-in robot ``name`` (``"iiwa7"``, ``"iiwa14"``).

    Its chain from the root link to the flange link has the same base frame, flange frame
    and joint signs as the DH model: ``fk(load_urdf(urdf_path(name)), q) == fk(robots.<name>(), q)``.
    """
    if name not in _URDFS:
        raise ValueError(f"name: expected one of {_URDFS}, got {name!r}")
    return str(resources.files("diffkin.robots") / "urdf" / f"{name}.urdf")


__all__ = ["iiwa7", "iiwa14", "panda", "planar", "puma560", "ur5", "urdf_path"]
