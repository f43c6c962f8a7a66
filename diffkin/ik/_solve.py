"""``solve``: the front door. Checks the arguments on the host, turns them into one problem (a model,
its terms, locked joints, a root), and runs the one compiled solver of every problem.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._checks import instance
from diffkin._sharding import automatic_axes
from diffkin._static import ModelKey, combine, partition
from diffkin._xla import solver_jit
from diffkin.collision._robot import check_geometry
from diffkin.ik import _args, _search, _secondary
from diffkin.ik._implicit import implicit
from diffkin.ik._methods import METHODS
from diffkin.ik._prepare import cast, detach, inward, valid_targets
from diffkin.ik._problem import BASE_ROWS, Kinematics, Problem
from diffkin.ik._result import IKResult
from diffkin.ik._terms import pose, relative
from diffkin.ik._terms.avoid import Avoid, AvoidTerm
from diffkin.ik._terms.com import ComTarget, from_target
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

#: Success margins, in units of the dtype's epsilon: metres (about eight roundings of a position of
#: a metre or two) and radians. float32: 9.5e-7 m and 1.9e-6 rad; float64: ~2e-15 and ~4e-15.
ROUNDING_POS, ROUNDING_ROT = 8.0, 16.0


class Spec(NamedTuple):
    """The static part of a problem: its terms, locked joints, secondary objectives, solved root."""

    terms: tuple
    locked: tuple[bool, ...]
    secondary: tuple[tuple[str, float], ...]
    solve_base: bool
    errors_per_term: bool  # IKResult errors (..., k) (a robot) or (...) (a chain)


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
    relative=None,
    com=None,
    avoid=None,
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
    through the implicit function theorem (``dq = J^+ dr``, see :mod:`diffkin.ik._implicit`), not through
    the iterations; the derivative is that of a successful, non-singular solution off the limits.

    A :class:`~diffkin.Robot` takes a mapping ``{frame_name: target}`` instead, and targets between
    two of its frames (``relative``): every target is solved at once (success means all within
    tolerance), with per-axis ``weights``, ``locked`` joints, secondary objectives and a solved
    floating base (the residual stacks one such residual per target, dense linear algebra above 6
    rows and columns, 30 LM iterations per seed by default).

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
        respect_limits: keep every iterate (and the result) within ``[chain.lower, chain.upper]``;
            locked joints excepted (``locked``).
        optimizer: an ``optax.GradientTransformation`` for ``method="optax"``; default
            ``optax.adam(1e-2)``.
        relative: robots: ``{(a, b): T_a_b}``, the pose ``(..., 4, 4)`` of frame ``b`` in frame ``a``
            (or the position ``(..., 3)`` of ``b``'s origin in ``a``), the batch shape of ``target``
            (which may then be empty): two hands holding one object, a tool held against a part.
            Their errors follow the targets' in ``IKResult.pos_err``/``rot_err``.
        com: robots: ``(..., 3)`` the centre of mass in the world, or ``(..., 2)`` its horizontal
            components only (balance over the feet), the batch shape of ``target`` (which may then
            be empty); its error is ``IKResult.com_err`` and success needs it within ``pos_tol``.
        avoid: robots: a :class:`~diffkin.ik.Avoid` (collision geometry, obstacles, margin): the
            robot's shapes are kept apart from the obstacles and (``self_collision``) from each
            other by one-sided residuals (:mod:`diffkin.ik._terms.avoid`). Those rows are
            deferred (they cost ~30x the pose's): seeds iterate without them and each round's best
            state is checked for clearance; a target whose states are on target but not clear gets
            them in its last random round and its polishing rounds (seeds screened for clearance).
            Success also needs the exact clearance ``>= margin`` (``IKResult.clearance``),
            which a solution may meet without the ``0.01`` m band above it. The implicit derivative
            of ``q`` is that of the targets alone: exact where no distance is within
            ``margin + 0.01`` m of the obstacles.
        weights: robots: ``{frame_name: w}`` (``{(a, b): w}`` for a relative target), ``w`` six
            non-negative weights of the ``[v; w]`` error in the target frame (world axes for a
            position target) or a pair
            ``(w_pos, w_rot)``; a zero frees that axis (errors and success ignore it). Default 1.
        locked: robots: ``{joint_name: value}`` (a number or one per target) or a sequence of
            joint names whose values come from ``q0``; those joints do not move. A locked value
            outside the joint's limits is held there, not clipped (a gripper held open wider than
            its URDF allows), with a ``UserWarning`` naming the joint.
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

    Warns:
        UserWarning: a concrete locked value outside its joint's limits (named; held there).

    Raises:
        ValueError: a bad target shape, ``q0`` of the wrong length or batch, an unknown method,
            ``num_seeds < 1``, ``max_iters < 0``, negative tolerances, ``optimizer`` without
            ``method="optax"``.
        ValueError: also a concrete pose target that is not a rigid transform (within 1e-5 in
            float32, 1e-9 in float64), naming its batch index; traced ones give ``success=False``.
        TypeError: a chain that is not a chain model, an optimizer that is not an optax
            ``GradientTransformation``, a bool, complex or float16 target.
    """
    p = plan(
        chain,
        target,
        q0=q0,
        num_seeds=num_seeds,
        method=method,
        max_iters=max_iters,
        pos_tol=pos_tol,
        rot_tol=rot_tol,
        optimizer=optimizer,
        weights=weights,
        locked=locked,
        rest=rest,
        secondary=secondary,
        solve_base=solve_base,
        base=base,
        relative=relative,
        com=com,
        avoid=avoid,
    )
    spec, arrays, batch, dtype, max_iters, locked_q = p
    if 0 in batch:  # no targets: empty results of the batch's shape
        empty = lambda *shape, dt=dtype: jnp.zeros(batch + shape, dt)  # noqa: E731
        has_com = isinstance(spec.terms[-1], ComTarget)
        errors = (len(spec.terms) - has_com,) if spec.errors_per_term else ()
        return IKResult(
            empty(chain.dof),
            empty(dt=bool),
            empty(*errors),
            empty(*errors),
            empty(dt=jnp.int32),
            empty(4, 4) if solve_base else None,
            empty() if has_com else None,
            empty() if avoid is not None else None,
        )
    static, traced = partition(chain)
    as_dtype = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    return automatic_axes(_solve, arrays[0], len(batch))(
        traced,
        tuple(arrays),
        _args.default_key() if key is None else key,
        as_dtype(q0),
        as_dtype(rest),
        as_dtype(base),
        as_dtype(locked_q),
        avoid,
        _args.tolerance(pos_tol, dtype),
        _args.tolerance(rot_tol, dtype),
        static=static,
        spec=spec,
        num_seeds=int(num_seeds),
        method=method,
        max_iters=int(max_iters),
        respect_limits=bool(respect_limits),
        optimizer=optimizer,
        batch=batch,
    )


