"""What a solve prepares inside ``jit``: the model and targets in the solver's dtype, safe targets,
limits rounded inwards, and the method's iteration."""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

from diffkin._checks import rigid_poses
from diffkin._xla import traced_only
from diffkin.ik import _lm


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


class Method(NamedTuple):
    """An iterative method: ``init(x) -> aux``, ``propose(problem, x, ev, aux) -> (x_try, aux)`` and
    ``judge(cost, cost_try, aux) -> (accepted, aux, stalled)`` (see :func:`diffkin.ik._rounds.search`)."""

    init: Callable
    propose: Callable
    judge: Callable


def method_steps(method: str, optimizer) -> Method:
    """The :class:`Method` of ``method`` (``"lm"`` or ``"optax"`` with ``optimizer``)."""
    if method == "lm":
        return Method(_lm.init, _lm.propose, _lm.judge)
    _optax = optax_module()
    opt = _optax.default_optimizer() if optimizer is None else optimizer
    return Method(functools.partial(_optax.init, opt), functools.partial(_optax.propose, opt), _optax.judge)


def optax_module():
    """``diffkin.ik._optax`` (which needs optax), or an ImportError naming the extra to install."""
    try:
        return importlib.import_module("diffkin.ik._optax")
    except ImportError as e:
        raise ImportError("method='optax' needs optax: pip install 'diffkin[ik]' (or pip install optax)") from e


def valid_targets(flat: jax.Array, position_only: bool) -> tuple[jax.Array, jax.Array]:
    """``(valid, safe)``: which of the targets ``(n, 4, 4)``/``(n, 3)`` are finite (and rigid), and the
    targets with the others replaced by the identity (so that nothing NaN enters the solver)."""
    n = flat.shape[0]
    valid = jnp.all(jnp.isfinite(flat.reshape(n, -1)), axis=-1)
    valid = valid if position_only else valid & rigid_poses(flat)  # a non-rigid traced target fails
    identity = jnp.eye(4, dtype=flat.dtype)
    safe = jnp.where(valid.reshape((n,) + (1,) * (flat.ndim - 1)), flat, identity[:3, 3] if position_only else identity)
    return valid, safe
