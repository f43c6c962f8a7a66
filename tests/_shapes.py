"""Collision shapes for the tests: random shapes of every kind (and coal's view of them), a toy arm's
collision geometry, an arm of capsules and a scene of obstacles."""

from __future__ import annotations

import os

import jax
import numpy as np
from _paths import ROOT

import diffkin as dk


def rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n, 3, 3)`` uniformly random rotations (from unit quaternions)."""
    w, x, y, z = (rng.normal(size=(n, 4)) / 1).T
    s = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / s, x / s, y / s, z / s
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


#: the primitive kinds of ``dk.collision`` and every unordered pair of them
SHAPE_KINDS = ("sphere", "capsule", "box", "plane")
SHAPE_PAIRS = [(a, b) for i, a in enumerate(SHAPE_KINDS) for b in SHAPE_KINDS[i:]]


def random_fields(kind: str, rng: np.random.Generator, n: int, points: float = 0.1) -> dict[str, np.ndarray]:
    """Fields of ``n`` random shapes of one kind in the cube ``[-0.5, 0.5]^3`` (sizes 0.02 to 0.4 m),
    so that about a third of the pairs overlap. A fraction ``points`` of the capsules have zero length."""
    if kind == "sphere":
        return {"center": rng.uniform(-0.5, 0.5, (n, 3)), "radius": rng.uniform(0.02, 0.4, n)}
    if kind == "capsule":
        a = rng.uniform(-0.5, 0.5, (n, 3))
        b = a + rng.normal(0, 0.3, (n, 3)) * (rng.uniform(size=(n, 1)) >= points)
        return {"a": a, "b": b, "radius": rng.uniform(0.01, 0.2, n)}
    if kind == "box":
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, :3, :3], T[:, :3, 3] = rotations(rng, n), rng.uniform(-0.5, 0.5, (n, 3))
        return {"pose": T, "half_extents": rng.uniform(0.02, 0.4, (n, 3))}
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return {"normal": normal, "offset": rng.uniform(-0.3, 0.3, n)}


def random_cylinders(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """Fields of ``n`` random cylinders in the cube ``[-0.5, 0.5]^3`` (radii 0.02 to 0.3 m, half lengths 0 to 0.3 m)."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = rotations(rng, n), rng.uniform(-0.5, 0.5, (n, 3))
    return {"pose": T, "radius": rng.uniform(0.02, 0.3, n), "half_length": rng.uniform(0.0, 0.3, n)}


def shape(kind: str, fields: dict, dtype=None):
    """A ``dk.collision`` shape of one kind (sphere, capsule, box, cylinder, plane) from :func:`random_fields`
    (:func:`random_cylinders`)."""
    classes = {"sphere": dk.collision.Sphere, "capsule": dk.collision.Capsule, "box": dk.collision.Box}
    classes["cylinder"] = dk.collision.Cylinder
    return classes.get(kind, dk.collision.Plane)(**{k: jax.numpy.asarray(v, dtype) for k, v in fields.items()})


def coal_shape(coal, kind: str, f: dict, i: int):
    """The coal geometry and placement of shape ``i`` of :func:`random_fields` (:func:`random_cylinders`)."""
    if kind == "cylinder":
        T = f["pose"][i]
        return coal.Cylinder(f["radius"][i], 2 * f["half_length"][i]), coal.Transform3s(T[:3, :3], T[:3, 3])
    if kind == "sphere":
        return coal.Sphere(f["radius"][i]), coal.Transform3s(np.eye(3), f["center"][i])
    if kind == "capsule":
        a, b = f["a"][i], f["b"][i]
        axis = b - a
        length = float(np.linalg.norm(axis))
        R = np.eye(3)
        if length > 0:
            z = axis / length
            x = np.cross([1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0], z)
            x /= np.linalg.norm(x)
            R = np.column_stack([x, np.cross(z, x), z])
        return coal.Capsule(f["radius"][i], length), coal.Transform3s(R, 0.5 * (a + b))
    if kind == "box":
        T = f["pose"][i]
        return coal.Box(*(2 * f["half_extents"][i])), coal.Transform3s(T[:3, :3], T[:3, 3])
    return coal.Halfspace(f["normal"][i], f["offset"][i]), coal.Transform3s()


