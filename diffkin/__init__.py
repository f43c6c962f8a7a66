"""diffkin: differentiable robot kinematics in JAX.

The public names of the API contract: models, forward kinematics, Jacobians, and the
``robots``, ``ik``, ``se3``, ``srs``, ``workspace`` and ``collision`` modules. They are imported on first use
(``dk.fk``, ``from diffkin import fk``), so that ``import diffkin`` alone does not import JAX and
the ``diffkin`` command answers ``--help`` and usage errors at once. The first use of a model switches
JAX's persistent compilation cache on unless the user configured one or set ``DIFFKIN_CACHE_DIR=off``
(:mod:`diffkin._cache`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the same names, eagerly, for type checkers and editors
    from diffkin import collision, ik, robots, se3, srs, traj, workspace
    from diffkin.kinematics import com, com_jacobian, fk, jacobian, link_poses, loop_closure, manipulability
    from diffkin.models import DHChain, PoEChain, Robot, load_robot, load_urdf, to_poe

_HOMES = {
    "collision": None,
    "ik": None,
    "robots": None,
    "se3": None,
    "srs": None,
    "traj": None,
    "workspace": None,  # submodules
    "viewer": None,  # optional: needs viser and trimesh (pip install "diffkin[viewer]")
    "com": "diffkin.kinematics",
    "com_jacobian": "diffkin.kinematics",
    "loop_closure": "diffkin.kinematics",
    "fk": "diffkin.kinematics",
    "jacobian": "diffkin.kinematics",
    "link_poses": "diffkin.kinematics",
    "manipulability": "diffkin.kinematics",
    "DHChain": "diffkin.models",
    "PoEChain": "diffkin.models",
    "load_urdf": "diffkin.models",
    "to_poe": "diffkin.models",
    "Robot": "diffkin.models",
    "load_robot": "diffkin.models",
}

__all__ = [
    "DHChain",
    "PoEChain",
    "Robot",
    "com",
    "com_jacobian",
    "loop_closure",
    "fk",
    "jacobian",
    "link_poses",
    "load_robot",
    "load_urdf",
    "manipulability",
    "collision",
    "ik",
    "robots",
    "se3",
    "srs",
    "to_poe",
    "traj",
    "workspace",
]
__version__ = "0.1.0"  # the package version (pyproject.toml reads it from here)


def __getattr__(name: str):
    """Import a public name on first use (PEP 562) and keep it as a module attribute."""
    if name not in _HOMES:
        raise AttributeError(f"module 'diffkin' has no attribute {name!r}")
    home = _HOMES[name]
    value = importlib.import_module(f"diffkin.{name}") if home is None else getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
