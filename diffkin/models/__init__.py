"""Chain models: DH tables, products of exponentials, URDF."""

from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain, to_poe
from diffkin.models.urdf import load_urdf

__all__ = ["DHChain", "PoEChain", "load_urdf", "to_poe"]
