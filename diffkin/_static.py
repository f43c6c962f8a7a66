"""The static/traced rule, said once: which model numbers fold into a compiled program.

A model is a pytree whose structure (joint types, names, parents) is static and whose numbers
are array leaves. A leaf is *concrete* when its value is known at trace time (a model closed over
by ``jit``, or passed to a function that jits itself); it is *traced* under a transformation
(a model passed as a ``jit`` argument, differentiated by ``grad``, batched by ``vmap``).

- Concrete numbers fold: the forward passes read them on the host as Python floats
  (:func:`host`, :func:`diffkin._rigid.constant`), so exact zeros and ones of a DH table vanish
  from the program and only the arithmetic a robot needs is compiled (2.5-3x faster FK,
  docs/performance.md).
- Traced numbers stay program inputs, and the same code takes the general path with the same
  result (``tests/unit/test_xla.py``).

The library's own jitted solvers keep that rule across their ``jit`` boundary with the names JAX
users know from Equinox: :func:`partition` splits a model into its static part (a
:class:`ModelKey`: the structure and the concrete leaves, hashed by value, a static argument)
and its traced leaves (an argument); :func:`combine` joins them inside the trace.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np


def is_concrete(x) -> bool:
    """Whether ``x`` holds known values at trace time (not a tracer): then it can be folded as constants."""
    return not isinstance(x, jax.core.Tracer)


def host(x):
    """A concrete model array as float64 NumPy (its entries fold at trace time); a traced one as it is."""
    return np.asarray(x, dtype=np.float64) if is_concrete(x) else x


def traced_only(fn: Callable[[jax.Array], jax.Array], tree):
    """``fn`` applied to the traced leaves of ``tree``; concrete leaves are kept as they are (still foldable).

    For example ``traced_only(jax.lax.stop_gradient, chain)`` detaches a traced chain without
    turning a concrete one into traced values (which would lose the folding).
    """
    return jax.tree.map(lambda x: x if is_concrete(x) else fn(x), tree)


class ModelKey:
    """The static part of a model: its structure and its concrete leaves, hashed and compared by value.

    A static argument of the library's jitted functions: equal models (by structure and numbers)
    share one compilation, and their numbers stay trace-time constants that the forward passes
    fold (as for a model closed over by ``jit``). Traced leaves are ``None`` here.
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
        return isinstance(other, ModelKey) and self._key == other._key

    @property
    def model(self):
        """The model, for a key without traced leaves (every leaf concrete)."""
        return combine(self, (None,) * len(self.leaves))


def partition(model) -> tuple[ModelKey, tuple]:
    """``(static, traced)``: the :class:`ModelKey` of ``model`` and its traced leaves (``None`` where concrete)."""
    leaves, treedef = jax.tree_util.tree_flatten(model)
    known = tuple(x if is_concrete(x) else None for x in leaves)
    traced = tuple(None if is_concrete(x) else x for x in leaves)
    return ModelKey(treedef, known), traced


def combine(static: ModelKey, traced: tuple):
    """The model again (inside a trace): concrete leaves from ``static``, the others from ``traced``."""
    leaves = [t if k is None else k for k, t in zip(static.leaves, traced, strict=True)]
    return jax.tree_util.tree_unflatten(static.treedef, leaves)
