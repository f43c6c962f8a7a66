"""Models: DH tables, products of exponentials, whole robots (trees), and their loaders."""

from diffkin._cache import use_cache_by_default
from diffkin.models.dh import DHChain
from diffkin.models.load import load_robot
from diffkin.models.poe import PoEChain, to_poe
from diffkin.models.robot import Robot
from diffkin.models.urdf import load_urdf

__all__ = ["DHChain", "PoEChain", "Robot", "load_robot", "load_urdf", "to_poe"]

use_cache_by_default()  # every computation starts from a model: JAX's persistent cache goes on here
