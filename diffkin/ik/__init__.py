"""Batched inverse kinematics: damped least squares (Levenberg-Marquardt) or optax, from many seeds.

``solve(chain, target, ...)`` returns an :class:`IKResult`; ``solve_path(chain, waypoints, ...)``
a :class:`PathResult` (each waypoint from the previous solution, joint steps bounded);
``step(model, q, targets, dt=...)`` a :class:`Step` (one velocity-IK step with hard limits).
"""

from diffkin.ik._path import PathResult, solve_path
from diffkin.ik._result import IKResult
from diffkin.ik._solve import solve
from diffkin.ik._step import Step, step
from diffkin.ik._terms.avoid import Avoid

__all__ = ["Avoid", "IKResult", "PathResult", "Step", "solve", "solve_path", "step"]