class Plan(NamedTuple):
    """A checked call of :func:`solve`: its static problem, target arrays (in term order), batch shape,
    dtype, iterations per seed and locked values (``None``: none, or all from ``q0``)."""

    spec: Spec
    arrays: list
    batch: tuple[int, ...]
    dtype: Any
    max_iters: int
    locked_q: Any


def terms_of(chain, target, relative, weights, com) -> tuple[tuple, list, tuple[int, ...]]:
    """The terms of a call's targets, their arrays and their batch shape (checked on the host)."""
    if isinstance(chain, Robot):
        return _robot_terms(chain, target, relative, weights, com)
    array, position_only, batch = _args.check_target(target)
    return (pose.PoseTarget(None, position_only),), [array], batch


def plan(
    chain,
    target,
    *,
    q0,
    num_seeds,
    method,
    max_iters,
    pos_tol,
    rot_tol,
    optimizer,
    weights,
    locked,
    rest,
    secondary,
    solve_base,
    base,
    relative,
    com,
    avoid=None,
) -> Plan:
    """Check every argument of :func:`solve` on the host (see its Raises) and build its :class:`Plan`."""
    instance(chain, (DHChain, PoEChain, Robot), "chain", "a DHChain, PoEChain or Robot")
    is_robot = isinstance(chain, Robot)
    facts = METHODS.get(method)
    if max_iters is None and facts is not None:
        max_iters = facts.iters_robot if is_robot else facts.iters_chain
    _args.check_settings(num_seeds, method, 0 if max_iters is None else max_iters, pos_tol, rot_tol, optimizer)
    if not is_robot:
        for name, value in (
            ("weights", weights),
            ("locked", locked),
            ("rest", rest),
            ("secondary", secondary),
            ("base", base),
            ("relative", relative),
            ("com", com),
            ("avoid", avoid),
        ):
            if value is not None:
                raise ValueError(f"{name}: only for a Robot (solve dk.load_robot(...) with a mapping of targets)")
        if solve_base:
            raise ValueError("solve_base: only for a floating Robot")
    terms, arrays, batch = terms_of(chain, target, relative, weights, com)
    dtypes = {a.dtype for a in arrays}
    if len(dtypes) > 1:
        raise TypeError(
            "target: every target needs one dtype (the solver and its tolerances follow it), "
            f"got {sorted(map(str, dtypes))}"
        )
    dtype = arrays[0].dtype
    what = f"for a {chain.dof}-joint {'robot' if is_robot else 'chain'}"
    for name, value in (("q0", q0), ("rest", rest)):
        if value is not None:
            _args.check_batched(value, name, (chain.dof,), batch, what)
    if rest is not None:
        _args.finite(rest, "rest", "a finite rest configuration")
    if base is not None:
        _args.check_target(base, "base")
        _args.check_batched(base, "base", (4, 4), batch, "(T_world_root)")
    if solve_base and not chain.floating:
        raise ValueError(f"solve_base: robot {chain.name!r} has a fixed root (load it with floating=True)")
    if solve_base and not METHODS[method].solves_base:
        raise ValueError(f"solve_base: needs method='lm', got method={method!r}")
    mask, locked_q = _args.locked_joints(chain, locked, q0, batch) if is_robot else ((False,) * chain.dof, None)
    if chain.dof == 0 and not solve_base:
        raise ValueError(f"robot: {chain.name!r} has no joints to solve")
    if avoid is not None:
        instance(avoid, Avoid, "avoid", "a dk.ik.Avoid(geom, world, margin)")
        check_geometry(chain, avoid.geom)
    assert max_iters is not None  # (checked by check_settings)
    spec = Spec(terms, mask, _args.secondary_spec(secondary, rest), bool(solve_base), is_robot)
    return Plan(spec, arrays, batch, dtype, max_iters, locked_q)


