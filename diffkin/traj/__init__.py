"""Collision-free trajectories: smooth timed motions from a start to a goal, within joint, velocity and
acceleration limits along the whole continuous motion, with a certified clearance between the knots.

``optimize(model, q_start, goal, avoid=..., limits=...)`` returns a :class:`Trajectory`
(:func:`optimize`; the guide: docs/traj.md).
"""

from diffkin.traj._limits import Limits
from diffkin.traj._optimize import optimize
from diffkin.traj._trajectory import Trajectory

__all__ = ["Limits", "Trajectory", "optimize"]
