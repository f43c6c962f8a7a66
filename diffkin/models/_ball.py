"""Ball joints: three rotational degrees of freedom about one point, as a rotation vector in ``q``.

A ball joint is three consecutive tree joints of type ``"B"`` (one entry of ``q`` each: the rotation
vector ``r = (rx, ry, rz)`` in the joint frame), their screws the three axes ``e_k`` through the
joint's centre ``c`` (``[c x e_k; e_k]``) and the two bodies between them massless and frameless.
The child body is the joint frame turned by ``exp([r])`` about ``c``, as one rotation (not three).

- Jacobian columns: a change ``dr`` turns the child by ``J_l(r) dr`` (the left Jacobian of SO(3),
  :func:`diffkin._rigid.rotation_exp`), so column ``k`` is the world screw ``(p_c x w_k, w_k)`` with
  ``w_k = R_joint J_l(r) e_k`` and ``p_c`` the centre in the world.
- Limits: a cone ``|r| <= range`` (MJCF ``range="0 angle"``): ``robot.lower/upper`` hold ``-+range``
  for each component (the box around the cone); IK keeps ``r`` in the cone and samplers draw in it.
  Unlimited: ``|r| <= pi`` (a longer ``r`` turns by the same rotation as ``r`` with its angle wrapped into
  ``[-pi, pi)``).
- MuJoCo's ``qpos`` quaternion ``(w, x, y, z)`` is ``(cos(|r|/2), sin(|r|/2) r / |r|)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg

AXES = ("rx", "ry", "rz")  # suffixes of the three names in q: f"{joint}:{axis}"


def starts(types: str) -> tuple[int, ...]:
    """The index of the first of each ball joint's three letters ``"B"`` in ``types`` (per tree joint,
    or per entry of ``q``): a run of ``"B"`` is whole ball joints, three letters each."""
    out, k = [], 0
    while k < len(types):
        if types[k] == "B":
            out.append(k)
            k += 3
        else:
            k += 1
    return tuple(out)


def check_structure(types: str, parents, sources) -> None:
    """Raise a ValueError unless every ball joint is three ``"B"`` tree joints, each the parent of the
    next, driven by three consecutive entries of ``q`` that drive nothing else."""
    for j in starts(types):
        if types[j : j + 3] != "BBB":
            raise ValueError(f"joint_types[{j}:{j + 3}]: a ball joint is three letters 'B', got {types[j : j + 3]!r}")
        if parents[j + 1] != j + 1 or parents[j + 2] != j + 2:
            raise ValueError(
                f"parents[{j + 1}:{j + 3}]: a ball joint's three joints form a chain, got {parents[j + 1 : j + 3]}"
            )
        s = sources[j]
        if tuple(sources[j : j + 3]) != (s, s + 1, s + 2) or sum(x in (s, s + 1, s + 2) for x in sources) != 3:
            raise ValueError(
                f"sources[{j}:{j + 3}]: a ball joint is three entries of q of its own, got {sources[j : j + 3]}"
            )


def check_values(j: int, joint_poses: np.ndarray, screws: np.ndarray, multipliers, offsets, tol: float) -> None:
    """Raise a ValueError unless the ball joint at tree joint ``j`` has the screws ``[c x e_k; e_k]`` of one
    centre, identity poses between its joints, multipliers 1 and offsets 0 (host values)."""
    w = screws[j : j + 3, 3:]
    if np.abs(w - np.eye(3)).max() > tol:
        raise ValueError(f"screws[{j}:{j + 3}]: a ball joint's axes are x, y, z of its frame, got {w.tolist()}")
    c = centre_host(screws[j : j + 3])
    if np.abs(screws[j : j + 3, :3] - np.cross(c, np.eye(3))).max() > tol:
        raise ValueError(f"screws[{j}:{j + 3}]: a ball joint's three axes pass through one point")
    if np.abs(joint_poses[j + 1 : j + 3] - np.eye(4)).max() > tol:
        raise ValueError(f"joint_poses[{j + 1}:{j + 3}]: a ball joint's second and third poses are the identity")
    if (
        np.abs(np.asarray(multipliers[j : j + 3]) - 1.0).max() > tol
        or np.abs(np.asarray(offsets[j : j + 3])).max() > tol
    ):
        raise ValueError(f"multipliers/offsets[{j}:{j + 3}]: a ball joint has multipliers 1 and offsets 0")


def centre_host(screws: np.ndarray) -> np.ndarray:
    """The centre ``c`` of the three screws ``[c x e_k; e_k]`` ``(3, 6)``: ``c = sum_k e_k x v_k / 2``."""
    return 0.5 * np.cross(screws[:, 3:], screws[:, :3]).sum(axis=0)


def motion(axes: list[tuple[rg.Vec3, rg.Vec3]], r: list[rg.Entry], T_world_joint: rg.Rigid):
    """The ball joint's motion from its frame ``T_world_joint`` at rotation vector ``r`` (three entries).

    Args:
        axes: the three screws ``(v_k, w_k)`` in the joint frame.
        r: the three components (``q`` entries).
        T_world_joint: the joint frame in the world (the parent body moved by the joint's pose).

    Returns:
        ``T_world_child`` and the three world screws ``(v_k, w_k)`` (columns per unit ``r_k``).
    """
    c = rg.scale(0.5, rg.vadd(*(rg.cross(w, v) for v, w in axes)))
    r_joint = rg.vadd(*(rg.scale(rk, w) for rk, (_, w) in zip(r, axes, strict=True)))
    R, J = rg.rotation_exp(r_joint)
    turn = rg.Rigid(R, rg.vadd(c, rg.scale(-1.0, rg.rotate(R, c))))  # about c: p = c - R c
    centre = rg.vadd(rg.rotate(T_world_joint.R, c), T_world_joint.p)
    screws = []
    for _, w in axes:
        w_world = rg.rotate(T_world_joint.R, rg.rotate(J, w))
        screws.append((rg.cross(centre, w_world), w_world))
    return rg.compose(T_world_joint, turn), screws


def into_cone(r: jax.Array, radius) -> jax.Array:
    """``r`` ``(3, ...)`` scaled into ``|r| <= radius``; with an infinite radius (unlimited), the same
    rotation with ``|r| <= pi``. NaN-free, derivatives too (``r = 0`` stays 0)."""
    n2 = jnp.sum(r * r, axis=0)
    n = jnp.sqrt(jnp.where(n2 > 0, n2, 1.0))
    radius = jnp.asarray(radius, r.dtype)
    limited = jnp.isfinite(radius)
    scaled = jnp.minimum(1.0, jnp.where(limited, radius, 1.0) / n)
    wrapped = jnp.where(n > np.pi, (jnp.mod(n + np.pi, 2 * np.pi) - np.pi) / n, 1.0)  # the angle into [-pi, pi)
    return r * jnp.where(n2 > 0, jnp.where(limited, scaled, wrapped), 1.0)


def sample(key, radius: float, n: int, dtype) -> jax.Array:
    """``(3, n)`` rotation vectors uniform in the ball ``|r| <= radius`` (``pi`` if infinite)."""
    radius = np.pi if not np.isfinite(radius) else float(radius)
    k_dir, k_len = jax.random.split(key)
    d = jax.random.normal(k_dir, (3, n), dtype)
    length = radius * jax.random.uniform(k_len, (n,), dtype) ** (1.0 / 3.0)
    norm = jnp.sqrt(jnp.maximum(jnp.sum(d * d, axis=0), jnp.finfo(dtype).tiny))
    return d * (length / norm)