def _robot_terms(robot: Robot, targets, relative_targets, weights, com) -> tuple[tuple, list, tuple[int, ...]]:
    """The terms of a robot's targets (world, relative, then the centre of mass), their arrays and their
    batch shape."""
    if weights is not None and not isinstance(weights, Mapping):
        raise TypeError(f"weights: expected a mapping from target frame names to weights, got {type(weights).__name__}")
    weights = {} if weights is None else weights
    found: list[tuple[Any, Any, str]] = list(pose.from_mapping(robot, targets, weights))
    if relative_targets is not None:
        found += relative.from_mapping(robot, relative_targets, weights)
    if com is not None:
        found.append((*from_target(robot, com), "'com'"))
    if not found:
        raise TypeError(f"target: for a Robot, expected a non-empty mapping frame name -> target, got {targets!r}")
    keys = set(targets) | set(relative_targets or ())
    for name in weights:
        if name not in keys:
            raise ValueError(f"weights: {name!r} is not one of the targets {list(keys)}")
    batch = None
    for term, array, label in found:
        b = tuple(array.shape[:-1] if term.position_only else array.shape[:-2])
        if batch is not None and b != batch:
            raise ValueError(f"target[{label}]: batch shape {b} differs from target[{found[0][2]}]'s {batch}")
        batch = b
    assert batch is not None
    # Only the weights' ratios matter: scaled so that the largest is 1 (LM's damping floor and stall
    # test are absolute; weights of 1e-5 would otherwise stall every seed).
    scale = max(max(t.weights[: 3 if t.position_only else 6]) for t, _, _ in found)
    terms = tuple(
        t if scale == 1.0 else dataclasses.replace(t, weights=tuple(w / scale for w in t.weights)) for t, _, _ in found
    )
    return terms, [a for _, a, _ in found], batch


def _moves(model, terms: tuple) -> np.ndarray:
    """``(dof, k)`` bool: whether ``q_i`` drives a joint that moves a frame of term ``k``."""
    out = np.zeros((model.dof, len(terms)), bool)
    for k, term in enumerate(terms):
        for f in term.frames:
            if f is None:  # a chain's end effector: every joint
                out[:, k] = True
                continue
            for j in model.ancestors(model.frame_bodies[f]):
                if model.sources[j] < model.dof:
                    out[model.sources[j], k] = True
                else:  # a joint solved from q by a closed loop: any entry may move it
                    out[:, k] = True
    return out


def _flat(x, batch, tail, n, dtype):
    """``x`` broadcast to ``batch + tail``, flattened to ``(n,) + tail``, detached, non-finite entries 0."""
    if x is None:
        return None
    x = jnp.broadcast_to(x, batch + tail).reshape((n,) + tail).astype(dtype)
    return detach(jnp.where(jnp.isfinite(x), x, 0.0))


