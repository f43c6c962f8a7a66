"""Spherical-revolute-spherical arms (KUKA LBR iiwa): closed-form IK over the arm angle ``psi``.

A 7-joint SRS arm reaching a 6-DoF pose has a one-parameter family of solutions: the elbow
swings on a circle about the shoulder-wrist line. :func:`ik` gives the solution for an arm
angle ``psi`` and a global configuration ``gc = (gc2, gc4, gc6)`` (the signs of joints 2, 4, 6),
:func:`arm_angle` is its inverse, :func:`feasible_arm_angles` the exact set of ``psi`` within the
joint limits, and :func:`sample_self_motion` draws exact solutions spread over that set;
:data:`ALL_GC` lists the eight global configurations. All are
pure, batched by broadcasting, and work under ``jit``, ``vmap`` and ``grad`` in float32 and float64.
"""

from diffkin.srs._arm import SRSArm, iiwa7, iiwa14
from diffkin.srs._closed_form import arm_angle, ik
from diffkin.srs._intervals import ALL_GC, feasible_arm_angles, sample_self_motion

__all__ = ["ALL_GC", "SRSArm", "arm_angle", "feasible_arm_angles", "iiwa7", "iiwa14", "ik", "sample_self_motion"]
