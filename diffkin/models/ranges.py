"""Where a model's joints are sampled: within their limits, one turn for an unlimited revolute joint,
in its cone for a ball joint. Internal (not in API.md): the models' interface for the packages that sample
or project joint values (collision pairs, IK, workspace maps)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.models import _ball, forward
from diffkin.models.robot import Robot


def sampling_ranges(chain) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` sampling ranges: the limits, one turn ``[-pi, pi)`` for unlimited revolute joints
    (and ``+-pi`` for each component of an unlimited ball joint)."""
    forward.check(chain)
    lo, hi = np.asarray(chain.lower, np.float64), np.asarray(chain.upper, np.float64)
    for i, kind in enumerate(chain.actuated_types if isinstance(chain, Robot) else chain.joint_types):
        if kind == "P" and not (np.isfinite(lo[i]) and np.isfinite(hi[i])):
            raise ValueError(
                f"chain.lower/upper[{i}]: expected finite limits for prismatic joint {i}, got [{lo[i]}, {hi[i]}]"
            )
    return np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)


def uniform(key, lo: np.ndarray, hi: np.ndarray, n: int, dtype, balls: tuple[int, ...] = ()) -> jax.Array:
    """``(dof, n)`` uniform joint values, one row per joint (the layout the kernel consumes); the three rows
    of each ball joint (first rows ``balls``: :func:`diffkin.models._ball.starts`) uniform in its cone."""
    u = jax.random.uniform(key, (lo.size, n), dtype)
    q = jnp.asarray(lo[:, None], dtype) + u * jnp.asarray((hi - lo)[:, None], dtype)
    for i in balls:
        q = q.at[i : i + 3].set(_ball.sample(jax.random.fold_in(key, lo.size + i), float(hi[i]), n, dtype))
    return q


def ball_starts(model) -> tuple[int, ...]:
    """The first entry in ``q`` of each of the model's ball joints (:mod:`diffkin.models._ball`)."""
    return _ball.starts(model.actuated_types)


def into_cones(q: jax.Array, model, respect_limits: bool) -> jax.Array:
    """``q`` ``(dof, ...)`` with each ball joint's rotation vector scaled into its cone (``respect_limits``;
    its ``upper`` is the cone's angle) or, unlimited, wrapped to ``|r| <= pi``; other rows unchanged."""
    for i in ball_starts(model):
        radius = model.upper[i] if respect_limits else jnp.inf
        q = q.at[i : i + 3].set(_ball.into_cone(q[i : i + 3], radius))
    return q
