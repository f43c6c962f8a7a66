"""Frozen dataclasses registered as JAX pytrees, validated when built.

Fields declared with :func:`static` are pytree metadata (hashed, part of the compiled
structure); every other field is an array leaf that JAX can trace, batch and differentiate.

Validation is one hook: a class may define ``_check(self, concrete: bool)``. It runs on every
construction by the user (``Cls(...)``, ``obj.replace(...)``, the ``from_*`` builders, which end
in ``Cls(...)``): it checks the static fields and the shapes of the leaves always, and their
values only when ``concrete`` (no leaf is a tracer, e.g. not under ``jit``, ``grad``, ``vmap``).
JAX's own rebuilding of instances (``tree_unflatten``: after a transformation, ``tree_map``, with
tracers, batched leaves, ``None`` or ``object()`` placeholders) bypasses ``__init__`` and so the
check: it costs nothing there and cannot break on leaves that are not the user's arrays.

Defaults that depend on other fields are a second hook, run first: ``_fill(self) -> dict`` gives
the values of the fields the user left ``None`` (the models' ``velocity``: ``inf`` per joint).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar, dataclass_transform

import jax

T = TypeVar("T")


def static(**kwargs: Any) -> Any:
    """A dataclass field that is static structure, not an array leaf."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def _post_init(self) -> None:
    fill = getattr(self, "_fill", None)
    if fill is not None:
        for name, value in fill().items():
            object.__setattr__(self, name, value)
    leaves = [getattr(self, f.name) for f in dataclasses.fields(self) if not f.metadata.get("static", False)]
    self._check(concrete=not any(isinstance(x, jax.core.Tracer) for x in leaves))


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field, static))
def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it as a pytree.

    The class gains ``replace(**fields)``, returning a modified copy, validated as a new instance
    (see the module docstring; traced values get the shape checks only).
    """
    klass: Any = cls  # the class being made a dataclass: attributes a type checker cannot know of
    if hasattr(klass, "_check") and "__post_init__" not in klass.__dict__:
        klass.__post_init__ = _post_init
    klass = dataclasses.dataclass(frozen=True, eq=False)(klass)
    fields = dataclasses.fields(klass)
    meta = tuple(f.name for f in fields if f.metadata.get("static", False))
    data = tuple(f.name for f in fields if not f.metadata.get("static", False))

    def flatten_with_keys(obj):
        return [(jax.tree_util.GetAttrKey(n), getattr(obj, n)) for n in data], tuple(getattr(obj, n) for n in meta)

    def flatten(obj):
        return [getattr(obj, n) for n in data], tuple(getattr(obj, n) for n in meta)

    def unflatten(aux, children):
        obj = object.__new__(klass)  # no __init__, so no check: see the module docstring
        for name, value in zip(meta, aux, strict=True):
            object.__setattr__(obj, name, value)
        for name, value in zip(data, children, strict=True):
            object.__setattr__(obj, name, value)
        return obj

    jax.tree_util.register_pytree_with_keys(klass, flatten_with_keys, unflatten, flatten)
    klass.replace = lambda self, **changes: dataclasses.replace(self, **changes)
    return klass
