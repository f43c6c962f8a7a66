"""Collision geometry and signed distances.

Primitives (:class:`Sphere`, :class:`Capsule`, :class:`Box`, :class:`Plane`) and their signed
:func:`distance` for every pair of kinds: positive between separated shapes, minus the penetration
depth when they overlap; batched, float32/float64, differentiable where the closest features are
unique.
"""

from diffkin.collision._distance import distance
from diffkin.collision._shapes import Box, Capsule, Plane, Sphere

__all__ = ["Box", "Capsule", "Plane", "Sphere", "distance"]