@functools.partial(
    solver_jit,
    static_argnames=("static", "spec", "num_seeds", "method", "max_iters", "respect_limits", "optimizer", "batch"),
)
def _solve(
    traced: tuple,
    targets: tuple,
    key,
    q0,
    rest,
    base,
    locked_q,
    avoid,
    pos_tol,
    rot_tol,
    *,
    static: ModelKey,
    spec: Spec,
    num_seeds,
    method,
    max_iters,
    respect_limits,
    optimizer,
    batch,
) -> IKResult:
    """The solver, compiled once per model (by value), spec, shapes and settings.

    Every closure (problems, ranks) is built here, inside the trace, so that repeated eager
    calls of :func:`solve` hit jit's cache instead of retracing and recompiling.
    """
    model_in = combine(static, traced)
    dtype, dof, k = targets[0].dtype, model_in.dof, len(spec.terms)
    n = int(np.prod(batch, dtype=np.int64))
    checked = [
        valid_targets(t.reshape((n,) + t.shape[len(batch) :]), term.position_only)
        for t, term in zip(targets, spec.terms, strict=True)
    ]
    valid = checked[0][0] if k == 1 else jnp.all(jnp.stack([v for v, _ in checked]), axis=0)
    safe = tuple(s for _, s in checked)
    fixed = [detach(s) for s in safe]
    model = cast(detach(model_in), dtype)
    lower, upper = inward(detach(model_in.lower), dtype, -1), inward(detach(model_in.upper), dtype, 1)
    wrap = jnp.asarray([t == "R" for t in model_in.actuated_types]) & ~jnp.isfinite(lower) & ~jnp.isfinite(upper)
    q0_flat = _flat(q0, batch, (dof,), n, dtype)
    rest_flat = _flat(rest, batch, (dof,), n, dtype)
    locked_flat = _flat(locked_q, batch, (dof,), n, dtype)
    for given in (rest, None if locked_q is None else jnp.where(jnp.asarray(spec.locked), locked_q, 0.0)):
        if given is not None:  # traced non-finite values (the host rejects concrete ones): no success
            finite = jnp.all(jnp.isfinite(jnp.broadcast_to(given, batch + (dof,)).reshape(n, dof)), axis=-1)
            valid = valid & finite
    base_in, base_ok = None, None
    if base is not None or spec.solve_base:
        eye = jnp.eye(4, dtype=dtype)
        base_in = jnp.broadcast_to(eye if base is None else base, batch + (4, 4)).reshape(n, 4, 4)
        base_ok = jnp.all(jnp.isfinite(base_in.reshape(n, -1)), axis=-1)
        base_in = jnp.where(base_ok[:, None, None], base_in, eye)
    base_flat = None if base_in is None else detach(base_in)
    avoid_term = None if avoid is None else AvoidTerm.of(avoid)
    terms = spec.terms + (() if avoid_term is None else (avoid_term,))  # the targets' terms, then clearance
    avoid_arrays = None if avoid is None else detach(avoid.cast(dtype))
    avoid_bound = () if avoid_arrays is None else (avoid_arrays,)

    def build(idx, copies: int) -> Problem:
        def tile(x):  # (n, ...) -> (copies * m, ...)
            x = x[idx]
            return jnp.broadcast_to(x, (copies,) + x.shape).reshape((copies * idx.shape[0],) + x.shape[1:])

        bound = tuple(term.bind(tile(T)) for term, T in zip(spec.terms, fixed, strict=True)) + avoid_bound
        root = rg.IDENTITY if base_flat is None else rg.from_matrix(tile(base_flat))
        locked_values = tile(locked_flat).T if locked_flat is not None else jnp.zeros((dof, 1), dtype)
        return Problem(
            model,
            terms,
            bound,
            lower,
            upper,
            wrap,
            respect_limits,
            spec.locked,
            locked_values,
            root,
            spec.solve_base,
        )

    moves = _moves(model_in, terms)
    still = ~np.any(moves, axis=1)  # joints that move no target

    if base_flat is not None:  # the root's guess as state rows (n, 12), for a solved root
        base_rows = jnp.concatenate([base_flat[:, :3, 3], base_flat[:, :3, :3].reshape(n, 9)], axis=-1)

    def lift(idx, q):  # joint seeds (copies, m, dof) -> states: joints that move nothing at q0, the root at its guess
        if q0_flat is not None and np.any(still):
            q = jnp.where(jnp.asarray(still), q0_flat[idx], q)
        if not spec.solve_base:
            return q
        return jnp.concatenate([q, jnp.broadcast_to(base_rows[idx], q.shape[:2] + (BASE_ROWS,))], axis=-1)

    free = jnp.asarray([not lock for lock in spec.locked])

    def h_of(idx):
        def h(x):  # x (n_state, ...) -> (h, Newton step)
            r = None if rest_flat is None else rest_flat[idx].T.reshape((dof,) + (1,) * (x.ndim - 2) + (-1,))
            return _secondary.cost_and_step(spec.secondary, x[:dof], r, lower, upper, free)

        return h

    def rank(idx, x):  # among successes: least secondary cost, else nearest the warm start
        if spec.secondary:
            return h_of(idx)(x)[0]
        return None if q0_flat is None else jnp.sum((x[:dof] - q0_flat[idx].T[:, None, :]) ** 2, axis=0)

    first = None
    if q0_flat is not None:
        first = q0_flat if not spec.solve_base else lift(jnp.arange(n), q0_flat[None])[0]
    facts = METHODS[method]
    # Success is decided in the solver's dtype with a margin for its rounding, so that it holds when
    # checked exactly: float32 forward passes (and targets rounded to float32) are off by ~1e-7
    # (3 of 1,000 float32 Talos successes were 1.01e-5 m from their targets in float64).
    eps = float(jnp.finfo(dtype).eps)
    pos_tol = jnp.maximum(pos_tol - ROUNDING_POS * eps, 0.0).astype(dtype)
    rot_tol = jnp.maximum(rot_tol - ROUNDING_ROT * eps, 0.0).astype(dtype)
    settings = _search.Settings(num_seeds, max_iters, facts.polish, pos_tol, rot_tol)
    best = _search.search(
        build,
        lift,
        rank,
        key,
        n,
        lower,
        upper,
        first,
        facts.steps(optimizer),
        settings,
        moves=jnp.asarray(moves) if len(terms) > 1 else None,
    )
    x, ev = best.x, best.ev
    if spec.secondary:
        everything = jnp.arange(n)
        x, ev = _secondary.refine(build(everything, 1), x, ev, best.success, h_of(everything), pos_tol, rot_tol)
    solved_root = base_in if base is not None and not spec.solve_base else None
    x = implicit(spec, cast(model_in, dtype), safe, solved_root, x)
    success = best.success & valid if base_ok is None else best.success & valid & base_ok
    clearance = None
    if avoid_term is not None and avoid_arrays is not None:  # recomputed at the returned states, exactly
        clearance = avoid_term.clearance(Kinematics(build(jnp.arange(n), 1), x), avoid_arrays)
        success = success & (clearance >= avoid_arrays.margin)
    return result(spec, x, ev.pos_err[:k], ev.rot_err[:k], valid, success, best.iters, batch, clearance)


