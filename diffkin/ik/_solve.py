"""``solve``: argument checks, seeding, the shared iteration loop and the choice of seed."""

from __future__ import annotations

import functools
import importlib
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin import kinematics
from diffkin._checks import real_array, rigid_poses, rigid_tol
from diffkin._rigid import is_concrete
from diffkin.ik import _lm
from diffkin.ik._implicit import implicit_q
from diffkin.ik._problem import ROT_WEIGHT, Eval, Problem, evaluate
from diffkin.ik._result import IKResult
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

_METHODS = ("lm", "optax")
_DEFAULT_ITERS = {"lm": 10, "optax": 1000}
# Rounds of _GROUP seeds per target: the first for every target, the later ones only for the
# targets still unsolved, packed into chunks of max(n / 32, 8) targets (one compiled loop serves
# every later round, and small chunks keep its iterations cheap).
_GROUP = 4
_CHUNK_DIV, _MIN_CHUNK = 32, 8
_SCREEN = 8  # each random seed is the best (least pose error) of this many uniform draws
_POLISH = 3  # LM: final rounds go on from the best seed so far and perturbations of it ...
_JITTER = 0.05  # ... each a step of this fraction towards a random seed


class _Seeds(NamedTuple):
    """Iteration state of every seed, flat over ``P = seeds x targets`` (problem axis last)."""

    q: jax.Array  # (dof, P)
    ev: Eval
    aux: object  # method state: LM damping or optax state
    success: jax.Array  # (P,) bool, sticky
    stalled: jax.Array  # (P,) bool
    iters: jax.Array  # (P,) int32


def _detach(tree):
    """``stop_gradient`` on traced leaves only (concrete model constants stay foldable)."""
    return jax.tree.map(lambda x: x if is_concrete(x) else jax.lax.stop_gradient(x), tree)


def _cast(tree, dtype):
    """Traced floating leaves to ``dtype``; concrete ones are folded as Python floats by the model."""
    def cast(x):
        if not is_concrete(x) and jnp.issubdtype(x.dtype, jnp.floating):
            return x.astype(dtype)
        return x
    return jax.tree.map(cast, tree)


def _where(mask, new, old):
    """Per-problem select over a pytree whose leaves all end with the problem axis."""
    return jax.tree.map(lambda a, b: jnp.where(mask, a, b), new, old)


def _inward(limit, dtype, side: int) -> jax.Array:
    """``limit`` in ``dtype``, rounded towards the inside of the range (``side`` -1: lower, +1: upper)."""
    limit = jnp.asarray(limit)
    rounded = limit.astype(dtype)
    outside = side * (rounded.astype(limit.dtype) - limit) > 0
    return jnp.where(outside, jnp.nextafter(rounded, jnp.asarray(-side * jnp.inf, dtype)), rounded)


def _seed_configs(key, targets: jax.Array, rounds: jax.Array, lower, upper, count: int, dtype) -> jax.Array:
    """``(count, len(targets), dof)`` uniform within the limits (one turn / one metre if unlimited).

    Target ``b = targets[i]`` draws its seeds of round ``r = rounds[i]`` from
    ``fold_in(fold_in(key, b), r)``: they depend neither on the batch nor on the pass that tries them.
    """
    lo = jnp.where(jnp.isfinite(lower), lower, -np.pi)
    hi = jnp.where(jnp.isfinite(upper), upper, np.pi)
    keys = jax.vmap(lambda b, r: jax.random.fold_in(jax.random.fold_in(key, b), r))(targets, rounds)
    u = jax.vmap(lambda k: jax.random.uniform(k, (count, lower.shape[0]), dtype))(keys)
    return jnp.swapaxes(lo + u * (hi - lo), 0, 1)


def _screened(model, targets, q, position_only: bool):
    """Per target and seed slot, the candidate of least pose error (one forward pass each).

    Args:
        model: the chain.
        targets: ``(m, 4, 4)`` poses or ``(m, 3)`` positions.
        q: ``(K, group, m, dof)`` candidates, ``K`` per seed slot.

    Returns:
        ``(group, m, dof)``. The error is ``|p_t - p|^2 + ROT_WEIGHT^2 (3 - trace(R_t^T R))``
        (the rotation term is ``2 (1 - cos angle)``, the squared angle near 0).
    """
    ee = kinematics._pass(model, q)[0].ee
    if position_only:
        tp, cost = targets, 0.0
    else:
        tp = targets[..., :3, 3]
        trace = sum(rg.mul(ee.R[i][j], targets[..., i, j]) for i in range(3) for j in range(3))
        cost = ROT_WEIGHT**2 * (3.0 - trace)
    cost = cost + sum((ee.p[i] - tp[..., i]) ** 2 for i in range(3))
    best = jnp.argmin(cost, axis=0)
    return jnp.take_along_axis(q, best[None, ..., None], axis=0)[0]


