"""The keywords of :func:`diffkin.ik.solve` that add terms, in one registry: ``solve`` and ``solve_path``
iterate it (which keywords are robots-only, which carry a path's waypoint axis, the terms of a call).

A new kind of term is its own file in :mod:`diffkin.ik._terms` (the term and a host-side builder),
one :class:`Keyword` here and a case in the term-Jacobian test (``tests/validation/test_ik_relative.py``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

from diffkin.ik import _args
from diffkin.ik._terms import Constraint, Target, com, pose, relative
from diffkin.ik._terms.avoid import Avoid, AvoidTerm, check_avoid
from diffkin.models.robot import Robot


def _avoid(robot: Robot, avoid, weights: Mapping) -> list[tuple[AvoidTerm, Avoid, str]]:
    """The clearance term of ``avoid=dk.ik.Avoid(...)``: ``[(term, avoid, label)]``, checked on the host."""
    check_avoid(robot, avoid)
    return [(AvoidTerm.of(avoid), avoid, "'avoid'")]


class Keyword(NamedTuple):
    """A keyword of :func:`diffkin.ik.solve` (robots only) that adds terms of one kind.

    Attributes:
        name: the keyword.
        terms: ``terms(robot, value, weights) -> [(term, data, label)]``: its terms, checked on the
            host, each with what it binds (a target's ``(..., 4, 4)`` or ``(..., 3)`` array, or a
            constraint's data) and its name in error messages. ``weights`` is ``solve``'s mapping.
        per_target: the value holds one entry per target (the targets' batch shape, and along a
            path their waypoint axis): its terms are :class:`~diffkin.ik._terms.Target`\\ s; else one
            value serves every target: :class:`~diffkin.ik._terms.Constraint`\\ s.
    """

    name: str
    terms: Callable[[Robot, Any, Mapping], list[tuple[Any, Any, str]]]
    per_target: bool


#: Every keyword that adds terms, in the order of their terms (and of their errors in ``IKResult``),
#: after the targets' mapping's.
KEYWORDS = (
    Keyword("relative", relative.from_mapping, True),
    Keyword("com", com.from_target, True),
    Keyword("avoid", _avoid, False),
)


class Terms(NamedTuple):
    """The terms of a call of :func:`diffkin.ik.solve`: its ``targets``, its ``constraints``, what they
    bind (``data``: the targets' arrays, then the constraints' data) and the targets' ``batch`` shape."""

    targets: tuple[Target, ...]
    constraints: tuple[Constraint, ...]
    data: list
    batch: tuple[int, ...]


def terms_of(model, target, given: Mapping[str, Any], weights) -> Terms:
    """The terms of ``target`` (a chain's array, a robot's mapping) and of the keywords ``given``
    (``{name: value}``, ``None`` for absent), checked on the host."""
    if not isinstance(model, Robot):
        array, position_only, shape = _args.check_target(target)
        return Terms((pose.PoseTarget(None, position_only),), (), [array], shape)
    if weights is not None and not isinstance(weights, Mapping):
        raise TypeError(f"weights: expected a mapping from target frame names to weights, got {type(weights).__name__}")
    weights = {} if weights is None else weights
    found: list[tuple[Any, Any, str]] = list(pose.from_mapping(model, target, weights))
    constraints: list[tuple[Any, Any, str]] = []
    for keyword in KEYWORDS:
        if given.get(keyword.name) is not None:
            (found if keyword.per_target else constraints).extend(keyword.terms(model, given[keyword.name], weights))
    if not found:
        raise TypeError(f"target: for a Robot, expected a non-empty mapping frame name -> target, got {target!r}")
    keys = set(target).union(*(value for value in given.values() if isinstance(value, Mapping)))
    for name in weights:
        if name not in keys:
            raise ValueError(f"weights: {name!r} is not one of the targets {list(keys)}")
    batch: tuple[int, ...] | None = None
    for term, array, label in found:
        b = tuple(array.shape[:-1] if term.position_only else array.shape[:-2])
        if batch is not None and b != batch:
            raise ValueError(f"target[{label}]: batch shape {b} differs from target[{found[0][2]}]'s {batch}")
        batch = b
    assert batch is not None
    # Only the weights' ratios matter: scaled so that the largest is 1 (LM's damping floor and stall
    # test are absolute; weights of 1e-5 would otherwise stall every seed).
    scale = max(max(t.weights[: 3 if t.position_only else 6]) for t, _, _ in found)
    targets = tuple(
        t if scale == 1.0 else dataclasses.replace(t, weights=tuple(w / scale for w in t.weights)) for t, _, _ in found
    )
    return Terms(targets, tuple(t for t, _, _ in constraints), [a for _, a, _ in found + constraints], batch)
