"""Collision geometry and signed distances.

Primitives (:class:`Sphere`, :class:`Capsule`, :class:`Box`, :class:`Cylinder`, :class:`Convex`,
:class:`Plane`) and their signed
:func:`distance` for every pair of kinds: positive between separated shapes, minus the penetration
depth when they overlap; batched, float32/float64, differentiable where the closest features are
unique. A robot's shapes from its URDF or MJCF file (:func:`load`, a :class:`Geometry`), obstacles
(:class:`World`, or a JSON scene file: :func:`load_scene`), and the robot's distances
(:func:`self_distances`, :func:`world_distances`, :func:`clearance`); the self-collision pairs that
sampled configurations find never or always in collision (:func:`sample_pairs`, saved as SRDF).
"""

from diffkin.collision._distance import distance
from diffkin.collision._geometry import Geometry, load
from diffkin.collision._pairs import PairSample, sample_pairs
from diffkin.collision._robot import World, clearance, self_distances, world_distances
from diffkin.collision._scene import Scene, load_scene
from diffkin.collision._shapes import Box, Capsule, Convex, Cylinder, Plane, Sphere

__all__ = [
    "Box",
    "Capsule",
    "Convex",
    "Cylinder",
    "Geometry",
    "PairSample",
    "Plane",
    "Scene",
    "Sphere",
    "World",
    "clearance",
    "distance",
    "load",
    "load_scene",
    "sample_pairs",
    "self_distances",
    "world_distances",
]
