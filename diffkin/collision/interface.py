"""What the packages built on collision use beyond its public names (internal: not in API.md).

IK's clearance term (and the trajectories that reuse it) places the shapes by its own frames' poses and
measures distances and their motions in its own layouts, and checks an ``Avoid``'s geometry against the
robot (``diffkin.ik.interface.check_avoid``, which every function taking ``avoid=`` calls); the viewer
draws a convex shape by its hull; the trajectories' search measures polytopes of fewer vertices (``inner``).
"""

from diffkin.collision._fit import hull
from diffkin.collision._geometry import moved
from diffkin.collision._inner import inner
from diffkin.collision._near import NEAR_SHARE, near_motions
from diffkin.collision._robot import (
    batch_last,
    check_geometry,
    expanded,
    obstacles_last,
    pair_blocks,
    smallest_distance,
    take,
)

__all__ = [
    "NEAR_SHARE",
    "batch_last",
    "check_geometry",
    "expanded",
    "hull",
    "inner",
    "moved",
    "near_motions",
    "obstacles_last",
    "pair_blocks",
    "smallest_distance",
    "take",
]
