"""Host-side checks of :func:`diffkin.ik.solve`'s arguments, before anything is traced."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import real_array, rigid_poses, rigid_tol
from diffkin._static import is_concrete
from diffkin.ik import _secondary
from diffkin.ik._methods import METHODS, optax_module


def check_settings(num_seeds, method, max_iters, pos_tol, rot_tol, optimizer) -> None:
    """The solver's settings: a known method, positive counts, non-negative tolerances, an optax optimizer."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {tuple(METHODS)}, got {method!r}")
    for name, value, low in (("num_seeds", num_seeds, 1), ("max_iters", max_iters, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
    for name, value in (("pos_tol", pos_tol), ("rot_tol", rot_tol)):
        if isinstance(value, jax.Array) and value.shape == () and not jnp.issubdtype(value.dtype, jnp.complexfloating):
            if not is_concrete(value):
                continue  # a traced tolerance (a jit argument): its value is not known here
            value = value.item()
        if not isinstance(value, (int, float, np.floating, np.integer)) or not value >= 0:
            raise ValueError(f"{name}: expected a non-negative number, got {value!r}")
    if method == "optax":
        optax_module()  # ImportError with the extra to install, before tracing
    if optimizer is not None:
        if method != "optax":
            raise ValueError(f"optimizer: only used with method='optax', got method={method!r}")
        import optax

        if not isinstance(optimizer, optax.GradientTransformation):
            raise TypeError(f"optimizer: expected an optax.GradientTransformation, got {type(optimizer).__name__}")


def check_target(target, name: str = "target") -> tuple[jax.Array, bool, tuple[int, ...]]:
    """``(array, position_only, batch)`` of a pose ``(..., 4, 4)`` or position ``(..., 3)`` target.

    Non-finite targets are not errors (they fail); a concrete finite pose that is not rigid is.
    """
    target = real_array(target, name, "poses or positions")
    if jnp.finfo(target.dtype).bits < 32:
        # float16 rounding (~5e-4 m at 1 m) exceeds the default tolerances: errors would read 0.
        raise TypeError(f"{name}: expected float32 or float64, got {target.dtype} (cast it to float32)")
    if target.ndim >= 2 and target.shape[-2:] == (4, 4):
        position_only = False
    elif target.ndim >= 1 and target.shape[-1] == 3:
        position_only = True
    else:
        raise ValueError(f"{name}: expected shape (..., 4, 4) for poses or (..., 3) for positions, got {target.shape}")
    batch = target.shape[:-1] if position_only else target.shape[:-2]
    if not position_only and is_concrete(target):
        poses = np.asarray(target)
        bad = ~rigid_poses(poses) & np.all(np.isfinite(poses), axis=(-2, -1))
        if np.any(bad):
            i = tuple(int(k) for k in np.argwhere(bad)[0])
            raise ValueError(
                f"{name}[{', '.join(map(str, i))}]: expected a rigid transform (R^T R = I, det R = +1, "
                f"last row [0, 0, 0, 1], within {rigid_tol(target.dtype):g}), "
                f"got {poses[i].tolist()}"
            )
    return target, position_only, tuple(batch)


def check_batched(value, name: str, tail: tuple[int, ...], batch: tuple[int, ...], what: str) -> None:
    """``value`` has shape ``(..., *tail)`` with a batch shape that broadcasts to ``batch``."""
    shape = np.shape(value)
    if len(shape) < len(tail) or shape[len(shape) - len(tail) :] != tail:
        raise ValueError(f"{name}: expected shape (..., {', '.join(map(str, tail))}) {what}, got {shape}")
    head = shape[: len(shape) - len(tail)]
    try:
        fits = np.broadcast_shapes(head, batch) == batch
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(f"{name}: batch shape {head} does not broadcast to the targets' {batch}")


def finite(value, name: str, what: str) -> None:
    """A concrete ``value`` has only finite entries (a traced one is checked inside the solver: success=False)."""
    if is_concrete(value) and not np.all(np.isfinite(np.asarray(value))):
        bad = np.argwhere(~np.isfinite(np.atleast_1d(np.asarray(value))))[0]
        raise ValueError(f"{name}: expected {what}, got a non-finite value at index {tuple(int(i) for i in bad)}")


def tolerance(value, dtype):
    """A checked tolerance as a solver argument of ``dtype``: a NumPy scalar when known (no device dispatch)."""
    return np.asarray(value, dtype) if is_concrete(value) else jnp.asarray(value, dtype)


def default_key() -> jax.Array:
    """``jax.random.key(0)`` of the configured PRNG implementation, made once per implementation and
    concrete even when first asked for inside a trace (each ``jax.random.key`` call is a device dispatch)."""
    return _key_zero(jax.config.jax_default_prng_impl)  # type: ignore[attr-defined]  # a flag JAX sets at run time


@functools.cache
def _key_zero(impl: str) -> jax.Array:
    with jax.ensure_compile_time_eval():
        return jax.random.key(0, impl=impl)


def secondary_spec(secondary, rest) -> tuple[tuple[str, float], ...]:
    """Objectives and weights from ``None``, a name, names, or a mapping name -> weight."""
    if secondary is None:
        secondary = ("rest",) if rest is not None else ()
    if isinstance(secondary, str):
        secondary = (secondary,)
    items = secondary.items() if isinstance(secondary, Mapping) else [(s, 1.0) for s in secondary]
    spec = []
    for name, weight in items:
        if name not in _secondary.OBJECTIVES:
            raise ValueError(f"secondary: expected names from {_secondary.OBJECTIVES}, got {name!r}")
        if not isinstance(weight, (int, float, np.floating, np.integer)) or not np.isfinite(weight) or weight <= 0:
            raise ValueError(f"secondary[{name!r}]: expected a positive weight, got {weight!r}")
        spec.append((name, float(weight)))
    if any(name == "rest" for name, _ in spec) and rest is None:
        raise ValueError("rest: the 'rest' objective needs a rest configuration (rest=...)")
    return tuple(spec)


def locked_joints(robot, locked, q0, batch) -> tuple[tuple[bool, ...], jax.Array | None]:
    """Per joint, locked or not, and the locked values ``(..., dof)`` (``None`` if nothing is locked)."""
    if locked is None:
        return (False,) * robot.dof, None
    if isinstance(locked, str) or not isinstance(locked, Mapping | Sequence):
        raise TypeError(f"locked: expected a mapping joint name -> value or a sequence of joint names, got {locked!r}")
    for name in locked:
        if name not in robot.joint_names:
            raise ValueError(f"locked: {name!r} is not an actuated joint; expected one of {list(robot.joint_names)}")
    mask = tuple(name in locked for name in robot.joint_names)
    if isinstance(locked, Mapping):
        values = []
        for name in robot.joint_names:
            if name in locked:
                v = real_array(locked[name], f"locked[{name!r}]", "a joint value")
                check_batched(v, f"locked[{name!r}]", (), batch, "(a value per target, or one)")
                finite(v, f"locked[{name!r}]", "a finite joint value (a locked joint is a hard constraint)")
                values.append(jnp.broadcast_to(v, batch))
            else:
                values.append(jnp.zeros(batch))
        locked_q = jnp.stack(values, axis=-1)
    elif q0 is None:
        raise ValueError("locked: a sequence of joint names takes their values from q0; pass q0 (or a mapping)")
    else:
        locked_q = jnp.broadcast_to(jnp.asarray(q0), batch + (robot.dof,))
    _warn_outside_limits(robot, mask, locked_q)
    return mask, locked_q


def _warn_outside_limits(robot, mask: tuple[bool, ...], locked_q: jax.Array) -> None:
    """A ``UserWarning`` per locked joint held outside its limits (concrete values only): locked joints stay
    where the user puts them, the one exception to every returned ``q`` lying within the limits."""
    if not (is_concrete(locked_q) and is_concrete(robot.lower) and is_concrete(robot.upper)):
        return
    values = np.asarray(locked_q, np.float64).reshape(-1, robot.dof)
    lower, upper = np.asarray(robot.lower, np.float64), np.asarray(robot.upper, np.float64)
    for j in np.flatnonzero(mask):
        outside = np.flatnonzero((values[:, j] < lower[j]) | (values[:, j] > upper[j]))
        if len(outside):
            at = f" (target {int(outside[0])} of the flattened batch)" if values.shape[0] > 1 else ""
            warnings.warn(
                f"locked joint {robot.joint_names[j]!r} at {values[outside[0], j]:.6g}{at} is outside its limits "
                f"[{lower[j]:.6g}, {upper[j]:.6g}]: held there (locked joints are not clipped to their limits)",
                UserWarning,
                stacklevel=4,
            )
