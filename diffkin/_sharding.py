"""Batches sharded over a mesh with explicit axes (``jax.make_mesh``'s default in current JAX)."""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
from jax.sharding import PartitionSpec


def automatic_axes(fn: Callable, batched: jax.Array, batch_ndim: int) -> Callable:
    """``fn``, run with the explicit mesh axes of ``batched`` made automatic where it has any.

    In explicit mode JAX must infer every intermediate's sharding while tracing, and refuses what
    it cannot infer: the IK solver's gathers across the batch (the unsolved targets packed into
    small chunks) raise ``ShardingTypeError``. With the axes automatic, XLA partitions the solver
    as it does for a plain ``Mesh`` (the same numbers as on one device, ``tests/integration/test_sharding.py``),
    and every output is sharded like the first ``batch_ndim`` axes of ``batched``. Inputs
    without explicit axes (one device, a plain ``Mesh``) get ``fn`` itself.

    The returned function takes ``fn``'s array arguments positionally and its static (non-array)
    arguments by keyword.
    """
    sharding = getattr(jax.typeof(batched), "sharding", None)
    mesh = getattr(sharding, "mesh", None)
    if sharding is None or mesh is None or not getattr(mesh, "explicit_axes", ()):
        return fn
    spec = (tuple(sharding.spec) + (None,) * batch_ndim)[:batch_ndim]

    @functools.wraps(fn)
    def call(*arrays, **static):
        run = jax.sharding.auto_axes(lambda *a: fn(*a, **static), out_sharding=PartitionSpec(*spec))
        with jax.sharding.use_abstract_mesh(mesh):
            return run(*arrays)

    return call
