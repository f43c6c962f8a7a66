"""Building a :class:`~diffkin.models.robot.Robot` from what the loaders read: :func:`build` takes a
host-side list of :class:`JointSpec` and checks the tree (one root, no loops, one parent per link,
known mimic sources, no mimic cycles), merges fixed joints into frames and masses into bodies.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import jax.numpy as jnp
import numpy as np

from diffkin import _validate as check
from diffkin.models.robot import Robot


@dataclasses.dataclass(frozen=True)
class JointSpec:
    """One joint of a robot description, as the loaders read it (host side, float64).

    Attributes:
        name: joint name (unique).
        kind: ``"R"`` (revolute), ``"P"`` (prismatic), ``"F"`` (fixed) or ``"B"`` (one of the three
            consecutive joints of a ball joint: :mod:`diffkin.models._ball`).
        parent, child: link names.
        origin: ``(4, 4)`` pose of the joint frame in the parent link frame; the child link frame
            is the joint frame moved by ``exp([screw] theta)``.
        screw: ``(6,)`` unit screw ``[v; w]`` in the joint frame (unused for fixed joints).
        lower, upper: limits (``-inf``/``inf`` if unlimited).
        mimic: ``(source joint, multiplier, offset)``: ``theta = multiplier * theta_source + offset``.
        offset: constant added to ``theta`` (MJCF ``ref``: the joint angle is ``q - ref``).
        velocity: velocity limit, rad/s or m/s (``inf`` if none: MJCF, a URDF ``<limit>`` without it).
    """

    name: str
    kind: str
    parent: str
    child: str
    origin: np.ndarray
    screw: np.ndarray
    lower: float = -np.inf
    upper: float = np.inf
    mimic: tuple[str, float, float] | None = None
    offset: float = 0.0
    velocity: float = np.inf


def build(
    joints: Sequence[JointSpec],
    links: Sequence[str],
    *,
    frames: Sequence[tuple[str, str, np.ndarray]] = (),
    inertials: Mapping[str, tuple[float, np.ndarray]] | None = None,
    unknown_masses: Sequence[str] = (),
    floating: bool = False,
    name: str = "",
    where: str = "robot",
) -> Robot:
    """Check a tree description and build the :class:`Robot`.

    Args:
        joints: every joint, in file order (the order of ``q`` follows a depth-first walk of the
            tree that visits children in this order).
        links: every named link; joints may also connect unnamed links (not frames; the MJCF
            loader uses them for bodies with several joints).
        frames: extra fixed frames ``(name, link, T_link_frame)``.
        inertials: ``{link: (mass, centre of mass (3,) in the link frame)}`` (links left out are
            massless); merged per body.
        unknown_masses: links whose mass the description does not determine, with the reason.
        floating: whether the root moves.
        name: robot name.
        where: what the description is called in error messages (``"URDF"``, ``"MJCF"``).

    Raises:
        ValueError: duplicate names, a link with two parents, several roots or none, kinematic
            loops, unknown links, mimic joints of missing or fixed joints, mimic cycles.
    """
    for kind, names in (("link", list(links)), ("joint", [j.name for j in joints])):
        seen = set()
        for n in names:
            if n in seen:
                raise ValueError(f"{where}: duplicate {kind} name {n!r}")
            seen.add(n)
    by_child: dict[str, JointSpec] = {}
    children: dict[str, list[JointSpec]] = {}
    for j in joints:
        if j.parent == j.child:
            raise ValueError(f"{where}: joint {j.name!r} connects link {j.parent!r} to itself (a kinematic loop)")
        if j.child in by_child:
            raise ValueError(
                f"{where}: link {j.child!r} is the child of two joints ({by_child[j.child].name!r}, "
                f"{j.name!r}); a tree has one parent per link (kinematic loops are not supported)"
            )
        by_child[j.child] = j
        children.setdefault(j.parent, []).append(j)
    everything = list(dict.fromkeys([*links, *(x for j in joints for x in (j.parent, j.child))]))
    roots = [n for n in everything if n not in by_child]
    if not everything:
        raise ValueError(f"{where}: no links")
    if len(roots) != 1:
        if not roots:
            raise ValueError(f"{where}: no root link (every link is a child: a kinematic loop)")
        raise ValueError(f"{where}: expected one root link, found {len(roots)}: {roots}")
    root = roots[0]

    # Depth-first walk from the root (children in file order): fixed joints become frames of their body.
    body_of: dict[str, tuple[int, np.ndarray]] = {root: (0, np.eye(4))}
    moving: list[JointSpec] = []
    joint_poses, parents = [], []
    order = [root]  # links in the order of the walk
    stack = list(reversed(children.get(root, [])))
    while stack:
        j = stack.pop()
        order.append(j.child)
        body, T_body_link = body_of[j.parent]
        if j.kind == "F":
            body_of[j.child] = (body, T_body_link @ j.origin)
        else:
            moving.append(j)
            parents.append(body)
            joint_poses.append(T_body_link @ j.origin)
            body_of[j.child] = (len(moving), np.eye(4))
        stack.extend(reversed(children.get(j.child, [])))
    unreached = [n for n in everything if n not in body_of]
    if unreached:
        raise ValueError(f"{where}: links {unreached} are not connected to the root {root!r} (a kinematic loop)")

    index = {j.name: k for k, j in enumerate(moving)}
    fixed = {j.name for j in joints if j.kind == "F"}
    actuated = [j for j in moving if j.mimic is None]
    q_index = {j.name: i for i, j in enumerate(actuated)}
    sources, multipliers, offsets = [], [], []
    for j in moving:
        # positions: pos_j = mult * pos_src + off along the mimic chain, so pos_j = m q_src + o;
        # the joint's angle is theta_j = pos_j + j.offset.
        m, o, cur, followed = 1.0, 0.0, j, [j.name]
        while cur.mimic is not None:
            src, mult, off = cur.mimic
            if src in fixed:
                raise ValueError(f"{where}: joint {cur.name!r} mimics {src!r}, a fixed joint")
            if src not in index:
                raise ValueError(f"{where}: joint {cur.name!r} mimics {src!r}, which is not a joint of the robot")
            if src in followed:
                raise ValueError(f"{where}: mimic joints form a cycle: {' -> '.join([*followed, src])}")
            followed.append(src)
            m, o = m * mult, o + m * off
            cur = moving[index[src]]
        sources.append(q_index[cur.name])
        multipliers.append(m)
        offsets.append(o + j.offset)

    named = set(links) | {root}
    frame_names = [n for n in order if n in named]
    frame_specs = [(n, *body_of[n]) for n in frame_names]
    for fname, link, T in frames:
        if fname in frame_names:
            raise ValueError(f"{where}: frame {fname!r} has the name of a link or of another frame")
        if link not in body_of:
            raise ValueError(f"{where}: frame {fname!r} is attached to unknown link {link!r}")
        body, T_body_link = body_of[link]
        frame_specs.append((fname, body, T_body_link @ check.rigid_transform(T, f"frame {fname!r}")))
        frame_names.append(fname)
    masses, moments = np.zeros(len(moving) + 1), np.zeros((len(moving) + 1, 3))
    for link, (mass, com) in (inertials or {}).items():
        if link in body_of:  # (a floating URDF joint's world link is not part of the robot)
            body, T_body_link = body_of[link]
            masses[body] += mass
            moments[body] += mass * (T_body_link[:3, :3] @ com + T_body_link[:3, 3])
    body_coms = moments / np.where(masses > 0, masses, 1.0)[:, None]
    f = jnp.asarray
    nj = len(moving)
    return Robot(
        joint_poses=f(np.array(joint_poses).reshape(nj, 4, 4)),
        screws=f(np.array([j.screw for j in moving], np.float64).reshape(nj, 6)),
        multipliers=f(np.array(multipliers, np.float64)),
        offsets=f(np.array(offsets, np.float64)),
        frame_poses=f(np.array([T for _, _, T in frame_specs]).reshape(-1, 4, 4)),
        lower=f(np.array([j.lower for j in actuated], np.float64)),
        upper=f(np.array([j.upper for j in actuated], np.float64)),
        velocity=f(np.array([j.velocity for j in actuated], np.float64)),
        masses=f(masses),
        body_coms=f(body_coms),
        parents=tuple(parents),
        joint_types="".join(j.kind for j in moving),
        sources=tuple(sources),
        tree_joints=tuple(j.name for j in moving),
        frame_bodies=tuple(b for _, b, _ in frame_specs),
        frame_names=tuple(frame_names),
        joint_names=tuple(j.name for j in actuated),
        floating=bool(floating),
        name=name,
        unknown_masses=tuple(unknown_masses),
        loop_points=f(np.zeros((0, 2, 3))),
        dependent_home=f(np.zeros(0)),
    )
