"""Where a model's joints are sampled: within their limits, one turn for an unlimited revolute joint."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.models import forward
from diffkin.models.robot import Robot


def sampling_ranges(chain) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` sampling ranges: the limits, one turn ``[-pi, pi)`` for unlimited revolute joints."""
    forward.check(chain)
    lo, hi = np.asarray(chain.lower, np.float64), np.asarray(chain.upper, np.float64)
    for i, kind in enumerate(chain.actuated_types if isinstance(chain, Robot) else chain.joint_types):
        if kind == "P" and not (np.isfinite(lo[i]) and np.isfinite(hi[i])):
            raise ValueError(
                f"chain.lower/upper[{i}]: expected finite limits for prismatic joint {i}, got [{lo[i]}, {hi[i]}]"
            )
    return np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)


def uniform(key, lo: np.ndarray, hi: np.ndarray, n: int, dtype) -> jax.Array:
    """``(dof, n)`` uniform joint values, one row per joint (the layout the kernel consumes)."""
    u = jax.random.uniform(key, (lo.size, n), dtype)
    return jnp.asarray(lo[:, None], dtype) + u * jnp.asarray((hi - lo)[:, None], dtype)