def result(
    spec: Spec, x: jax.Array, pos_err, rot_err, valid, success, iters, batch: tuple[int, ...], clearance=None
) -> IKResult:
    """The :class:`IKResult` of states ``x`` ``(n_state, n)`` with per-term errors ``(k, n)`` (the largest
    float where the targets were not ``valid``), ``success``, ``iters`` and ``clearance`` (or ``None``)
    ``(n,)``, shaped ``batch``."""
    dtype, dof, k = x.dtype, x.shape[0] - (BASE_ROWS if spec.solve_base else 0), len(spec.terms)
    n = x.shape[1]
    big = jnp.finfo(dtype).max
    pos_err, rot_err = (jnp.where(valid, e, big).T for e in (pos_err, rot_err))  # (n, k)
    if not spec.errors_per_term:
        pos_err, rot_err = pos_err[:, 0], rot_err[:, 0]
    T_world_root = None
    if spec.solve_base:
        b = x[dof:].T
        T_world_root = (
            jnp.zeros((n, 4, 4), dtype)
            .at[:, :3, :3]
            .set(b[:, 3:].reshape(n, 3, 3))
            .at[:, :3, 3]
            .set(b[:, :3])
            .at[:, 3, 3]
            .set(1.0)
        )
    com_err = None
    if isinstance(spec.terms[-1], ComTarget):  # the centre of mass: its own field
        com_err, pos_err, rot_err = pos_err[:, -1].reshape(batch), pos_err[:, :-1], rot_err[:, :-1]
        k -= 1
    tail = (k,) if spec.errors_per_term else ()
    return IKResult(
        q=x[:dof].T.reshape(batch + (dof,)),
        success=success.reshape(batch),
        pos_err=pos_err.reshape(batch + tail),
        rot_err=rot_err.reshape(batch + tail),
        iters=iters.reshape(batch),
        base=None if T_world_root is None else T_world_root.reshape(batch + (4, 4)),
        com_err=com_err,
        clearance=None if clearance is None else clearance.reshape(batch),
    )