def _start(problem: Problem, q: jax.Array, aux, pos_tol: float, rot_tol: float) -> _Seeds:
    """Seeds at ``q`` ``(dof, P)``, evaluated (one forward pass)."""
    ev = evaluate(problem, q)
    zeros = jnp.zeros(q.shape[1:], bool)
    return _Seeds(q, ev, aux, _succeeded(ev, pos_tol, rot_tol), zeros, jnp.zeros(q.shape[1:], jnp.int32))


def _succeeded(ev: Eval, pos_tol: float, rot_tol: float) -> jax.Array:
    return (ev.pos_err <= pos_tol) & (ev.rot_err <= rot_tol)


def _run(problem: Problem, seeds: _Seeds, step_fn, *, num_targets: int, has_q0: bool, max_iters: int,
         pos_tol: float, rot_tol: float) -> _Seeds:
    """Iterate every seed until its target is done or ``max_iters``; finished targets are frozen.

    A target is done once one of its seeds succeeded (with a warm start: once the ``q0`` seed,
    seed 0, also succeeded or stalled), or all its seeds stalled. Seeds of done targets and
    successful seeds no longer move, so each target's result does not depend on the others in
    the batch; the loop exits as soon as every target is done.
    """
    def active(s: _Seeds):
        success = s.success.reshape(-1, num_targets)
        finished = success | s.stalled.reshape(-1, num_targets)
        done = jnp.any(success, axis=0) & (finished[0] if has_q0 else True)
        done = done | jnp.all(finished, axis=0)
        return (~done[None] & ~finished).reshape(-1)

    def body(carry):
        i, s = carry
        move = active(s)
        q_new, ev_new, aux_new, accept, stalled = step_fn(problem, s.q, s.ev, s.aux)
        take = move & accept
        new = _Seeds(
            q=_where(take, q_new, s.q),
            ev=_where(take, ev_new, s.ev),
            aux=_where(move, aux_new, s.aux),
            success=s.success | (take & _succeeded(ev_new, pos_tol, rot_tol)),
            stalled=s.stalled | (move & stalled),
            iters=s.iters + move.astype(jnp.int32),
        )
        return i + 1, new

    def cond(carry):
        i, s = carry
        return (i < max_iters) & jnp.any(active(s))

    return jax.lax.while_loop(cond, body, (jnp.asarray(0), seeds))[1]


def _best(s: _Seeds, num_targets: int, q0) -> _Seeds:
    """The best seed of every target (leaves end with ``(num_targets,)``).

    A successful seed wins, the one nearest ``q0`` when given (else of least residual);
    without a success, the seed of least residual.
    """
    def per_target(x):  # (..., P) -> (..., seeds, targets)
        return x.reshape(x.shape[:-1] + (-1, num_targets))

    success, cost = per_target(s.success), per_target(s.ev.cost)
    rank = cost if q0 is None else jnp.sum((per_target(s.q) - q0.T[:, None, :]) ** 2, axis=0)
    order = jnp.lexsort((jnp.where(success, rank, cost), ~success), axis=0)[:1]  # (1, targets)

    def take(x):
        x = per_target(x)
        return jnp.take_along_axis(x, order.reshape((1,) * (x.ndim - 2) + order.shape), axis=-2)[..., 0, :]

    return jax.tree.map(take, s)