TOY_COLLISION_URDF = """<robot name="toy">
  <link name="base"><collision><geometry><box size="0.4 0.4 0.1"/></geometry></collision></link>
  <link name="upper">
    <collision><origin xyz="0 0 0.25"/><geometry><cylinder radius="0.05" length="0.5"/></geometry></collision>
    <collision><origin xyz="0 0 0.5"/><geometry><sphere radius="0.07"/></geometry></collision>
  </link>
  <link name="lower"><collision><origin xyz="0 0 0.2" rpy="0 1.5707963267948966 0"/>
    <geometry><capsule radius="0.04" length="0.4"/></geometry></collision></link>
  <link name="hand"><collision><geometry><sphere radius="0.06"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="upper"/><child link="lower"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="fixed" type="fixed"><parent link="lower"/><child link="hand"/><origin xyz="0 0 0.4"/></joint>
</robot>"""


def toy_robot():
    """The toy arm of :data:`TOY_COLLISION_URDF` and its collision geometry."""
    robot = dk.load_robot(TOY_COLLISION_URDF)
    return robot, dk.collision.load(TOY_COLLISION_URDF, robot)


def planar_capsule_arm(j2_limit: str = "3", tip: bool = False) -> str:
    """A URDF: a box base and two capsule links turning about y (``j1``, ``j2``: limits +-3 and +-``j2_limit``
    rad), with a ``tip`` frame at the end of the second link if asked."""
    tip_link = '\n  <link name="tip"/>' if tip else ""
    tip_joint = (
        '\n  <joint name="tip" type="fixed"><parent link="lower"/><child link="tip"/><origin xyz="0 0 0.4"/></joint>'
        if tip
        else ""
    )
    return f"""<robot name="arm">
  <link name="base"><collision><geometry><box size="0.4 0.4 0.1"/></geometry></collision></link>
  <link name="upper"><collision><origin xyz="0 0 0.25"/>
    <geometry><capsule radius="0.05" length="0.5"/></geometry></collision></link>
  <link name="lower"><collision><origin xyz="0 0 0.2"/>
    <geometry><capsule radius="0.04" length="0.4"/></geometry></collision></link>{tip_link}
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="upper"/><child link="lower"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 1 0"/><limit lower="-{j2_limit}" upper="{j2_limit}"/></joint>{tip_joint}
</robot>"""


#: an arm of capsules and a ball hand (URDF collision geometry), and a scene of a turned box and a floor
#: (``dk.collision.load_scene``); ``SCENE_FILE`` the documented example scene
CAPSULE_ARM = """<robot name="arm">
  <link name="base"/>
  <link name="l1"><collision><origin xyz="0 0 0.2"/><geometry><capsule radius="0.04" length="0.4"/></geometry>
    </collision></link>
  <link name="l2"><collision><origin xyz="0 0 0.2"/><geometry><capsule radius="0.04" length="0.4"/></geometry>
    </collision></link>
  <link name="l3"><collision><origin xyz="0 0 0.15"/><geometry><capsule radius="0.03" length="0.3"/></geometry>
    </collision></link>
  <link name="hand"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-2.8" upper="2.8"/></joint>
  <joint name="tip" type="fixed"><parent link="l3"/><child link="hand"/><origin xyz="0 0 0.3"/></joint>
</robot>"""
BOX_CENTER = [0.45, -0.1, 0.25]
SCENE = {
    "margin": 0.02,
    "boxes": [{"position": BOX_CENTER, "quaternion": [0.9800666, 0, 0, 0.1986693], "half_extents": [0.12, 0.08, 0.1]}],
    "planes": [{"normal": [0, 0, 2], "offset": -0.2}],  # z <= -0.1, the normal's length divided out
}
SCENE_FILE = os.path.join(ROOT, "docs", "scene.json")
