"""diffkin: differentiable robot kinematics in JAX.

The public names of the API contract: models, forward kinematics, Jacobians, and the
``robots``, ``ik``, ``srs`` and ``workspace`` modules.
"""

from diffkin import ik, robots, srs, workspace
from diffkin.kinematics import fk, jacobian, link_poses, manipulability
from diffkin.models import DHChain, PoEChain, load_urdf, to_poe

__all__ = [
    "DHChain", "PoEChain", "fk", "jacobian", "link_poses", "load_urdf", "manipulability",
    "ik", "robots", "srs", "to_poe", "workspace",
]
__version__ = "0.1.0"
