"""What a solve prepares inside ``jit``: the model and targets in the solver's dtype, safe targets,
limits rounded inwards; :func:`prepare`, the setup that ``solve`` and ``solve_path`` share."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import rigid_poses
from diffkin._static import combine, traced_only


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


class Prepared(NamedTuple):
    """What :func:`prepare` gives a solver: the model, limits and terms' data in its dtype, flat over
    ``n`` targets, of which ``m`` have their own locked values and root pose (``m = n`` for a solve,
    the paths for a path: each path's waypoints share them).

    Attributes:
        model: the model in the solver's dtype, detached (what the search iterates on).
        differentiable: the same, not detached (what the implicit derivative reads).
        lower, upper: ``(dof,)`` the limits, rounded inwards; ``wrap``: ``(dof,)`` unlimited revolute joints.
        valid: ``(n,)`` finite (and rigid) targets with finite rest and locked values.
        safe: per target term, its targets ``(n, ...)``, invalid ones the identity (differentiable).
        targets: the same, detached; ``data``: per constraint, its data in the dtype, detached.
        q0, rest, locked_q: ``(m, dof)`` the warm start, rest and locked values (non-finite
            entries 0, detached), or ``None``.
        base: ``(m, 4, 4)`` the given (or, ``spec.solve_base``, guessed) root poses, non-finite ones
            the identity, and ``base_ok`` ``(m,)`` where they were finite; or ``None``.
    """

    model: Any
    differentiable: Any
    lower: jax.Array
    upper: jax.Array
    wrap: jax.Array
    valid: jax.Array
    safe: tuple
    targets: tuple
    data: tuple
    q0: jax.Array | None
    rest: jax.Array | None
    locked_q: jax.Array | None
    base: jax.Array | None
    base_ok: jax.Array | None


def prepare(
    static,
    traced,
    data: tuple,
    spec,
    batch: tuple[int, ...],
    lead: tuple[int, ...],
    *,
    q0=None,
    rest=None,
    locked_q=None,
    base=None,
) -> Prepared:
    """The setup that :func:`~diffkin.ik._solve.solve` and :func:`~diffkin.ik._path.solve_path` share, inside ``jit``.

    Args:
        static, traced: the model (:func:`diffkin._static.partition`).
        data: what the terms of ``spec`` (:class:`~diffkin.ik._problem.Spec`) bind: per target
            ``batch + (4, 4)`` or ``batch + (3,)`` (their dtype is the solver's), then per constraint its data.
        batch: the targets' batch shape; ``lead``: its leading part that the others have.
        q0, rest, locked_q: ``lead + (dof,)`` (broadcastable) warm start, rest configuration and values
            of the locked joints, or ``None``.
        base: ``lead + (4, 4)`` (broadcastable) root poses, or ``None``.
    """
    model_in = combine(static, traced)
    k, dtype, dof = len(spec.targets), data[0].dtype, model_in.dof
    n, m = int(np.prod(batch, dtype=np.int64)), int(np.prod(lead, dtype=np.int64))
    checked = [
        valid_targets(t.reshape((n,) + t.shape[len(batch) :]), term.position_only)
        for t, term in zip(data[:k], spec.targets, strict=True)
    ]
    valid = checked[0][0] if k == 1 else jnp.all(jnp.stack([v for v, _ in checked]), axis=0)
    safe = tuple(s for _, s in checked)
    targets = tuple(detach(s) for s in safe)
    model = cast(detach(model_in), dtype)
    lower, upper = inward(detach(model_in.lower), dtype, -1), inward(detach(model_in.upper), dtype, 1)
    wrap = jnp.asarray([t == "R" for t in model_in.actuated_types]) & ~jnp.isfinite(lower) & ~jnp.isfinite(upper)
    q0_flat, rest_flat, locked_flat = (flat(x, lead, (dof,), m, dtype) for x in (q0, rest, locked_q))
    for given in (rest, None if locked_q is None else jnp.where(jnp.asarray(spec.locked), locked_q, 0.0)):
        if given is not None:  # traced non-finite values (the host rejects concrete ones): no success
            finite = jnp.all(jnp.isfinite(jnp.broadcast_to(given, lead + (dof,)).reshape(m, dof)), axis=-1)
            valid = valid & (finite if m == n else jnp.repeat(finite, n // m))
    base_in, base_ok = None, None
    if base is not None or spec.solve_base:
        eye = jnp.eye(4, dtype=dtype)
        base_in = jnp.broadcast_to(eye if base is None else base, lead + (4, 4)).reshape(m, 4, 4)
        base_ok = jnp.all(jnp.isfinite(base_in.reshape(m, -1)), axis=-1)
        base_in = jnp.where(base_ok[:, None, None], base_in, eye)
    return Prepared(
        model=model,
        differentiable=cast(model_in, dtype),
        lower=lower,
        upper=upper,
        wrap=wrap,
        valid=valid,
        safe=safe,
        targets=targets,
        data=tuple(detach(d.cast(dtype).flat(lead)) for d in data[k:]),
        q0=q0_flat,
        rest=rest_flat,
        locked_q=locked_flat,
        base=base_in,
        base_ok=base_ok,
    )


def flat(x, batch: tuple[int, ...], tail: tuple[int, ...], n: int, dtype):
    """``x`` broadcast to ``batch + tail``, flattened to ``(n,) + tail``, detached, non-finite entries 0."""
    if x is None:
        return None
    x = jnp.broadcast_to(x, batch + tail).reshape((n,) + tail).astype(dtype)
    return detach(jnp.where(jnp.isfinite(x), x, 0.0))
