"""How far a robot's collision shapes can move per unit of joint motion, for any configuration.

For a joint ``c`` and a shape ``s`` it carries, :func:`reach` gives ``R[c, s]`` such that every point of
``s`` moves at most ``R[c, s] |dq_c|`` when joint ``c`` moves by ``dq_c`` (the others fixed), in every
configuration: for a revolute joint the largest distance from its axis to the shape, for a prismatic
one 1 (times the length of its axis). So over a motion each point of ``s`` moves at most
``sum_c R[c, s] int |dq_c/dt| dt``.

The distance from joint ``c``'s axis to a point ``x`` of ``s`` depends on the joints between them; it
is bounded without them by the triangle inequality along the chain of joints ``c = c_1, ..., c_m``
that move ``s``: each ``c_k`` has a point ``a_k`` on its axis (fixed in the bodies on both sides of
it; the one nearest its child body's origin, so that the steps are about the links' lengths),
``|a_k - a_{k+1}|`` is constant (both points fixed in the body between the two joints), so
``|x - a_1| <= sum_k |a_k - a_{k+1}| + |a_m - centre_s| + radius_s``, measured once at ``q = 0``. A
prismatic joint's point slides with it: its stroke (the largest ``|q|`` within its limits) is
added; an unlimited one makes the bound infinite (nothing downstream is then certified).
"""

from __future__ import annotations

import numpy as np

from diffkin import _rigid as rg
from diffkin.collision import Geometry
from diffkin.models.robot import Robot


def _host(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _bounding(geom: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Per shape, a centre ``(S, 3)`` in its frame and a radius ``(S,)`` of a ball containing it."""
    sph, cap, box, cyl, cvx = geom.shapes
    centres, radii = [], []
    centres.append(_host(sph.center))
    radii.append(_host(sph.radius))
    a, b = _host(cap.a), _host(cap.b)
    centres.append((a + b) / 2)
    radii.append(np.linalg.norm(a - b, axis=-1) / 2 + _host(cap.radius))
    centres.append(_host(box.pose)[:, :3, 3])
    radii.append(np.linalg.norm(_host(box.half_extents), axis=-1))
    centres.append(_host(cyl.pose)[:, :3, 3])
    radii.append(np.hypot(_host(cyl.radius), _host(cyl.half_length)))
    T, V = _host(cvx.pose), _host(cvx.vertices)
    world = np.einsum("nij,nvj->nvi", T[:, :3, :3], V) + T[:, None, :3, 3]
    mid = (world.max(axis=1) + world.min(axis=1)) / 2 if len(V) else np.zeros((0, 3))
    centres.append(mid)
    radii.append(np.linalg.norm(world - mid[:, None], axis=-1).max(axis=1) if len(V) else np.zeros(0))
    return np.concatenate([c.reshape(-1, 3) for c in centres]), np.concatenate([r.reshape(-1) for r in radii])


def reach(robot: Robot, geom: Geometry) -> np.ndarray:
    """``(dof, S)``: ``R[c, s]`` of the module docstring (0 where joint ``c`` does not move shape ``s``).

    Needs the robot and geometry concrete (closed over by ``jit``, not traced arguments).
    """
    dof, frames = robot.dof, len(robot.frame_names)
    kin = robot.forward([np.float64(0.0)] * dof, rg.IDENTITY)
    twists = np.zeros((frames, dof, 6))
    origins = np.zeros((frames, 3))
    for f in range(frames):
        cols = kin.columns(f)
        for c, (v, w) in enumerate(cols):
            twists[f, c] = [float(e) for e in (*v, *w)]
        T = kin.pose(f)
        origins[f] = [float(e) for e in T.p]
    moves = np.linalg.norm(twists, axis=-1) > 1e-12  # (F, dof): joint c moves frame f
    sizes = moves.sum(axis=1)
    lower, upper = _host(robot.lower), _host(robot.upper)
    # per joint: the frame nearest to it that it moves (its child body), its depth and a point on its axis
    depth = np.zeros(dof, dtype=np.int64)
    point = np.zeros((dof, 3))
    speed_w, speed_v = np.zeros(dof), np.zeros(dof)
    for c in range(dof):
        moved = np.flatnonzero(moves[:, c])
        if not len(moved):
            continue
        f = int(moved[np.argmin(sizes[moved])])
        depth[c] = sizes[f]
        v_c, w_c = twists[f, c, :3], twists[f, c, 3:]
        nw = np.linalg.norm(w_c)
        if nw > 1e-12:  # revolute: the point of the axis nearest its child body's origin (a file's joint
            # origin lies on its axis: the chain's steps are then the links' lengths, not the distances
            # between the axes' feet from the world origin); pitch motion (v + w x a) kept
            foot, unit = np.cross(w_c, v_c) / nw**2, w_c / nw
            a = foot + unit * np.dot(origins[f] - foot, unit)
            point[c] = a
            speed_w[c], speed_v[c] = nw, np.linalg.norm(v_c + np.cross(w_c, a))
        else:  # prismatic: the child body's origin (it slides with the joint)
            point[c] = origins[f]
            speed_v[c] = np.linalg.norm(v_c)
    stroke = np.where(speed_w > 0, 0.0, np.maximum(np.abs(lower), np.abs(upper)) * speed_v)
    centre_local, radius = _bounding(geom)
    S = len(geom.shape_frames)
    out = np.zeros((dof, S))
    for s, f in enumerate(geom.shape_frames):
        T = kin.pose(f)
        R = np.array([[float(e) for e in row] for row in T.R])
        centre = R @ centre_local[s] + np.array([float(e) for e in T.p])
        chain = [int(c) for c in sorted(np.flatnonzero(moves[f]), key=lambda c: depth[c])]
        tail = float(np.linalg.norm(point[chain[-1]] - centre) + radius[s]) if chain else 0.0
        for k in range(len(chain) - 1, -1, -1):
            c = chain[k]
            if k < len(chain) - 1:
                nxt = chain[k + 1]
                tail = tail + np.linalg.norm(point[c] - point[nxt]) + stroke[nxt]
            out[c, s] = speed_w[c] * tail + speed_v[c]
    return out
