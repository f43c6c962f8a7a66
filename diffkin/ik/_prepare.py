"""What a solve prepares inside ``jit``: the model and targets in the solver's dtype, safe targets,
limits rounded inwards."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from diffkin._checks import rigid_poses
from diffkin._static import traced_only


def detach(tree):
    """``stop_gradient`` on traced leaves only (concrete model constants stay foldable)."""
    return traced_only(jax.lax.stop_gradient, tree)


def cast(tree, dtype):
    """Traced floating leaves to ``dtype``; concrete ones are folded as Python floats by the model."""
    return traced_only(lambda x: x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def inward(limit, dtype, side: int) -> jax.Array:
    """``limit`` in ``dtype``, rounded towards the inside of the range (``side`` -1: lower, +1: upper)."""
    limit = jnp.asarray(limit)
    rounded = limit.astype(dtype)
    outside = side * (rounded.astype(limit.dtype) - limit) > 0
    return jnp.where(outside, jnp.nextafter(rounded, jnp.asarray(-side * jnp.inf, dtype)), rounded)


def valid_targets(flat: jax.Array, position_only: bool) -> tuple[jax.Array, jax.Array]:
    """``(valid, safe)``: which of the targets ``(n, 4, 4)``/``(n, 3)`` are finite (and rigid), and the
    targets with the others replaced by the identity (so that nothing NaN enters the solver)."""
    n = flat.shape[0]
    valid = jnp.all(jnp.isfinite(flat.reshape(n, -1)), axis=-1)
    valid = valid if position_only else valid & rigid_poses(flat)  # a non-rigid traced target fails
    identity = jnp.eye(4, dtype=flat.dtype)
    safe = jnp.where(valid.reshape((n,) + (1,) * (flat.ndim - 1)), flat, identity[:3, 3] if position_only else identity)
    return valid, safe
