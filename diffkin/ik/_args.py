"""Host-side checks of :func:`diffkin.ik.solve`'s arguments, and the model as a static argument."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import real_array, rigid_poses, rigid_tol
from diffkin._xla import is_concrete

METHODS = ("lm", "optax")


def check_settings(num_seeds, method, max_iters, pos_tol, rot_tol, optimizer) -> None:
    """The solver's settings: a known method, positive counts, non-negative tolerances, an optax optimizer."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
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
        from diffkin.ik._prepare import optax_module

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


class KnownLeaves:
    """The concrete leaves of a model (and its structure), hashed and compared by value.

    It is a static argument of the jitted solvers: equal models (by structure and numbers) share
    one compilation, and their numbers stay trace-time constants that the forward pass folds (as
    for a model closed over by ``jit``).
    """

    def __init__(self, treedef, leaves: tuple):
        self.treedef, self.leaves = treedef, leaves
        self._key = (
            treedef,
            tuple(
                None
                if x is None
                else (
                    np.asarray(x).dtype.str,
                    np.shape(x),
                    bool(getattr(x, "weak_type", False)),
                    np.asarray(x).tobytes(),
                )
                for x in leaves
            ),
        )
        self._hash = hash(self._key)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return isinstance(other, KnownLeaves) and self._key == other._key


def split_model(model) -> tuple[KnownLeaves, tuple]:
    """``(concrete leaves, traced leaves)`` of ``model``, each with ``None`` in the other's slots."""
    leaves, treedef = jax.tree_util.tree_flatten(model)
    known = tuple(x if is_concrete(x) else None for x in leaves)
    traced = tuple(None if is_concrete(x) else x for x in leaves)
    return KnownLeaves(treedef, known), traced


def join(known: KnownLeaves, traced: tuple):
    """The model again, inside the trace: concrete leaves from ``known``, the others from ``traced``."""
    return jax.tree_util.tree_unflatten(
        known.treedef, [t if k is None else k for k, t in zip(known.leaves, traced, strict=True)]
    )
