"""Distances and their motions for many shape pairs, exact where they are near: what a solver needs.

A solver that keeps shapes ``reach`` apart needs each pair's distance exactly only below ``reach``
(above it the pair exerts nothing). So every pair of the kinds whose distance is dear
(:data:`diffkin.collision._distance.BOUNDED`: box-box, capsule-box and the general pairs) first gets
a cheap lower bound (:func:`diffkin.collision._distance.lower_bound`); where it is at least ``reach``
that bound stands for the distance and the motion is zero. The exact work is gathered for the
others, ``1 / NEAR_SHARE`` of the pairs at a time (no step when none is near, one when few are): one
traced computation serves every case, which XLA compiles once.

The general pairs (:mod:`diffkin.collision._gjk`) of every kind are joined into one batch, each
shape in the one form :class:`diffkin.collision._shapes.Solid`: one GJK per call rather than one per
pair of kinds (a robot of boxes and polytopes among boxes and cylinders has five), which is what
XLA's compile time and the batch's work grow with. When there is such a batch, the box-box and
capsule-box pairs join it too (GJK is exact for them apart, and never reports an overlap shallower
than it is): their closed forms are the largest code of a solver's program, compiled at every place
it measures distances.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from diffkin.collision import _gjk
from diffkin.collision._distance import BOUNDED, GENERAL, lower_bound, motion
from diffkin.collision._robot import batch_shape
from diffkin.collision._shapes import taken

#: the exact motion of the near pairs is computed for 1 / NEAR_SHARE of the pairs at a time: in clutter a few
#: percent of the pairs are near, and a step costs its whole share, padding included (docs/performance.md).
NEAR_SHARE = 64


def _wrench(n: jax.Array, p: jax.Array) -> jax.Array:
    """``(..., 6)``: ``[n; p x n]``."""
    return jnp.concatenate([n, jnp.cross(p, n)], axis=-1)


def _flat_reach(reach, batch: tuple[int, ...]):
    """``reach`` as :func:`_gathered` takes it for pairs of ``batch``: a scalar as it is, else broadcast to
    ``batch`` and flattened."""
    return reach if jnp.ndim(reach) == 0 else jnp.broadcast_to(reach, batch).reshape(-1)


def _gathered(bound: jax.Array, reach, measure, share: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(d, W_a, W_b)`` of ``M`` pairs, ``(M,)``, ``(M, 6)`` twice: ``measure(idx, reach)`` (the distance and
    wrenches of the pairs ``idx``, exact below their ``reach``, else a lower bound at least it) where
    ``bound < reach``, else the bound; the wrenches zero where ``d >= reach``. ``reach``: a scalar or
    ``(M,)``, one per pair. ``1 / share`` of the pairs are measured at a time."""
    total = bound.shape[0]
    budget = -(-total // share)
    per_pair = jnp.ndim(reach) > 0

    def step(state):
        left, d, Wa, Wb = state
        idx = jnp.nonzero(left, size=budget, fill_value=total)[0]
        safe = jnp.minimum(idx, total - 1)
        measured = measure(safe, reach[safe] if per_pair else reach)
        put = lambda x, value: x.at[idx].set(value, mode="drop")  # noqa: E731
        return put(left, False), *(put(x, m) for x, m in zip((d, Wa, Wb), measured, strict=True))

    zero = jnp.zeros((total, 6), bound.dtype)
    _, d, Wa, Wb = jax.lax.while_loop(lambda state: jnp.any(state[0]), step, (bound < reach, bound, zero, zero))
    near = (d < reach)[:, None]  # (a pair measured beyond the reach exerts nothing either)
    return d, jnp.where(near, Wa, 0.0), jnp.where(near, Wb, 0.0)


def _padded(solid, size: int):
    """``solid`` with its vertices padded to ``size`` by repeating the first (the hull is unchanged)."""
    v = solid.vertices
    extra = jnp.broadcast_to(v[..., :1, :], v.shape[:-2] + (size - v.shape[-2], 3))
    return solid.replace(vertices=jnp.concatenate([v, extra], axis=-2))


def _general(pairs: list, batches: list, reach, share: int) -> list[tuple[jax.Array, jax.Array, jax.Array]]:
    """The general pairs of every kind in one gathered batch (the module docstring)."""
    sizes = [int(np.prod(b)) for b in batches]
    starts = np.cumsum([0, *sizes])
    bound = jnp.concatenate(
        [jnp.broadcast_to(lower_bound(a, b), batch).reshape(-1) for (a, b), batch in zip(pairs, batches, strict=True)]
    )
    if jnp.ndim(reach):
        reach = jnp.concatenate([_flat_reach(reach, batch) for batch in batches])
    solids = [(a.solid(), b.solid()) for a, b in pairs]
    width = max(s.vertices.shape[-2] for pair in solids for s in pair)

    def measure(idx, reach):
        block = jnp.searchsorted(jnp.asarray(starts[1:-1]), idx, side="right")
        sides = None
        for k, ((sa, sb), batch) in enumerate(zip(solids, batches, strict=True)):
            local = jnp.clip(idx - starts[k], 0, sizes[k] - 1)
            block_sides = tuple(_padded(taken(s, batch, local), width) for s in (sa, sb))
            if sides is None:
                sides = block_sides
            else:
                here = block == k
                sides = jax.tree.map(
                    lambda new, old, here=here: jnp.where(here.reshape(here.shape + (1,) * (new.ndim - 1)), new, old),
                    block_sides,
                    sides,
                )
        assert sides is not None  # (at least one block)
        a, b = sides
        n, pa, pb, s = _gjk.witnesses(a, b, reach)
        return s - a.radius - b.radius, _wrench(-n, pa), _wrench(n, pb)

    d, Wa, Wb = _gathered(bound, reach, measure, share)
    return [
        (d[i:j].reshape(batch), Wa[i:j].reshape(batch + (6,)), Wb[i:j].reshape(batch + (6,)))
        for i, j, batch in zip(starts[:-1], starts[1:], batches, strict=True)
    ]


def near_motions(pairs: list, reach, share: int = NEAR_SHARE) -> list[tuple[jax.Array, jax.Array, jax.Array]]:
    """Per pair of shape batches ``(a, b)`` (their batch axes broadcast to ``B``): ``(d, W_a, W_b)``, ``d`` ``B``
    and the wrenches ``B + (6,)`` of :func:`diffkin.collision._distance.motion`, exact where the
    distance is below ``reach``; elsewhere ``d`` is a lower bound at least ``reach`` and the wrenches
    are zero (the module docstring). ``reach``: metres, a scalar or an array that broadcasts to every
    ``B`` (one per configuration, ``(P,)``, where the batches end in ``P``: a search's states). ``share``:
    ``1 / share`` of the pairs measured exactly at a time (a step costs its whole size, padding included,
    and a few GJK iterations whatever its size: the fewer pairs are near, the larger ``share`` pays)."""
    batches = [tuple(jnp.broadcast_shapes(batch_shape(a), batch_shape(b))) for a, b in pairs]
    out: list = [None] * len(pairs)
    kinds = [(type(a), type(b)) for a, b in pairs]
    general = [k for k in range(len(pairs)) if kinds[k] in GENERAL and np.prod(batches[k]) > 0]
    if general:  # the closed forms' pairs join the batch: its one GJK serves them too, their code is not compiled
        general += [k for k in range(len(pairs)) if kinds[k] in BOUNDED - GENERAL and np.prod(batches[k]) > 0]
        joined = _general([pairs[k] for k in general], [batches[k] for k in general], reach, share)
        for k, result in zip(general, joined, strict=True):
            out[k] = result
    for k, ((a, b), batch) in enumerate(zip(pairs, batches, strict=True)):
        if out[k] is not None:
            continue
        if not np.prod(batch):  # no pairs (e.g. a world without obstacles of one kind)
            dtype = jnp.result_type(*jax.tree.leaves((a, b)))
            d, Wa, Wb = jnp.zeros(batch, dtype), jnp.zeros(batch + (6,), dtype), jnp.zeros(batch + (6,), dtype)
        elif (type(a), type(b)) not in BOUNDED:
            d, Wa, Wb = motion(a, b)  # as cheap as a bound
        else:
            d, Wa, Wb = _gathered(
                jnp.broadcast_to(lower_bound(a, b), batch).reshape(-1),
                _flat_reach(reach, batch),
                lambda idx, _, a=a, b=b, batch=batch: motion(taken(a, batch, idx), taken(b, batch, idx)),
                share,
            )
            d, Wa, Wb = d.reshape(batch), Wa.reshape(batch + (6,)), Wb.reshape(batch + (6,))
        out[k] = (jnp.broadcast_to(d, batch), *(jnp.broadcast_to(W, batch + (6,)) for W in (Wa, Wb)))
    return out
