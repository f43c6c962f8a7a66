"""``solve``: the front door. Checks the arguments on the host, turns them into one problem (a model,
its terms, locked joints, a root), and runs the one compiled solver of every problem.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._checks import instance
from diffkin._sharding import automatic_axes
from diffkin._static import ModelKey, partition
from diffkin._xla import solver_jit
from diffkin.ik import _args, _search, _secondary
from diffkin.ik._implicit import implicit, measured
from diffkin.ik._keywords import terms_of
from diffkin.ik._methods import METHODS
from diffkin.ik._prepare import detach, prepare
from diffkin.ik._problem import BASE_ROWS, Kinematics, Problem, Spec
from diffkin.ik._result import IKResult
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

#: Success margins, in units of the dtype's epsilon: metres (about eight roundings of a position of
#: a metre or two) and radians. float32: 9.5e-7 m and 1.9e-6 rad; float64: ~2e-15 and ~4e-15.
ROUNDING_POS, ROUNDING_ROT = 8.0, 16.0


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
            targets use more than the first round. Where a joint moves two targets (a relative
            target; grippers on a torso), an unsolved target gets twice the later random rounds.
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
            deferred (they cost ~30x the pose's): seeds iterate without them (later rounds with 4x
            the seeds) and every seed that reaches the pose is checked for clearance; a target whose
            states are on target but not clear gets as many random rounds again without them, then
            them in its last random round and its polishing rounds, from its clearest state on the
            pose (seeds screened for clearance).
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
        {"relative": relative, "com": com, "avoid": avoid},
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
    )
    spec, data, batch, dtype, max_iters, locked_q = p
    if 0 in batch:  # no targets: empty results of the batch's shape
        return _empty(spec, chain.dof, batch, dtype)
    static, traced = partition(chain)
    as_dtype = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    return automatic_axes(_solve, data[0], len(batch))(
        traced,
        tuple(data),
        _args.default_key() if key is None else key,
        as_dtype(q0),
        as_dtype(rest),
        as_dtype(base),
        as_dtype(locked_q),
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
    """A checked call of :func:`solve`: its static problem, what its terms bind (in term order), the
    targets' batch shape, dtype, iterations per seed and locked values (``None``: none, or all from ``q0``)."""

    spec: Spec
    data: list
    batch: tuple[int, ...]
    dtype: Any
    max_iters: int
    locked_q: Any


def plan(
    chain,
    target,
    given: Mapping[str, Any],
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
) -> Plan:
    """Check every argument of :func:`solve` on the host (see its Raises) and build its :class:`Plan`;
    ``given``: the keywords of :data:`~diffkin.ik._keywords.KEYWORDS` (``{name: value}``, ``None`` for absent)."""
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
            *given.items(),
        ):
            if value is not None:
                raise ValueError(f"{name}: only for a Robot (solve dk.load_robot(...) with a mapping of targets)")
        if solve_base:
            raise ValueError("solve_base: only for a floating Robot")
    terms = terms_of(chain, target, given, weights)
    batch = terms.batch
    dtypes = {a.dtype for a in terms.data[: len(terms.targets)]}
    if len(dtypes) > 1:
        raise TypeError(
            "target: every target needs one dtype (the solver and its tolerances follow it), "
            f"got {sorted(map(str, dtypes))}"
        )
    dtype = terms.data[0].dtype
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
    assert max_iters is not None  # (checked by check_settings)
    secondary_spec = _args.secondary_spec(secondary, rest)
    spec = Spec(terms.targets, terms.constraints, mask, secondary_spec, bool(solve_base), is_robot)
    return Plan(spec, terms.data, batch, dtype, max_iters, locked_q)


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


