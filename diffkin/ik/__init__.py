"""Batched inverse kinematics: damped least squares (Levenberg-Marquardt) or optax, from many seeds.

``solve(chain, target, ...)`` returns an :class:`IKResult`; ``solve_path(chain, waypoints, ...)``
a :class:`PathResult` (each waypoint from the previous solution, joint steps bounded).
"""

from diffkin.ik._path import PathResult, solve_path
from diffkin.ik._result import IKResult
from diffkin.ik._solve import solve
from diffkin.ik._terms.avoid import Avoid

__all__ = ["Avoid", "IKResult", "PathResult", "solve", "solve_path"]
