"""Collision-aware IK whose only solutions lie in a narrow passage: a four-joint arm of capsules reaching
to the bottom of a slot between two walls. Fewer than one in a hundred of its plain IK solutions clear
the walls; every target is solved with ``avoid``, and every success is re-checked independently: the
hand's position by forward kinematics in NumPy, every capsule's distance to the walls and to the other
capsules by coal."""

from __future__ import annotations

import numpy as np
import pytest
from _reference import robot_poses

import diffkin as dk
from diffkin.collision import Box, World

#: (link, capsule centre along the link's z, radius, length); each link's joint is at the end of the
#: one before (the first 5 cm up), the first about z and the others about y; the hand at the end
CAPSULES = [("l1", 0.2, 0.03, 0.4), ("l2", 0.2, 0.03, 0.4), ("l3", 0.15, 0.03, 0.3), ("l4", 0.1, 0.025, 0.2)]
LIMITS = (3.0, 2.5, 2.8, 2.8)


def _arm() -> str:
    """The URDF of :data:`CAPSULES`: four revolute joints, a capsule per link, ``hand`` at the end."""
    links, joints, parent, offset = [], [], "base", 0.05
    for k, ((link, z, radius, length), limit) in enumerate(zip(CAPSULES, LIMITS, strict=True)):
        links.append(
            f'<link name="{link}"><collision><origin xyz="0 0 {z}"/>'
            f'<geometry><capsule radius="{radius}" length="{length}"/></geometry></collision></link>'
        )
        axis = "0 0 1" if k == 0 else "0 1 0"
        joints.append(
            f'<joint name="j{k + 1}" type="revolute"><parent link="{parent}"/><child link="{link}"/>'
            f'<origin xyz="0 0 {offset}"/><axis xyz="{axis}"/><limit lower="-{limit}" upper="{limit}"/></joint>'
        )
        parent, offset = link, 2 * z
    tip = f'<parent link="{parent}"/><child link="hand"/><origin xyz="0 0 {offset}"/>'
    joints.append(f'<joint name="tip" type="fixed">{tip}</joint>')
    return f'<robot name="arm"><link name="base"/>{"".join(links)}<link name="hand"/>{"".join(joints)}</robot>'


GAP, TOP = 0.065, 0.34  # the slot's half width at x = 0.6 m and its walls' height (m)
MARGIN = 0.01
#: walls ``(centre, half extents)``: 20 cm thick, 60 cm deep, from the floor to TOP
WALLS = [([0.6 + side * (GAP + 0.1), 0.0, TOP / 2], [0.1, 0.3, TOP / 2]) for side in (-1, 1)]


def _world() -> World:
    poses = np.stack([np.eye(4)] * len(WALLS))
    poses[:, :3, 3] = [c for c, _ in WALLS]
    return World(Box(poses, np.array([h for _, h in WALLS])))


def _coal_clearance(robot, q: np.ndarray, pairs) -> float:
    """The smallest coal distance of the arm's capsules at ``q`` to the walls and over ``pairs`` (capsule indices)."""
    coal = pytest.importorskip("coal")
    T = robot_poses(robot, q)
    placed = []
    for link, z, radius, length in CAPSULES:
        pose = T[robot.frame_names.index(link)] @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, z], [0, 0, 0, 1.0]])
        placed.append((coal.Capsule(radius, length), coal.Transform3s(pose[:3, :3], pose[:3, 3])))
    walls = [(coal.Box(*(2 * np.array(h))), coal.Transform3s(np.eye(3), np.array(c))) for c, h in WALLS]
    request = coal.DistanceRequest()
    d = [coal.distance(*a, *w, request, coal.DistanceResult()) for a in placed for w in walls]
    d += [coal.distance(*placed[i], *placed[j], request, coal.DistanceResult()) for i, j in pairs]
    return min(d)


def test_a_narrow_slot_is_reached_clear_of_its_walls():
    """Eight targets at the slot's bottom (1 cm apart along it): solved with ``avoid`` (margin 1 cm,
    float64), each success on its target (NumPy FK, 1e-9 m) and clear by the margin on coal's distances
    (1e-9 m); without ``avoid``, fewer than 1 % of 256 solutions of the first target clear the walls."""
    arm = _arm()
    robot = dk.load_robot(arm)
    geom = dk.collision.load(arm, robot)
    assert [name for name, *_ in CAPSULES] == list(geom.shape_links)
    world = _world()
    targets = np.array([0.6, 0.0, 0.12]) + np.linspace(0.0, 0.07, 8)[:, None] * [0.0, 1.0, 0.0]

    plain = dk.ik.solve(robot, {"hand": np.broadcast_to(targets[0], (256, 3))}, num_seeds=4)
    reached = np.asarray(plain.success)
    clear = np.asarray(dk.collision.clearance(robot, geom, np.asarray(plain.q), world)) >= MARGIN
    assert reached.mean() > 0.9 and (reached & clear).mean() < 0.01

    res = dk.ik.solve(robot, {"hand": targets}, avoid=dk.ik.Avoid(geom, world, margin=MARGIN))
    assert np.asarray(res.success).all()
    for q, target in zip(np.asarray(res.q), targets, strict=True):
        hand = robot_poses(robot, q)[robot.frame_names.index("hand"), :3, 3]
        assert np.linalg.norm(hand - target) <= 1e-5 + 1e-9
        assert _coal_clearance(robot, q, geom.pairs) >= MARGIN - 1e-9
