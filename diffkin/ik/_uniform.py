"""Uniform draws for the seeds of the IK: an integer hash of the key, the target, the round and the draw.

A target's seeds must not depend on the rest of the batch, so every draw is a function of the
target's own index. ``jax.random`` gives that with one key per target (a ``vmap`` of ``fold_in``
and ``uniform``, a threefry hash per key), which is costly to compile and to run. Here each draw is
a chain of ``lowbias32`` (C. Wellons' hash-prospector: a bijection of 32-bit words with near-ideal
avalanche) over the key's words, the target, the round and the draw's counter, about 15x cheaper to
compile and 10x to run (docs/performance.md, "The IK's seeds"). Seeds need an even cover of the
joint box, not cryptographic strength;
``tests/unit/test_ik.py`` checks the draws' moments, uniformity and independence.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

_GOLDEN = 0x9E3779B9  # 2^32 / golden ratio: spreads consecutive counters apart


def _mix(x: jax.Array) -> jax.Array:
    """``lowbias32``: a bijection of ``uint32`` in which every input bit flips every output bit with
    probability ~1/2."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def key_words(key) -> jax.Array:
    """The ``uint32`` words of a PRNG key (typed, ``jax.random.key``, or raw, ``jax.random.PRNGKey``)."""
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    return key.reshape(-1).astype(jnp.uint32)


def uniform(key, targets: jax.Array, rounds: jax.Array, count: int, dof: int, dtype) -> jax.Array:
    """``(count, m, dof)`` draws in ``[0, 1)``: draw ``c`` of joint ``j`` of target ``targets[i]``, round ``rounds[i]``.

    Each value is a function of ``(key, targets[i], rounds[i], c, j)`` alone, on 24 bits (exact
    in float32 and float64).

    Args:
        key: a PRNG key.
        targets, rounds: ``(m,)`` non-negative integers.
        count, dof: draws per target and values per draw (static).
        dtype: a floating dtype.
    """
    h = jnp.uint32(_GOLDEN)
    words = key_words(key)
    for i in range(words.shape[0]):
        h = _mix(h ^ words[i])
    per_target = _mix(_mix(h ^ targets.astype(jnp.uint32)) + rounds.astype(jnp.uint32) * jnp.uint32(_GOLDEN))
    counter = jnp.arange(count, dtype=jnp.uint32)[:, None] * jnp.uint32(dof) + jnp.arange(dof, dtype=jnp.uint32)
    bits = _mix(per_target[None, :, None] ^ _mix(counter[:, None, :] * jnp.uint32(_GOLDEN) + jnp.uint32(1)))
    return (bits >> 8).astype(dtype) * (2.0**-24)
