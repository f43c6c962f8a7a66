"""``solve``: the front door (argument checks) and the solver of one chain's end effector.

A :class:`~diffkin.Robot` with a mapping of targets goes to :mod:`diffkin.ik._tree`.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from diffkin._sharding import automatic_axes
from diffkin._xla import solver_jit
from diffkin.ik import _args, _rounds, _tree
from diffkin.ik._implicit import implicit_q
from diffkin.ik._prepare import cast, detach, inward, method_steps, valid_targets
from diffkin.ik._problem import Problem
from diffkin.ik._result import IKResult
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

_DEFAULT_ITERS = {"lm": 10, "optax": 1000}
# Several targets (and a floating base) converge in more LM steps: 10 solved 94 % of Talos'
# four-contact problems, 20 solved 98 %, 40 solved 100 % (50 problems, float32).
_TREE_ITERS = {"lm": 30, "optax": 1000}


def solve(
    chain,
    target,
    *,
    key=None,
    q0=None,
    num_seeds: int = 32,
    method: str = "lm",
    max_iters: int | None = None,
    pos_tol: float = 1e-5,
    rot_tol: float = 1e-4,
    respect_limits: bool = True,
    optimizer=None,
    weights=None,
    locked=None,
    rest=None,
    secondary=None,
    solve_base: bool = False,
    base=None,
) -> IKResult:
    """Inverse kinematics for a batch of targets, from random seeds (and an optional warm start).

    Every target gets up to ``num_seeds`` seeds, each the best (least pose error) of 8
    configurations drawn uniformly within the limits, in rounds of 4: the first round (plus
    ``q0`` when given) for every target at once, each later one only for the targets still
    unsolved, packed into small chunks; with LM, three final rounds go on from the best seed so
    far and small perturbations of it. Each round iterates its seeds together in a
    ``lax.while_loop`` that exits when every target in it is done, so easy targets cost one
    round and only hard (or unreachable) ones cost more. A target's
    result does not depend on the rest of the batch. Pure and traceable:
    works under ``jit``/``vmap``/``grad``; ``num_seeds``, ``method``, ``max_iters``,
    ``respect_limits`` and ``optimizer`` are static. Nothing raises inside ``jit``: a target
    that cannot be reached (or holds NaN) gives ``success=False`` and finite values.

    The residual is ``[p_t - p; 0.2 m/rad * log(R_t R^T)]`` (world frame). ``method="lm"``
    takes Levenberg-Marquardt steps ``dq = J^T (J J^T + lam I)^-1 r`` (or the ``dof x dof``
    form, whichever is smaller) with error-proportional damping ``lam = mu |r|^2`` adapted by
    accepting only steps that lower ``|r|^2``. ``method="optax"`` follows the exact gradient of
    ``|r|^2 / 2`` with an optax transformation; it needs far more iterations than LM for the
    same accuracy and is meant for combining with costs of your own. Iterates are projected:
    unlimited revolute joints wrap to ``[-pi, pi)`` and, with ``respect_limits``, every joint is
    clipped to ``[lower, upper]``.

    The returned ``q`` is differentiable with respect to ``target`` and the chain's parameters
    through the implicit function theorem (``dq = J^+ dx``, see :func:`implicit_q`), not through
    the iterations; the derivative is that of a successful, non-singular solution off the limits.

    A :class:`~diffkin.Robot` takes a mapping ``{frame_name: target}`` instead: every target is
    solved at once (success means all within tolerance), with per-axis ``weights``, ``locked``
    joints, secondary objectives and a solved floating base (see :mod:`diffkin.ik._tree`; the
    residual stacks one such residual per target, dense linear algebra above 6 rows and columns,
    30 LM iterations per seed by default).

    Args:
        chain: a :class:`~diffkin.DHChain` or :class:`~diffkin.PoEChain`, or a :class:`~diffkin.Robot`.
        target: ``(..., 4, 4)`` end-effector poses ``T_base_ee`` or ``(..., 3)`` positions in the
            base frame (metres; orientation free). The solver runs in this dtype (float32 default).
            For a robot: a mapping from frame names to such targets (world frame), one batch shape.
        key: PRNG key for the seeds; default ``jax.random.key(0)``. Target ``b`` of the flattened
            batch draws round ``r``'s seeds from a hash of ``(key, b, r)`` (not ``jax.random``: see
            :mod:`diffkin.ik._uniform`), so its result does not depend on the rest of the batch.
        q0: optional ``(..., dof)`` warm start broadcastable to the targets' batch; it is an extra
            seed and, among successful seeds, the solution nearest to ``q0`` is returned.
        num_seeds: most random seeds per target (static, >= 1), in rounds of 4; only unsolved
            targets use more than the first round.
        method: ``"lm"`` (default) or ``"optax"``.
        max_iters: iterations per seed (static); default 10 for LM, 1000 for optax. Each
            iteration is one forward pass.
        pos_tol: success tolerance on the position error, metres (may be a traced scalar: one
            compilation serves every tolerance).
        rot_tol: success tolerance on the rotation angle error, radians (may be traced).
        respect_limits: keep every iterate (and the result) within ``[chain.lower, chain.upper]``.
        optimizer: an ``optax.GradientTransformation`` for ``method="optax"``; default
            ``optax.adam(1e-2)``.
        weights: robots: ``{frame_name: w}``, ``w`` six non-negative weights of the ``[v; w]``
            error in the target frame (world axes for a position target) or a pair
            ``(w_pos, w_rot)``; a zero frees that axis (errors and success ignore it). Default 1.
        locked: robots: ``{joint_name: value}`` (a number or one per target) or a sequence of
            joint names whose values come from ``q0``; those joints do not move.
        rest: robots: ``(..., dof)`` rest configuration (for the ``"rest"`` objective).
        secondary: robots: ``"rest"``, ``"limits"``, a sequence of them or ``{name: weight}``
            (default ``"rest"`` when ``rest`` is given): lowered in the null space of the
            targets once they are solved, without losing any (see :mod:`diffkin.ik._secondary`).
        solve_base: robots: for a floating robot, solve the root pose too (``IKResult.base``).
        base: robots: ``(..., 4, 4)`` root pose ``T_world_root``: fixed, or the starting guess
            with ``solve_base`` (default identity).

    Returns:
        :class:`IKResult`, each field with the batch shape of ``target``. Without a success the
        seed of least residual is returned. Non-finite targets give ``success=False``, ``q`` of
        that seed and errors ``finfo(dtype).max``.

    Raises:
        ValueError: a bad target shape, ``q0`` of the wrong length or batch, an unknown method,
            ``num_seeds < 1``, ``max_iters < 0``, negative tolerances, ``optimizer`` without
            ``method="optax"``.
        ValueError: also a concrete pose target that is not a rigid transform (within 1e-5 in
            float32, 1e-9 in float64), naming its batch index; traced ones give ``success=False``.
        TypeError: a chain that is not a chain model, an optimizer that is not an optax
            ``GradientTransformation``, a bool, complex or float16 target.
    """
    if isinstance(chain, Robot):
        max_iters = _TREE_ITERS.get(method, 0) if max_iters is None else max_iters
        return _tree.solve(
            chain,
            target,
            weights=weights,
            locked=locked,
            q0=q0,
            rest=rest,
            secondary=secondary,
            solve_base=solve_base,
            base=base,
            key=key,
            num_seeds=num_seeds,
            method=method,
            max_iters=max_iters,
            pos_tol=pos_tol,
            rot_tol=rot_tol,
            respect_limits=respect_limits,
            optimizer=optimizer,
        )
    max_iters = _DEFAULT_ITERS.get(method, 0) if max_iters is None else max_iters  # (an unknown method raises)
    if not isinstance(chain, (DHChain, PoEChain)):
        raise TypeError(f"chain: expected a DHChain, PoEChain or Robot, got {type(chain).__name__}")
    for name, value in (
        ("weights", weights),
        ("locked", locked),
        ("rest", rest),
        ("secondary", secondary),
        ("base", base),
    ):
        if value is not None:
            raise ValueError(f"{name}: only for a Robot (solve dk.load_robot(...) with a mapping of targets)")
    if solve_base:
        raise ValueError("solve_base: only for a floating Robot")
    _args.check_settings(num_seeds, method, max_iters, pos_tol, rot_tol, optimizer)
    target, position_only, batch = _args.check_target(target)
    if q0 is not None:
        _args.check_batched(q0, "q0", (chain.dof,), batch, f"for a {chain.dof}-joint chain")
    if 0 in batch:  # no targets: empty results of the batch's shape
        empty = lambda *shape, dtype=target.dtype: jnp.zeros(batch + shape, dtype)  # noqa: E731
        return IKResult(empty(chain.dof), empty(dtype=bool), empty(), empty(), empty(dtype=jnp.int32))
    known, traced = _args.split_model(chain)
    return automatic_axes(_solve, target, len(batch))(
        traced,
        target,
        _args.default_key() if key is None else key,
        None if q0 is None else jnp.asarray(q0),
        _args.tolerance(pos_tol, target.dtype),
        _args.tolerance(rot_tol, target.dtype),
        known=known,
        num_seeds=int(num_seeds),
        method=method,
        max_iters=int(max_iters),
        respect_limits=bool(respect_limits),
        optimizer=optimizer,
        position_only=position_only,
        batch=batch,
    )


@functools.partial(
    solver_jit,
    static_argnames=(
        "known",
        "num_seeds",
        "method",
        "max_iters",
        "respect_limits",
        "optimizer",
        "position_only",
        "batch",
    ),
)
def _solve(
    traced: tuple,
    target,
    key,
    q0,
    pos_tol,
    rot_tol,
    *,
    known: _args.KnownLeaves,
    num_seeds,
    method,
    max_iters,
    respect_limits,
    optimizer,
    position_only,
    batch,
) -> IKResult:
    """The solver, compiled once per chain (by value), shapes and static settings.

    Every closure (problems, ranks) is built here, inside the trace, so that repeated eager
    calls of :func:`solve` hit jit's cache instead of retracing and recompiling.
    """
    chain = _args.join(known, traced)
    dtype = target.dtype
    dof = chain.dof
    n = int(np.prod(batch, dtype=np.int64))
    valid, safe = valid_targets(target.reshape((n,) + target.shape[len(batch) :]), position_only)
    model = cast(detach(chain), dtype)
    lower, upper = inward(detach(chain.lower), dtype, -1), inward(detach(chain.upper), dtype, 1)
    wrap = jnp.asarray([t == "R" for t in chain.joint_types]) & ~jnp.isfinite(lower) & ~jnp.isfinite(upper)
    fixed = detach(safe)
    q0_flat = None
    if q0 is not None:
        q0_flat = jnp.broadcast_to(jnp.asarray(q0, dtype), batch + (dof,)).reshape(n, dof)
        q0_flat = jnp.where(jnp.isfinite(q0_flat), detach(q0_flat), 0.0)

    def build(idx, copies: int) -> Problem:
        T = jnp.broadcast_to(fixed[idx], (copies,) + fixed[idx].shape).reshape(
            (copies * idx.shape[0],) + fixed.shape[1:]
        )
        p = tuple(T[:, i] if position_only else T[:, i, 3] for i in range(3))
        R = None if position_only else tuple(tuple(T[:, i, j] for j in range(3)) for i in range(3))
        return Problem(model, p, R, lower, upper, wrap, respect_limits)

    def rank(idx, q):  # among successes: nearest the warm start
        return None if q0_flat is None else jnp.sum((q - q0_flat[idx].T[:, None, :]) ** 2, axis=0)

    settings = _rounds.Settings(num_seeds, max_iters, _rounds.POLISH if method == "lm" else 0, pos_tol, rot_tol)
    best = _rounds.search(
        build, lambda idx, q: q, rank, key, n, lower, upper, q0_flat, method_steps(method, optimizer), settings
    )
    big = jnp.finfo(dtype).max
    q_best = implicit_q(chain, safe, best.x.T)
    return IKResult(
        q=q_best.reshape(batch + (dof,)),
        success=(best.success & valid).reshape(batch),
        pos_err=jnp.where(valid, best.ev.pos_err, big).reshape(batch),
        rot_err=jnp.where(valid, best.ev.rot_err, big).reshape(batch),
        iters=best.iters.reshape(batch),
    )
