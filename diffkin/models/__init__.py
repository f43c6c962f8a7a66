"""Models: DH tables, products of exponentials, whole robots (trees), and their loaders."""

from diffkin.models.dh import DHChain
from diffkin.models.load import load_robot
from diffkin.models.poe import PoEChain, to_poe
from diffkin.models.robot import Robot
from diffkin.models.urdf import load_urdf

__all__ = ["DHChain", "PoEChain", "Robot", "load_robot", "load_urdf", "to_poe"]
