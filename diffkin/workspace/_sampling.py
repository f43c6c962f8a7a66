"""What a map samples: the chain (or a robot's path to a frame), configurations uniform within its
joint limits, and the grid around its reach."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import instance, positive_int
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain, to_poe
from diffkin.models.ranges import ball_starts, sampling_ranges, uniform
from diffkin.models.robot import Robot


def _as_chain(chain):
    """A chain as given, or the chain of a ``(robot, frame_name)`` pair (:meth:`Robot.chain` from the root)."""
    if isinstance(chain, tuple) and len(chain) == 2 and isinstance(chain[0], Robot):
        robot, frame = chain
        return robot.chain(frame)
    instance(chain, (DHChain, PoEChain), "chain", "a DHChain, PoEChain or (Robot, frame_name)")
    return chain


def sample_configs(chain, n: int, key, *, dtype=None) -> jax.Array:
    """Configurations uniform within the joint limits.

    Unlimited revolute joints are sampled over one turn ``[-pi, pi)``; a prismatic joint needs
    finite limits. Chunk ``c`` of :func:`reachability` is ``sample_configs(chain, chunk,
    jax.random.fold_in(key, c))``.

    Args:
        chain: a :class:`DHChain`, :class:`PoEChain` or :class:`Robot` (its actuated joints).
        n: number of configurations.
        key: a JAX PRNG key.
        dtype: float dtype; default the default float (float32, or float64 with x64).

    Returns:
        ``(n, dof)`` joint values, radians (revolute) or metres (prismatic).
    """
    lo, hi = sampling_ranges(chain)
    n = positive_int(n, "n")
    return uniform(key, lo, hi, n, jnp.dtype(dtype or jnp.result_type(float)), ball_starts(chain)).T


def _reach(chain) -> float:
    """Upper bound on ``|p_ee|`` over all configurations, metres.

    A revolute joint keeps the distances from its axis to everything after it, so
    ``|p| <= |c_1| + sum |c_{i+1} - c_i| + |p_home - c_n|`` for any points ``c_i`` on the revolute
    axes at ``q = 0`` (each taken as the projection of the previous one, which keeps the bound
    tight); each prismatic joint adds its largest travel.
    """
    poe = to_poe(chain) if isinstance(chain, DHChain) else chain
    screws, home = np.asarray(poe.screws, np.float64), np.asarray(poe.home, np.float64)
    lo, hi = sampling_ranges(chain)
    points, reach = [np.zeros(3)], 0.0
    for i, kind in enumerate(chain.joint_types):
        v, w = screws[i, :3], screws[i, 3:]
        if kind == "R":
            c = np.cross(w, v)  # a point on the axis
            points.append(c + np.dot(points[-1] - c, w) * w)
        else:
            reach += max(abs(lo[i]), abs(hi[i]))
    points.append(home[:3, 3])
    return reach + float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def voxel_grid(chain, voxel_size, bounds) -> tuple[np.ndarray, float, tuple[int, ...]]:
    """``(origin (3,), voxel_size, shape)`` of the voxel grid, validated."""
    if isinstance(voxel_size, bool) or not isinstance(voxel_size, (int, float, np.integer, np.floating)):
        raise TypeError(f"voxel_size: expected a positive number of metres, got {type(voxel_size).__name__}")
    voxel_size = float(voxel_size)
    if not (math.isfinite(voxel_size) and voxel_size > 0):
        raise ValueError(f"voxel_size: expected a positive number of metres, got {voxel_size}")
    shape: tuple[int, ...]
    if bounds is None:
        m = math.ceil(_reach(chain) / voxel_size)
        origin, shape = np.full(3, -(m + 0.5) * voxel_size), (2 * m + 1,) * 3
    else:
        try:
            b = np.asarray(bounds, dtype=np.float64)
        except (TypeError, ValueError):
            b = np.full(0, np.nan)
        if b.shape != (2, 3) or not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
            raise ValueError(
                f"bounds: expected [[xmin, ymin, zmin], [xmax, ymax, zmax]] (metres) with min < max, got {bounds!r}"
            )
        origin, shape = b[0], tuple(int(max(1, math.ceil(s))) for s in (b[1] - b[0]) / voxel_size)
    return origin, voxel_size, shape