@functools.partial(
    solver_jit,
    static_argnames=("static", "spec", "num_seeds", "method", "max_iters", "respect_limits", "optimizer", "batch"),
)
def _solve(
    traced: tuple,
    data: tuple,
    key,
    q0,
    rest,
    base,
    locked_q,
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
    s = prepare(static, traced, data, spec, batch, batch, q0=q0, rest=rest, locked_q=locked_q, base=base)
    dtype, dof, k = data[0].dtype, s.model.dof, len(spec.targets)
    n = int(np.prod(batch, dtype=np.int64))
    q0_flat, rest_flat = s.q0, s.rest
    base_flat = None if s.base is None else detach(s.base)
    limits = (s.lower, s.upper, s.wrap, respect_limits)

    def build(idx, copies: int) -> Problem:
        def tile(x):  # (n, ...) -> (copies * m, ...)
            x = x[idx]
            return jnp.broadcast_to(x, (copies,) + x.shape).reshape((copies * idx.shape[0],) + x.shape[1:])

        bound = spec.bind((tile(t) for t in s.targets), tuple(d.tiled(tile) for d in s.data))
        root = rg.IDENTITY if base_flat is None else rg.from_matrix(tile(base_flat))
        locked_values = tile(s.locked_q).T if s.locked_q is not None else jnp.zeros((dof, 1), dtype)
        return spec.problem(s.model, bound, root, locked_values, limits)

    moves = _moves(s.model, spec.terms)
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
            return _secondary.cost_and_step(spec.secondary, x[:dof], r, s.lower, s.upper, free)

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
    everything = jnp.arange(n)

    def finish(best: _search.Best, moving) -> _search.Best:  # the secondary objectives, at the solved states
        x, ev = _secondary.refine(build(everything, 1), best.x, best.ev, moving, h_of(everything), pos_tol, rot_tol)
        return best._replace(x=x, ev=ev)

    best, value = _search.search(
        build,
        lift,
        rank,
        key,
        n,
        s.lower,
        s.upper,
        first,
        facts.steps(optimizer),
        settings,
        moves=moves if len(spec.terms) > 1 else None,
        finish=finish if spec.secondary else None,
    )
    x, ev = best.x, best.ev
    solved_root = s.base if base is not None and not spec.solve_base else None
    x = implicit(spec, s.differentiable, s.safe, solved_root, x)
    success = best.success & s.valid if s.base_ok is None else best.success & s.valid & s.base_ok
    if value is not None:  # measured by the search at x: the derivative of measuring it at x attached
        value = measured(spec, s.model, s.data, base_flat, x, value)
    values, met = constraints_at(spec, build(everything, 1), x, value)
    success = success if met is None else success & met
    return result(spec, x, ev.pos_err[:k], ev.rot_err[:k], s.valid, success, best.iters, batch, values)


def constraints_at(
    spec: Spec, problem: Problem, x: jax.Array, value: jax.Array | None = None
) -> tuple[dict[str, jax.Array], jax.Array | None]:
    """The constraint's value at the returned states ``x`` ``(n_state, P)``, exactly (``{"clearance": (P,)}``,
    empty without a constraint), and ``(P,)`` whether it is met (``None`` without one); ``value``: that
    value where it was measured already (:func:`diffkin.ik._search.search`). ``IKResult`` has one field
    for a constraint's value: one constraint (``avoid``'s) at most."""
    if not spec.constraints:
        return {}, None
    ((constraint, bound),) = zip(spec.constraints, problem.bound[len(spec.targets) :], strict=True)
    if value is None:
        value = constraint.clearance(Kinematics(problem, x), bound)  # measured once: its slack follows from it
    return {"clearance": value}, constraint.slack_of(value, bound) >= 0


def result(
    spec: Spec, x: jax.Array, pos_err, rot_err, valid, success, iters, batch: tuple[int, ...], values: Mapping
) -> IKResult:
    """The :class:`IKResult` of states ``x`` ``(n_state, n)`` with per-target errors ``(k, n)`` (the largest
    float where the targets were not ``valid``), ``success``, ``iters`` and the constraints' ``values``
    (:func:`constraints_at`) ``(n,)``, shaped ``batch``.

    A target's errors are a column of ``pos_err``/``rot_err`` or, with a ``result_field``, that field
    (its position error); :func:`target_errors` reads them back."""
    dtype, dof = x.dtype, x.shape[0] - (BASE_ROWS if spec.solve_base else 0)
    n = x.shape[1]
    big = jnp.finfo(dtype).max
    pos_err, rot_err = (jnp.where(valid, e, big).T for e in (pos_err, rot_err))  # (n, k)
    own = {t.result_field: pos_err[:, i].reshape(batch) for i, t in enumerate(spec.targets) if t.result_field}
    columns = [i for i, t in enumerate(spec.targets) if t.result_field is None]
    if len(columns) < len(spec.targets):
        pos_err, rot_err = pos_err[:, columns], rot_err[:, columns]
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
    tail = (len(columns),) if spec.errors_per_term else ()
    return IKResult(
        q=x[:dof].T.reshape(batch + (dof,)),
        success=success.reshape(batch),
        pos_err=pos_err.reshape(batch + tail),
        rot_err=rot_err.reshape(batch + tail),
        iters=iters.reshape(batch),
        base=None if T_world_root is None else T_world_root.reshape(batch + (4, 4)),
        **own,
        **{name: value.reshape(batch) for name, value in values.items()},
    )


def target_errors(spec: Spec, res, n: int) -> tuple[jax.Array, jax.Array]:
    """The per-target errors ``(k, n)`` (position, rotation) of ``res`` (an :class:`IKResult` of ``n``
    targets, as :func:`result` writes them): a column of ``pos_err``/``rot_err``, or a target's own field
    (its rotation error 0)."""
    pos, rot = res.pos_err.reshape(n, -1), res.rot_err.reshape(n, -1)
    column = iter(range(pos.shape[1]))
    pos_rows, rot_rows = [], []
    for t in spec.targets:
        if t.result_field is None:
            i = next(column)
            pos_rows.append(pos[:, i])
            rot_rows.append(rot[:, i])
        else:
            pos_rows.append(getattr(res, t.result_field).reshape(n))
            rot_rows.append(jnp.zeros((n,), rot.dtype))
    return jnp.stack(pos_rows), jnp.stack(rot_rows)


def _empty(spec: Spec, dof: int, batch: tuple[int, ...], dtype) -> IKResult:
    """The :class:`IKResult` of no targets: every field empty, of the batch's shape."""
    empty = lambda *shape, dt=dtype: jnp.zeros(batch + shape, dt)  # noqa: E731
    columns = sum(t.result_field is None for t in spec.targets)
    errors = (columns,) if spec.errors_per_term else ()
    own = {t.result_field: empty() for t in spec.targets if t.result_field}
    return IKResult(
        empty(dof),
        empty(dt=bool),
        empty(*errors),
        empty(*errors),
        empty(dt=jnp.int32),
        empty(4, 4) if spec.solve_base else None,
        **own,
        **({"clearance": empty()} if spec.constraints else {}),
    )
