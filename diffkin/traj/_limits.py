"""Velocity, acceleration and jerk limits of a motion."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._pytree import pytree_dataclass
from diffkin._static import is_concrete

#: rad/s (m/s for a prismatic joint) for a joint without a velocity limit in its file when no
#: :class:`Limits` are given: a conservative speed every arm can move at
DEFAULT_VELOCITY = 1.0
#: rad/s^2 (m/s^2) per joint when no :class:`Limits` are given
DEFAULT_ACCELERATION = 2.0


@pytree_dataclass
class Limits:
    """The bounds a trajectory keeps along its whole continuous motion.

    Attributes:
        velocity: ``(dof,)`` (or a scalar for every joint), rad/s or m/s, ``> 0``.
        acceleration: ``(dof,)`` (or a scalar), rad/s^2 or m/s^2, ``> 0``.
        jerk: ``(dof,)`` (or a scalar), rad/s^3 or m/s^3, ``> 0``, or ``None`` (unbounded).
    """

    velocity: jax.Array
    acceleration: jax.Array
    jerk: jax.Array | None = None

    def _check(self, concrete: bool) -> None:
        for name in ("velocity", "acceleration", "jerk"):
            value = getattr(self, name)
            if value is None and name == "jerk":
                continue
            if isinstance(value, (str, bytes)) or value is None:
                raise TypeError(f"Limits.{name}: expected numbers (a scalar or one per joint), got {value!r}")
            try:
                arr = np.asarray(value) if is_concrete(value) else value
                dtype = arr.dtype
            except (TypeError, ValueError):
                raise TypeError(f"Limits.{name}: expected numbers (a scalar or one per joint), got {value!r}") from None
            if not (jnp.issubdtype(dtype, jnp.floating) or jnp.issubdtype(dtype, jnp.integer)):
                raise TypeError(f"Limits.{name}: expected real numbers, got dtype {dtype}")
            if jnp.ndim(arr) > 1:
                raise ValueError(f"Limits.{name}: expected a scalar or shape (dof,), got shape {jnp.shape(arr)}")
            if concrete and is_concrete(value) and not np.all(np.isfinite(arr) & (arr > 0)):
                raise ValueError(f"Limits.{name}: expected finite values > 0, got {np.asarray(value).tolist()}")

    def per_joint(self, dof: int, dtype) -> tuple[jax.Array, jax.Array, jax.Array | None]:
        """``(velocity, acceleration, jerk)`` each ``(dof,)`` in ``dtype`` (jerk ``None`` if unbounded).

        Raises:
            ValueError: a field of another length than ``dof``.
        """
        out: list[jax.Array | None] = []
        for name in ("velocity", "acceleration", "jerk"):
            value = getattr(self, name)
            if value is None:
                out.append(None)
                continue
            if jnp.ndim(value) == 1 and jnp.shape(value)[0] != dof:
                raise ValueError(f"Limits.{name}: expected {dof} values (one per joint), got {jnp.shape(value)[0]}")
            out.append(jnp.broadcast_to(jnp.asarray(value, dtype), (dof,)))
        velocity, acceleration = out[0], out[1]
        assert velocity is not None and acceleration is not None
        return velocity, acceleration, out[2]


def default(velocity: jax.Array) -> Limits:
    """The limits used when none are given: the model's ``velocity`` ``(dof,)`` (its file's velocity limits;
    :data:`DEFAULT_VELOCITY` where it has none, ``inf`` or 0), :data:`DEFAULT_ACCELERATION` for every
    joint, no jerk bound."""
    v = jnp.asarray(velocity)
    given = jnp.isfinite(v) & (v > 0)
    return Limits(jnp.where(given, v, DEFAULT_VELOCITY), jnp.full(v.shape, DEFAULT_ACCELERATION))