def _check_args(chain, target, q0, num_seeds, method, max_iters, pos_tol, rot_tol, optimizer):
    """Host-side checks; returns the target array and its kind (``True`` for position targets)."""
    if not isinstance(chain, (DHChain, PoEChain)):
        hint = " (for a frame of a whole robot, solve robot.chain(frame_name))" if isinstance(chain, Robot) else ""
        raise TypeError(f"chain: expected a DHChain or PoEChain{hint}, got {type(chain).__name__}")
    if method not in _METHODS:
        raise ValueError(f"method: expected one of {_METHODS}, got {method!r}")
    for name, value, low in (("num_seeds", num_seeds, 1), ("max_iters", max_iters, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
    for name, value in (("pos_tol", pos_tol), ("rot_tol", rot_tol)):
        if isinstance(value, jax.Array) and value.shape == () and not jnp.issubdtype(value.dtype, jnp.complexfloating):
            if not is_concrete(value):
                continue  # a traced tolerance (a jit argument): its value is not known here
            value = value.item()
        if not isinstance(value, (int, float, np.floating, np.integer)) or not value >= 0:
            raise ValueError(f"{name}: expected a non-negative number, got {value!r}")
    if method == "optax":
        _optax_module()  # ImportError with the extra to install, before tracing
    if optimizer is not None:
        if method != "optax":
            raise ValueError(f"optimizer: only used with method='optax', got method={method!r}")
        import optax

        if not isinstance(optimizer, optax.GradientTransformation):
            raise TypeError(f"optimizer: expected an optax.GradientTransformation, got {type(optimizer).__name__}")
    target = real_array(target, "target", "poses or positions")
    if jnp.finfo(target.dtype).bits < 32:
        # float16 rounding (~5e-4 m at 1 m) exceeds the default tolerances: errors would read 0.
        raise TypeError(f"target: expected float32 or float64, got {target.dtype} (cast it to float32)")
    if target.ndim >= 2 and target.shape[-2:] == (4, 4):
        position_only = False
    elif target.ndim >= 1 and target.shape[-1] == 3:
        position_only = True
    else:
        raise ValueError(f"target: expected shape (..., 4, 4) for poses or (..., 3) for positions, got {target.shape}")
    batch = target.shape[:-1] if position_only else target.shape[:-2]
    if not position_only and is_concrete(target):
        bad = ~np.asarray(rigid_poses(target)) & np.all(np.isfinite(np.asarray(target)), axis=(-2, -1))
        if np.any(bad):  # non-finite targets are not errors: they fail (success=False)
            i = tuple(int(k) for k in np.argwhere(bad)[0])
            raise ValueError(f"target[{', '.join(map(str, i))}]: expected a rigid transform (R^T R = I, det R = +1, "
                             f"last row [0, 0, 0, 1], within {rigid_tol(target.dtype):g}), "
                             f"got {np.asarray(target)[i].tolist()}")
    if q0 is not None:
        q0_shape = np.shape(q0)
        if len(q0_shape) == 0 or q0_shape[-1] != chain.dof:
            raise ValueError(f"q0: expected shape (..., {chain.dof}) for a {chain.dof}-joint chain, got {q0_shape}")
        try:
            fits = np.broadcast_shapes(q0_shape[:-1], batch) == batch
        except ValueError:
            fits = False
        if not fits:
            raise ValueError(f"q0: batch shape {q0_shape[:-1]} does not broadcast to the targets' {batch}")
    return target, position_only, batch


def solve(chain, target, *, key=None, q0=None, num_seeds: int = 32, method: str = "lm", max_iters: int | None = None,
          pos_tol: float = 1e-5, rot_tol: float = 1e-4, respect_limits: bool = True, optimizer=None) -> IKResult:
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

    Args:
        chain: a :class:`~diffkin.DHChain` or :class:`~diffkin.PoEChain`.
        target: ``(..., 4, 4)`` end-effector poses ``T_base_ee`` or ``(..., 3)`` positions in the
            base frame (metres; orientation free). The solver runs in this dtype (float32 default).
        key: PRNG key for the seeds; default ``jax.random.key(0)``. Target ``b`` of the flattened
            batch draws round ``r``'s seeds from ``fold_in(fold_in(key, b), r)``.
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
    max_iters = _DEFAULT_ITERS[method] if max_iters is None and method in _METHODS else max_iters
    target, position_only, batch = _check_args(
        chain, target, q0, num_seeds, method, max_iters, pos_tol, rot_tol, optimizer)
    if 0 in batch:  # no targets: empty results of the batch's shape
        empty = lambda *shape, dtype=target.dtype: jnp.zeros(batch + shape, dtype)  # noqa: E731
        return IKResult(empty(chain.dof), empty(dtype=bool), empty(), empty(), empty(dtype=jnp.int32))
    known, traced = _split_chain(chain)
    return _solve(known, traced, target, jax.random.key(0) if key is None else key,
                  None if q0 is None else jnp.asarray(q0), jnp.asarray(pos_tol, target.dtype),
                  jnp.asarray(rot_tol, target.dtype), num_seeds=int(num_seeds), method=method,
                  max_iters=int(max_iters), respect_limits=bool(respect_limits), optimizer=optimizer,
                  position_only=position_only, batch=tuple(batch))


class _KnownLeaves:
    """The concrete leaves of a chain (and its structure), hashed and compared by value.

    It is a static argument of the jitted :func:`_solve`: equal chains (by structure and
    numbers) share one compilation, and their numbers stay trace-time constants that the
    forward pass folds (as for a chain closed over by ``jit``).
    """

    def __init__(self, treedef, leaves: tuple):
        self.treedef, self.leaves = treedef, leaves
        self._key = (treedef, tuple(None if x is None else (np.asarray(x).dtype.str, np.shape(x),
                                                           bool(getattr(x, "weak_type", False)),
                                                           np.asarray(x).tobytes()) for x in leaves))
        self._hash = hash(self._key)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return isinstance(other, _KnownLeaves) and self._key == other._key


def _split_chain(chain) -> tuple[_KnownLeaves, tuple]:
    """``(concrete leaves, traced leaves)`` of ``chain``, each with ``None`` in the other's slots."""
    leaves, treedef = jax.tree_util.tree_flatten(chain)
    known = tuple(x if is_concrete(x) else None for x in leaves)
    traced = tuple(None if is_concrete(x) else x for x in leaves)
    return _KnownLeaves(treedef, known), traced


def _optax_module():
    """``diffkin.ik._optax`` (which needs optax), or an ImportError naming the extra to install."""
    try:
        return importlib.import_module("diffkin.ik._optax")
    except ImportError as e:
        raise ImportError("method='optax' needs optax: pip install 'diffkin[ik]' (or pip install optax)") from e


@functools.partial(jax.jit, static_argnames=("known", "num_seeds", "method", "max_iters", "respect_limits",
                                             "optimizer", "position_only", "batch"))
def _solve(known: _KnownLeaves, traced: tuple, target, key, q0, pos_tol, rot_tol, *, num_seeds, method, max_iters,
           respect_limits, optimizer, position_only, batch) -> IKResult:
    """The solver, compiled once per chain (by value), shapes and static settings.

    Every closure (loop bodies, rounds) is built here, inside the trace, so that repeated eager
    calls of :func:`solve` hit jit's cache instead of retracing and recompiling.
    """
    chain = jax.tree_util.tree_unflatten(
        known.treedef, [t if k is None else k for k, t in zip(known.leaves, traced, strict=True)])
    dtype = target.dtype
    dof = chain.dof
    n = int(np.prod(batch, dtype=np.int64))
    flat = target.reshape((n,) + target.shape[len(batch):])
    valid = jnp.all(jnp.isfinite(flat.reshape(n, -1)), axis=-1)
    valid = valid if position_only else valid & rigid_poses(flat)  # a non-rigid traced target fails
    safe = jnp.where(valid.reshape((n,) + (1,) * (flat.ndim - 1)), flat, jnp.eye(4, dtype=dtype)[:3, 3]
                     if position_only else jnp.eye(4, dtype=dtype))
    model = _cast(_detach(chain), dtype)
    lower, upper = _inward(_detach(chain.lower), dtype, -1), _inward(_detach(chain.upper), dtype, 1)
    wrap = jnp.asarray([t == "R" for t in chain.joint_types]) & ~jnp.isfinite(lower) & ~jnp.isfinite(upper)
    fixed = _detach(safe)
    q0_flat = None
    if q0 is not None:
        q0_flat = jnp.broadcast_to(jnp.asarray(q0, dtype), batch + (dof,)).reshape(n, dof)
        q0_flat = jnp.where(jnp.isfinite(q0_flat), _detach(q0_flat), 0.0)
    if method == "lm":
        init, step_fn = _lm.init, _lm.step
    else:
        _optax = _optax_module()
        opt = _optax.default_optimizer() if optimizer is None else optimizer
        init, step_fn = functools.partial(_optax.init, opt), functools.partial(_optax.step, opt)

    def run_from(idx, q, live=None, q_first=None) -> _Seeds:
        """Iterate the seeds ``q`` ``(copies, m, dof)`` of the targets ``idx``; the best of each.

        ``live`` marks the targets that are not padding of a chunk; ``q_first`` is a warm start.
        """
        if q_first is not None:
            q = jnp.concatenate([q_first[None], q], axis=0)
        copies, m = q.shape[0], idx.shape[0]
        T = jnp.broadcast_to(fixed[idx], (copies,) + fixed[idx].shape).reshape((copies * m,) + fixed.shape[1:])
        p = tuple(T[:, i] if position_only else T[:, i, 3] for i in range(3))
        R = None if position_only else tuple(tuple(T[:, i, j] for j in range(3)) for i in range(3))
        problem = Problem(model, p, R, lower, upper, wrap, respect_limits)
        q = problem.project(q.reshape(-1, dof).T)
        start = _start(problem, q, init(q), pos_tol, rot_tol)
        if live is not None:  # padding: finished before it starts
            start = start._replace(stalled=~jnp.tile(live, copies))
        seeds = _run(problem, start, step_fn, num_targets=m, has_q0=q_first is not None, max_iters=max_iters,
                     pos_tol=pos_tol, rot_tol=rot_tol)
        return _best(seeds, m, q_first)

    def seeds(idx, round_index, group: int):
        """``group`` seeds per target of round ``round_index`` (per target): ``(group, len(idx), dof)``."""
        q = _seed_configs(key, idx, round_index, lower, upper, _SCREEN * group, dtype)
        return _screened(model, fixed[idx], q.reshape((_SCREEN, group) + q.shape[1:]), position_only)

    first = min(num_seeds, _GROUP)
    best = run_from(jnp.arange(n), seeds(jnp.arange(n), jnp.zeros(n, jnp.int32), first), q_first=q0_flat)
    random_rounds = -(-(num_seeds - first) // _GROUP)
    rounds = 1 + random_rounds + (_POLISH if method == "lm" else 0)
    if rounds > 1:
        chunk = min(n, max(_MIN_CHUNK, -(-n // _CHUNK_DIV)))

        def attempt(idx, round_index, live, best):
            """Round ``round_index`` (per target) for the targets ``idx``: random or polishing seeds."""
            fresh = seeds(idx, round_index, _GROUP)
            near = best.q[:, idx].T
            nearby = jnp.concatenate([near[None], near + _JITTER * (fresh[1:] - near)])
            polishing = round_index > random_rounds
            found = run_from(idx, jnp.where(polishing[:, None], nearby, fresh), live)
            return found._replace(iters=found.iters + jnp.where(polishing, best.iters[idx], 0))

        best = _retry_unsolved(attempt, best, rounds, chunk)
    big = jnp.finfo(dtype).max
    q_best = implicit_q(chain, safe, best.q.T)
    return IKResult(
        q=q_best.reshape(batch + (dof,)),
        success=(best.success & valid).reshape(batch),
        pos_err=jnp.where(valid, best.ev.pos_err, big).reshape(batch),
        rot_err=jnp.where(valid, best.ev.rot_err, big).reshape(batch),
        iters=best.iters.reshape(batch),
    )


def _retry_unsolved(attempt, best: _Seeds, rounds: int, chunk: int) -> _Seeds:
    """Rounds ``1 .. rounds - 1`` for every unsolved target, ``chunk`` targets at a time.

    Each pass takes the first unsolved targets with rounds left, runs
    ``attempt(idx, round_index, live, best)`` on them (each at its own next round) and keeps
    whatever is better per target. A target's result does not depend on the others: its rounds
    are tried in order, from its own keys and its own best so far.
    """
    n = best.success.shape[0]

    def pending(best, done):
        return ~best.success & (done < rounds)

    def body(state):
        best, done = state
        idx = jnp.nonzero(pending(best, done), size=chunk, fill_value=n)[0]
        live = idx < n
        safe_idx = jnp.where(live, idx, 0)
        new = attempt(safe_idx, done[safe_idx], live, best)
        better = live & (new.success | (new.ev.cost < best.ev.cost[safe_idx]))
        best = jax.tree.map(lambda old, x: old.at[..., idx].set(jnp.where(better, x, old[..., safe_idx]), mode="drop"),
                            best, new)
        return best, done.at[idx].add(1, mode="drop")

    return jax.lax.while_loop(lambda state: jnp.any(pending(*state)), body, (best, jnp.ones(n, jnp.int32)))[0]
