"""Batched inverse kinematics: damped least squares (Levenberg-Marquardt) or optax, from many seeds.

``solve(chain, target, ...)`` returns an :class:`IKResult`; see :func:`solve`.
"""

from diffkin.ik._result import IKResult
from diffkin.ik._solve import solve

__all__ = ["IKResult", "solve"]
