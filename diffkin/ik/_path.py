"""``solve_path``: IK along waypoints, each solved from the previous solution with bounded joint steps.

Waypoint 0 is solved by :func:`~diffkin.ik.solve` (every seed, or from ``q0``). Each later waypoint
starts from the previous solution and iterates only that state (no random seeds), every joint
kept within ``max_step`` of its previous value (a box intersected with the limits), so a solution
never jumps to another branch: a waypoint that cannot be reached within the step fails and the
path is reported not ok. The waypoints are a ``lax.scan``: one compiled step serves any number.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._checks import instance
from diffkin._static import ModelKey, partition
from diffkin._xla import solver_jit
from diffkin.ik import _args, _search
from diffkin.ik._implicit import implicit
from diffkin.ik._keywords import KEYWORDS, terms_of
from diffkin.ik._methods import METHODS
from diffkin.ik._prepare import detach, prepare
from diffkin.ik._problem import Spec
from diffkin.ik._solve import constraints_at, plan, result, solve, target_errors
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

# Settings of solve that a path passes on (secondary objectives and a rest pose are not: a path's
# later waypoints move by the targets only), and then every keyword that adds terms.
_SETTINGS = (
    "key",
    "num_seeds",
    "method",
    "max_iters",
    "pos_tol",
    "rot_tol",
    "respect_limits",
    "optimizer",
    "weights",
    "locked",
    "solve_base",
    "base",
)
_PASSED = _SETTINGS + tuple(keyword.name for keyword in KEYWORDS)


class PathResult(NamedTuple):
    """Solutions along paths of waypoints (a pytree); ``...`` is the batch of paths, ``T`` the waypoints.

    Attributes:
        q: ``(..., T, dof)`` the solution at every waypoint.
        success: ``(..., T)`` each waypoint within tolerance (as :attr:`IKResult.success`).
        path_ok: ``(...,)`` every waypoint a success and every joint step within ``max_step``.
        max_step: ``(...,)`` the largest joint step taken between consecutive waypoints (radians or
            metres; 0 for a single waypoint).
        pos_err, rot_err: ``(..., T)`` (a chain) or ``(..., T, k)`` (a robot's ``k`` targets), as
            :class:`IKResult`.
        base: ``(..., T, 4, 4)`` the solved root poses with ``solve_base=True``, else ``None``.
        com_err: ``(..., T)`` with a ``com`` target, else ``None``.
        clearance: ``(..., T)`` metres with ``avoid`` (as :attr:`IKResult.clearance`: every
            waypoint's success also needs it ``>= avoid.margin``), else ``None``.
    """

    q: jax.Array
    success: jax.Array
    path_ok: jax.Array
    max_step: jax.Array
    pos_err: jax.Array
    rot_err: jax.Array
    base: jax.Array | None = None
    com_err: jax.Array | None = None
    clearance: jax.Array | None = None


def _pose_axis(a) -> int:
    """The path axis of a target array: before ``(4, 4)`` of a pose, before the last axis otherwise."""
    return -3 if np.ndim(a) >= 3 and np.shape(a)[-2:] == (4, 4) else -2


def _waypoint(tree, t: int):
    """Waypoint ``t`` of every target array of ``tree`` (an array, a mapping of them, or ``None``)."""
    if tree is None:
        return None
    if isinstance(tree, Mapping):
        return {key: _waypoint(value, t) for key, value in tree.items()}
    a = jnp.asarray(tree)
    return jnp.take(a, t, axis=_pose_axis(a)) if a.ndim >= 2 else a


def solve_path(model, targets, *, q0=None, max_step=None, **solve_kwargs) -> PathResult:
    """Inverse kinematics along paths: waypoint 0 solved globally, each later one from the previous solution.

    Every joint moves at most ``max_step`` between consecutive waypoints (a bound on each step,
    intersected with the joint limits), so the solution stays on one branch; a waypoint it cannot
    reach that way fails (``success`` False there, ``path_ok`` False) instead of jumping. The
    waypoints are scanned: compile time does not grow with their number. Pure and traceable; ``q``
    is differentiable with respect to the waypoints (implicit function theorem, per waypoint).

    Args:
        model: a chain or a :class:`~diffkin.Robot` (as :func:`solve`).
        targets: a chain: ``(..., T, 4, 4)`` poses or ``(..., T, 3)`` positions; a robot: a mapping
            of those. ``relative`` and ``com`` (keyword arguments of :func:`solve`) carry the same
            path axis (``(..., T, 4, 4)``, ``(..., T, 3)`` or ``(..., T, 2)``).
        q0: ``(..., dof)`` warm start of waypoint 0 (its solution is then the one nearest ``q0``).
        max_step: the largest joint move between waypoints, radians (revolute) or metres
            (prismatic): a scalar or ``(dof,)``; default unbounded.
        **solve_kwargs: the other arguments of :func:`solve` (``key``, ``num_seeds``, ``method``,
            ``max_iters``, tolerances, ``respect_limits``, ``optimizer``, ``weights``, ``locked``,
            ``solve_base``, ``base``, ``relative``, ``com``, ``avoid``); ``max_iters`` applies to
            every waypoint, and with ``avoid`` every waypoint keeps clear (a waypoint that cannot
            is not a success).

    Returns:
        :class:`PathResult`.

    Raises:
        ValueError, TypeError: as :func:`solve`; also targets without a path axis (or with none
            of its waypoints), a ``max_step`` that is not positive or of the wrong shape, and the
            ``secondary``/``rest`` arguments (not supported along a path).
    """
    instance(model, (DHChain, PoEChain, Robot), "model", "a DHChain, PoEChain or Robot")
    for name in ("secondary", "rest"):
        if solve_kwargs.get(name) is not None:
            raise ValueError(f"{name}: not supported by solve_path (later waypoints move by the targets only)")
    unknown = sorted(set(solve_kwargs) - set(_PASSED))
    if unknown:
        raise TypeError(f"solve_path: unexpected arguments {unknown}; expected those of dk.ik.solve: {list(_PASSED)}")
    defaults = {name: p.default for name, p in inspect.signature(solve).parameters.items() if name in _PASSED}
    kw = {name: solve_kwargs.get(name, defaults[name]) for name in _SETTINGS}
    given = {k.name: solve_kwargs.get(k.name) for k in KEYWORDS}
    terms = terms_of(model, targets, given, kw["weights"])
    path_batch = terms.batch
    if not path_batch or path_batch[-1] == 0:
        raise ValueError(
            f"targets: expected a path axis with at least one waypoint before the pose axes ((..., T, 4, 4) or "
            f"(..., T, 3)), got batch shape {path_batch}"
        )
    bound = _max_step(max_step, model.dof)
    first_given: dict[str, Any] = {
        k.name: _waypoint(given[k.name], 0) if k.per_target else given[k.name] for k in KEYWORDS
    }
    # plan's keywords
    first_kw: dict[str, Any] = {name: value for name, value in kw.items() if name not in ("key", "respect_limits")}
    checked = plan(model, _waypoint(targets, 0), first_given, q0=q0, rest=None, secondary=None, **first_kw)
    first = solve(
        model,
        _waypoint(targets, 0),
        q0=q0,
        key=kw["key"],
        respect_limits=kw["respect_limits"],
        **first_kw,
        **first_given,
    )
    dtype = checked.dtype
    static, traced = partition(model)
    return _follow(
        traced,
        tuple(terms.data),
        first,
        None if kw["base"] is None else jnp.asarray(kw["base"], dtype),
        None if checked.locked_q is None else jnp.asarray(checked.locked_q, dtype),
        jnp.asarray(bound, dtype),
        _args.tolerance(kw["pos_tol"], dtype),
        _args.tolerance(kw["rot_tol"], dtype),
        static=static,
        spec=checked.spec,
        method=kw["method"],
        max_iters=checked.max_iters,
        respect_limits=bool(kw["respect_limits"]),
        optimizer=kw["optimizer"],
        batch=path_batch,
    )


def _max_step(max_step, dof: int) -> np.ndarray:
    """``(dof,)`` step bounds (``inf``: unbounded), checked on the host."""
    if max_step is None:
        return np.full(dof, np.inf)
    try:
        bound = np.broadcast_to(np.asarray(max_step, dtype=np.float64), (dof,))
    except (TypeError, ValueError) as err:
        raise ValueError(f"max_step: expected a positive number or {dof} of them, got {max_step!r}") from err
    if np.any(np.isnan(bound)) or np.any(bound <= 0):
        raise ValueError(f"max_step: expected positive bounds (radians or metres), got {max_step!r}")
    return bound


@functools.partial(
    solver_jit,
    static_argnames=("static", "spec", "method", "max_iters", "respect_limits", "optimizer", "batch"),
)
def _follow(
    traced,
    data: tuple,
    first,
    base,
    locked_q,
    bound,
    pos_tol,
    rot_tol,
    *,
    static: ModelKey,
    spec: Spec,
    method: str,
    max_iters: int,
    respect_limits: bool,
    optimizer,
    batch: tuple[int, ...],
) -> PathResult:
    """Waypoints ``1 .. T-1`` from waypoint 0's solution ``first`` (an :class:`IKResult`), scanned."""
    paths, T = batch[:-1], batch[-1]
    s = prepare(static, traced, data, spec, batch, paths, locked_q=locked_q, base=None if spec.solve_base else base)
    dtype, dof, k = data[0].dtype, s.model.dof, len(spec.targets)
    n = int(np.prod(paths, dtype=np.int64))
    lower, upper = s.lower, s.upper
    if not respect_limits:
        lower, upper = jnp.full_like(lower, -jnp.inf), jnp.full_like(upper, jnp.inf)
    valid = s.valid.reshape(n, T).T  # (T, n)
    root, base_flat = rg.IDENTITY, None
    if s.base is not None and s.base_ok is not None and not spec.solve_base:  # a non-finite root pose fails
        valid = valid & s.base_ok  # (as in solve), the identity solved
        base_flat = s.base
        root = rg.from_matrix(detach(base_flat))
    locked_values = s.locked_q.T if s.locked_q is not None else jnp.zeros((dof, 1))
    x0 = jax.lax.stop_gradient(first.q.reshape(n, dof).T)
    if spec.solve_base:
        B = jax.lax.stop_gradient(first.base.reshape(n, 4, 4))
        x0 = jnp.concatenate([x0, B[:, :3, 3].T, B[:, :3, :3].reshape(n, 9).T])
    no_wrap = jnp.zeros(dof, bool)
    steps = METHODS[method].steps(optimizer)
    settings = _search.Settings(1, max_iters, 0, pos_tol, rot_tol)

    def step(x_prev, waypoint):
        q_prev = x_prev[:dof]
        lo = jnp.maximum(lower[:, None], q_prev - bound[:, None])
        hi = jnp.minimum(upper[:, None], q_prev + bound[:, None])
        problem = spec.problem(s.model, spec.bind(waypoint, s.data), root, locked_values, (lo, hi, no_wrap, True))
        best = _search.follow(problem, x_prev, steps, settings)
        values, met = constraints_at(spec, problem, best.x)  # exactly, at the returned states
        success = best.success if met is None else best.success & met
        return best.x, (best.x, success, best.ev.pos_err[:k], best.ev.rot_err[:k], best.iters, values)

    # per waypoint (T, n, ...), in term order
    later = [jnp.moveaxis(t.reshape((n, T) + t.shape[1:]), 1, 0)[1:] for t in s.targets]
    _, (xs, success, pos_err, rot_err, iters, values) = jax.lax.scan(step, x0, later)
    # every waypoint's state (T, n_state, n), its derivative by the implicit function theorem
    xs = jnp.concatenate([x0[None], xs])
    flat = lambda a: jnp.moveaxis(a, 0, -1).reshape(a.shape[1:-1] + (n * T,))  # noqa: E731  (..., n, T) order
    x_all = implicit(
        spec, s.differentiable, s.safe, None if base_flat is None else jnp.repeat(base_flat, T, axis=0), flat(xs)
    )
    first_pos, first_rot = target_errors(spec, first, n)
    pos_err = jnp.concatenate([first_pos[None], pos_err])  # (T, k, n)
    rot_err = jnp.concatenate([first_rot[None], rot_err])
    success = jnp.concatenate([first.success.reshape(1, n), success & valid[1:]])
    iters = jnp.concatenate([first.iters.reshape(1, n), iters])
    values = {name: jnp.concatenate([getattr(first, name).reshape(1, n), v]) for name, v in values.items()}
    out = result(
        spec,
        x_all,
        flat(pos_err),
        flat(rot_err),
        flat(valid),
        flat(success),
        flat(iters),
        paths + (T,),
        {name: flat(v) for name, v in values.items()},
    )
    q = out.q
    moves = jnp.abs(jnp.diff(q, axis=-2))  # (..., T - 1, dof)
    largest = jnp.max(moves, axis=(-2, -1), initial=0.0)
    eps = jnp.finfo(dtype).eps
    within = jnp.all(moves <= bound + 8 * eps * (1.0 + jnp.abs(q[..., 1:, :])), axis=(-2, -1))
    return PathResult(
        q=q,
        success=out.success,
        path_ok=jnp.all(out.success, axis=-1) & within,
        max_step=largest,
        pos_err=out.pos_err,
        rot_err=out.rot_err,
        base=out.base,
        com_err=out.com_err,
        clearance=out.clearance,
    )
