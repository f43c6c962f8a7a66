"""Frozen dataclasses registered as JAX pytrees.

Fields declared with :func:`static` are pytree metadata (hashed, part of the compiled
structure); every other field is an array leaf that JAX can trace, batch and differentiate.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

T = TypeVar("T")


def static(**kwargs: Any) -> Any:
    """A dataclass field that is static structure, not an array leaf."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it as a pytree.

    The class gains ``replace(**fields)``, returning a modified copy (no validation: it is
    used inside traced code, e.g. ``jax.grad`` with respect to a field).
    """
    cls = dataclasses.dataclass(frozen=True, eq=False)(cls)
    fields = dataclasses.fields(cls)
    meta = [f.name for f in fields if f.metadata.get("static", False)]
    data = [f.name for f in fields if not f.metadata.get("static", False)]
    jax.tree_util.register_dataclass(cls, data_fields=data, meta_fields=meta)
    cls.replace = lambda self, **changes: dataclasses.replace(self, **changes)
    return cls
