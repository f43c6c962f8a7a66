"""The iterative methods of the IK, and each method's facts, in one registry.

A method is three functions over a batch of problems (problem axis last): ``init(x) -> aux``,
``propose(problem, x, ev, aux) -> (x_try, aux)`` and ``judge(cost, cost_try, aux) -> (accepted,
aux, stalled)`` (see :func:`diffkin.ik._search.search`). A new method is a module with those three
functions and one entry in :data:`METHODS`.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
from collections.abc import Callable
from typing import Any, NamedTuple

from diffkin.ik import _lm


class Steps(NamedTuple):
    """An iterative method's functions (see the module docstring)."""

    init: Callable[..., Any]  # (x) -> aux
    propose: Callable[..., tuple[Any, Any]]  # (problem, x, ev, aux) -> (x_try, aux)
    judge: Callable[..., tuple[Any, Any, Any]]  # (cost, cost_try, aux) -> (accepted, aux, stalled)


@dataclasses.dataclass(frozen=True)
class Method:
    """What the solver needs to know of a method.

    Attributes:
        iters_chain: default iterations per seed for a chain (one end-effector target).
        iters_robot: default iterations per seed for a robot: several targets and a floating base
            converge in more LM steps (10 solved 94 % of Talos' four-contact problems, 20 solved
            98 %, 40 solved 100 %; 50 problems, float32).
        polish: final rounds that go on from the best seed so far and small perturbations of it.
        solves_base: whether it can solve a floating base (a retraction on SE(3)).
        steps: ``steps(optimizer) -> Steps``.
    """

    iters_chain: int
    iters_robot: int
    polish: int
    solves_base: bool
    steps: Callable[..., Steps]


def _lm_steps(optimizer) -> Steps:
    return Steps(_lm.init, _lm.propose, _lm.judge)


def _optax_steps(optimizer) -> Steps:
    _optax = optax_module()
    opt = _optax.default_optimizer() if optimizer is None else optimizer
    return Steps(functools.partial(_optax.init, opt), functools.partial(_optax.propose, opt), _optax.judge)


def optax_module():
    """``diffkin.ik._optax`` (which needs optax), or an ImportError naming the extra to install."""
    try:
        return importlib.import_module("diffkin.ik._optax")
    except ImportError as e:
        raise ImportError("method='optax' needs optax: pip install 'diffkin[ik]' (or pip install optax)") from e


METHODS = {
    "lm": Method(iters_chain=10, iters_robot=30, polish=3, solves_base=True, steps=_lm_steps),
    "optax": Method(iters_chain=1000, iters_robot=1000, polish=0, solves_base=False, steps=_optax_steps),
}
