"""``dk.traj.optimize``: the front door. Arguments checked on the host, pose goals solved by
collision-aware IK, then one compiled program: seeds, descent, certificate, timing, the best seed."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import positive_int, real_array
from diffkin._static import combine, is_concrete, partition
from diffkin._xla import TRAJ_COMPILE, in_steps, in_threads, problems_at_once, solver_jit, spans
from diffkin.collision.interface import inner
from diffkin.ik import Avoid
from diffkin.ik.interface import cast, check_avoid, check_batched, default_key, detach, finite, target_batch
from diffkin.models.robot import Robot
from diffkin.traj import _limits, _reach, _seeds, _spline
from diffkin.traj._certify import certified
from diffkin.traj._descent import EXTRA, Curves
from diffkin.traj._trajectory import Trajectory

#: joint-space points per segment that measure the path length
_LENGTH_SAMPLES = 16
#: curves per problem timed and certified at a check: the lowest-cost ones (a second one certified solved no more
#: problems, and each costs about as much as a few descent iterations)
CERTIFIED = 1
#: rounds of seeds for a problem without a successful curve, the first included (on the CPU a problem's
#: later rounds cost only where it failed: problems are planned one at a time; a round's keys do not depend on
#: how many there are, so more rounds only add successes)
ROUNDS = 6
#: metres a later round's clearance rows aim beyond the margin (the first's: :data:`diffkin.traj._descent.EXTRA`):
#: its problem's first curves came short of the certificate, most often by a few millimetres
LATER_EXTRA = 0.03
#: descent iterations after which a problem's best curves are certified (and where its descent ends), while none
#: has succeeded: most curves clear the certificate after a few
CHECKS = (4, 12)
#: vertices of each polytope the seeds and the descent measure (:func:`_searched`; the certificate measures all)
SEARCH_VERTICES = 32


def optimize(
    model,
    q_start,
    goal,
    *,
    avoid: Avoid | None = None,
    limits: _limits.Limits | None = None,
    knots: int = 10,
    key=None,
    num_seeds: int = 4,
    max_iters: int = 30,
    pos_tol: float = 1e-5,
    rot_tol: float = 1e-4,
    locked=None,
    base=None,
) -> Trajectory:
    """A smooth motion from ``q_start`` to ``goal`` within limits, clear of obstacles between its knots too.

    The motion is a uniform cubic B-spline in joint space with ``knots`` knots (``knots + 2`` control
    points: the start and the goal three times each, so it starts and stops at rest). Every problem
    runs ``num_seeds`` seeds (the straight line, then curves through via points: with ``avoid``, the
    clearest of 32 random ones, :mod:`diffkin.traj._seeds`) through at most ``max_iters``
    Levenberg-Marquardt iterations on its free control points (smoothness rows and the clearance rows of
    collision-aware IK at 8 samples per segment, pushed through the spline's basis; a curve stops once it
    has converged, and a problem once one of its curves is clear of every row; the seeds and the descent
    measure each convex polytope through at most :data:`SEARCH_VERTICES` of its vertices, the certificate the
    geometry itself: :func:`_searched`). After 4 and 12 iterations (:data:`CHECKS`) and where the descent
    ends, the curve of lowest cost (of those whose samples clear the margin, if any) is timed and certified, and
    the problem stops at its first success (a problem with none gets new seeds through via points, descended to
    :data:`LATER_EXTRA` beyond the margin, up to :data:`ROUNDS` rounds in all; one whose start or goal is
    off the joint limits or within the margin of ``avoid``, where no motion succeeds, only the first):

    - **timing**: the shortest duration for which the spline's velocity, acceleration (and jerk)
      stay within ``limits`` along the whole curve, by exact bounds of its derivatives (the convex
      hull of the control polygon's differences);
    - **clearance**: a certified lower bound over the whole motion (each segment cut into 32 pieces; where
      their bound falls below the margin, the lowest quarter of a curve's cut 4 times finer; on a piece, the
      distances at its middle minus how far the shapes can move within it, from the joint speeds and each
      joint's reach to the shapes it moves: :mod:`diffkin.traj._certify`).

    The first successful curve is kept, else the one with the largest certified clearance. Failures stay
    honest: ``success=False`` with finite values and the reason in ``goal_ok``, ``limits_ok``, ``clear``.
    Problems are independent (a world per
    problem where ``avoid.world`` has problem axes): a problem's motion depends on its own data and its
    place in the batch (its seeds' key) only. On the CPU one compiled loop plans them one after another
    (a batch costs the sum of its problems, not its slowest times their number), called at the top level on
    spans of the batch by one host thread per core, each taking the next span as it comes free; elsewhere all
    at once.
    Compiled once per model, batch shape and static argument; works inside ``jit`` with the model and
    ``avoid.geom`` closed over (the certificate reads them on the host) and the starts, goals and worlds
    traced (batch problems by their leading axes rather than by ``vmap``).

    Args:
        model: a :class:`~diffkin.Robot`, :class:`~diffkin.DHChain` or :class:`~diffkin.PoEChain` of
            revolute and prismatic joints (``avoid`` needs a robot).
        q_start: ``(..., dof)`` the start (radians / metres); its dtype is the solver's.
        goal: a joint goal ``(..., dof)``; or pose targets as :func:`diffkin.ik.solve` takes them,
            ``(..., 4, 4)`` for a chain (read as poses whenever the last two axes are ``(4, 4)``) or a
            mapping ``{frame: (..., 4, 4)}`` for a robot: solved first by :func:`diffkin.ik.solve`
            with ``avoid``, warm-started at ``q_start`` (any branch).
        avoid: :class:`diffkin.ik.Avoid`: the geometry, obstacles (shared, or one world per problem)
            and margin the whole motion keeps; ``None``: no clearance.
        limits: :class:`Limits`; default: the model's ``velocity`` (a URDF's ``<limit velocity>``;
            :data:`diffkin.traj._limits.DEFAULT_VELOCITY`, 1 rad/s, for a joint without one) and
            :data:`~diffkin.traj._limits.DEFAULT_ACCELERATION` (2 rad/s^2) per joint, no jerk bound.
        knots: static, ``K >= 5``: more make the segments shorter (the descent's samples and the certificate's
            pieces closer along the motion), each iteration dearer.
        key: PRNG key of the random seeds (and of a pose goal's IK); default ``jax.random.key(0)``.
        num_seeds: static, ``>= 1`` seeds per problem (the first the straight line).
        max_iters: static, ``>= 0`` iterations per seed.
        pos_tol, rot_tol: metres, radians: a pose goal's tolerance.
        locked: ``{joint name: value}`` joints held at ``value`` through the motion (their start and
            goal entries are replaced by it).
        base: robots: ``(..., 4, 4)`` root pose ``T_world_root`` (default identity).

    Returns:
        A :class:`Trajectory` of the problems' batch shape.

    Raises:
        TypeError, ValueError: bad arguments, named (on the host, before anything is traced).
    """
    dof = _check_model(model)
    q_start = real_array(q_start, "q_start", "joint values")
    if q_start.ndim == 0 or q_start.shape[-1] != dof:
        raise ValueError(f"q_start: expected shape (..., {dof}) joint values, got {q_start.shape}")
    finite(q_start, "q_start", "finite joint values")
    dtype = q_start.dtype
    knots = positive_int(knots, "knots", "an int >= 5")
    if knots < 5:
        raise ValueError(f"knots: expected an int >= 5, got {knots}")
    num_seeds = positive_int(num_seeds, "num_seeds", "an int >= 1")
    if isinstance(max_iters, bool) or not isinstance(max_iters, (int, np.integer)) or max_iters < 0:
        raise ValueError(f"max_iters: expected an int >= 0, got {max_iters!r}")
    if avoid is not None and not isinstance(model, Robot):
        raise TypeError(f"avoid: needs a diffkin.Robot with collision geometry, got a {type(model).__name__}")
    if avoid is not None:
        check_avoid(model, avoid)
    if limits is None:
        limits = _limits.default(model.velocity)
    if not isinstance(limits, _limits.Limits):
        raise TypeError(f"limits: expected a diffkin.traj.Limits or None, got {type(limits).__name__}")
    velocity, acceleration, jerk = limits.per_joint(dof, dtype)
    if base is not None and not isinstance(model, Robot):
        raise TypeError(f"base: only a diffkin.Robot takes a root pose, got a {type(model).__name__}")
    key = default_key() if key is None else key

    pose_goal = isinstance(goal, Mapping) or (jnp.ndim(goal) >= 2 and jnp.shape(goal)[-2:] == (4, 4))
    if pose_goal:
        if isinstance(goal, Mapping) and not isinstance(model, Robot):
            raise TypeError("goal: a mapping {frame: pose} needs a diffkin.Robot; a chain takes (..., 4, 4) poses")
        goal_batch = target_batch(model, goal)  # IK's result's (checked as IK checks it); solved below
        q_goal, goal_ok = jnp.zeros(goal_batch + (dof,), dtype), jnp.zeros(goal_batch, bool)
    else:
        q_goal = real_array(goal, "goal", "joint values (or (..., 4, 4) poses)")
        if q_goal.ndim == 0 or q_goal.shape[-1] != dof:
            raise ValueError(
                f"goal: expected shape (..., {dof}) joint values, (..., 4, 4) poses or a mapping, got {q_goal.shape}"
            )
        finite(q_goal, "goal", "finite joint values")
        q_goal = q_goal.astype(dtype)
        goal_ok = jnp.ones(q_goal.shape[:-1], bool)
    shapes = [q_start.shape[:-1], q_goal.shape[:-1]]
    if avoid is not None and avoid.world is not None:
        shapes.append(avoid.world.batch)
    try:
        batch = tuple(np.broadcast_shapes(*shapes))
    except ValueError:
        raise ValueError(
            f"q_start, goal, avoid.world: batch shapes {shapes} (q_start, goal, world) do not broadcast"
        ) from None
    if base is not None:
        base = real_array(base, "base", "poses")
        check_batched(base, "base", (4, 4), batch, "(T_world_root)")
    mask, locked_q = _locked(model, locked, batch)
    B = int(np.prod(batch, dtype=np.int64))
    flat = lambda x, tail: jnp.broadcast_to(x, batch + tail).reshape((B,) + tail)  # noqa: E731
    avoid_flat = searched_flat = None
    reach = np.zeros((dof, 0))
    if avoid is not None:
        _check_concrete(avoid)
        reach = _reach.reach(model, avoid.geom)
        avoid_flat = avoid.cast(dtype).flat(batch)
        searched_flat = _searched(avoid).cast(dtype).flat(batch)
    static, traced = partition(model)
    q_start_flat = flat(q_start, (dof,))
    base_flat = None if base is None else flat(base.astype(dtype), (4, 4))
    locked_flat = None if locked_q is None else flat(locked_q.astype(dtype), (dof,))
    # on the CPU, spans of the problems planned by one host thread per core (diffkin._xla.in_threads)
    parts = spans(B, q_start, goal, avoid, base)

    def arguments(q_goal_flat, goal_ok_flat, start: int, size: int) -> tuple:  # _solve's, [start, start + size)
        part = lambda x: None if x is None else x[start : start + size]  # noqa: E731
        own = lambda a: None if a is None else a.tiled(part)  # noqa: E731  (a world per problem, or shared)
        return (
            static,
            traced,
            jnp.arange(start, start + size, dtype=jnp.int32),
            part(q_start_flat),
            part(q_goal_flat),
            part(goal_ok_flat),
            own(avoid_flat),
            own(searched_flat),
            part(base_flat),
            part(locked_flat),
            (velocity, acceleration, jerk),
            jnp.asarray(reach, dtype),
            key,
        )

    statics = {"locked": mask, "free": knots - 4, "seeds": num_seeds, "iters": int(max_iters)}
    # one compile serves every span: the motion's program compiles first (with a pose goal, in another thread,
    # from the goal's placeholders, while IK compiles and solves the goal)
    goal_flat = (flat(q_goal, (dof,)), flat(goal_ok, ()))  # (a pose goal's placeholders until IK solves it)
    ahead = None
    if len(parts) > 1 or pose_goal:
        ahead = _solve.compile_ahead(*arguments(*goal_flat, *parts[0]), **statics)
    if pose_goal:
        from diffkin.ik import solve

        res = solve(
            model, goal, key=key, q0=q_start, avoid=avoid, locked=locked, base=base, pos_tol=pos_tol, rot_tol=rot_tol
        )
        goal_flat = (flat(res.q.astype(dtype), (dof,)), flat(res.success, ()))
    if ahead is not None:
        ahead.result()
    out = in_threads(lambda start, size: _solve(*arguments(*goal_flat, start, size), **statics), parts)
    return jax.tree.map(lambda x: x.reshape(batch + x.shape[1:]), out)


def _check_model(model) -> int:
    types = getattr(model, "actuated_types", None)
    if types is None or not hasattr(model, "forward"):
        raise TypeError(f"model: expected a diffkin.Robot, DHChain or PoEChain, got {type(model).__name__}")
    bad = [t for t in types if t not in "RP"]
    if bad:
        raise ValueError(
            f"model: dk.traj moves revolute and prismatic joints only; {model.joint_names[types.index(bad[0])]!r} "
            f"is of type {bad[0]!r}"
        )
    return int(model.dof)


def _check_concrete(avoid: Avoid) -> None:
    leaves = jax.tree.leaves(avoid.geom)
    if not all(is_concrete(x) for x in leaves):
        raise TypeError("avoid.geom: must be concrete (close over it in jit): the certificate reads it on the host")


def _searched(avoid: Avoid) -> Avoid:
    """What the seeds and the descent keep clear: ``avoid`` with each polytope the hull of at most
    :data:`SEARCH_VERTICES` of its vertices (:func:`diffkin.collision._inner.inner`): GJK's support scans every
    vertex, on both sides of a pair, and a mesh's hull has many. Inside the originals, they fall a little short of
    them, which the rows' aim beyond the margin (:data:`diffkin.traj._descent.EXTRA`) covers."""
    return dataclasses.replace(avoid, geom=inner(avoid.geom, SEARCH_VERTICES))


def _locked(model, locked, batch) -> tuple[tuple[bool, ...], jax.Array | None]:
    names = tuple(model.joint_names)
    if locked is None:
        return (False,) * len(names), None
    if not isinstance(locked, Mapping):
        raise TypeError(f"locked: expected a mapping joint name -> value, got {type(locked).__name__}")
    values = []
    for name in locked:
        if name not in names:
            raise ValueError(f"locked: {name!r} is not a joint; expected one of {list(names)}")
    for name in names:
        if name in locked:
            v = real_array(locked[name], f"locked[{name!r}]", "a joint value")
            check_batched(v, f"locked[{name!r}]", (), batch, "(a value per problem, or one)")
            finite(v, f"locked[{name!r}]", "a finite joint value")
            values.append(jnp.broadcast_to(v, batch))
        else:
            values.append(jnp.zeros(batch))
    return tuple(n in locked for n in names), jnp.stack(values, axis=-1)


def _core(
    static,
    traced,
    index,
    q_start,
    q_goal,
    goal_ok,
    avoid,
    searched,
    base,
    locked_q,
    bounds,
    reach,
    key,
    *,
    locked,
    free,
    seeds,
    iters,
):
    model = cast(detach(combine(static, traced)), q_start.dtype)
    dtype = q_start.dtype
    valid = goal_ok & jnp.all(jnp.isfinite(q_start) & jnp.isfinite(q_goal), axis=-1)
    q_start, q_goal = jnp.where(jnp.isfinite(q_start), q_start, 0.0), jnp.where(jnp.isfinite(q_goal), q_goal, 0.0)
    if locked_q is not None:
        held = jnp.asarray(locked)
        q_start, q_goal = jnp.where(held, locked_q, q_start), jnp.where(held, locked_q, q_goal)
    B = q_start.shape[0]
    per_problem = avoid is not None and avoid.world is not None and bool(avoid.world.batch)
    mapped = (index, q_start, q_goal, valid, base, locked_q, avoid.world if per_problem else None)
    leaves, tree = jax.tree.flatten(mapped)
    seed_key = jax.random.fold_in(key, 1)

    def plan(*chunk):
        index, q_start, q_goal, valid, base, locked_q, world = jax.tree.unflatten(tree, chunk)
        own = lambda a: a.replace(world=world) if per_problem else a  # noqa: E731
        keys = jax.vmap(lambda i: jax.random.fold_in(seed_key, i))(index)
        return _plan(
            model,
            q_start,
            q_goal,
            valid,
            own(avoid),
            own(searched),
            base,
            locked_q,
            bounds,
            reach,
            keys,
            locked,
            free,
            seeds,
            iters,
        )

    step = problems_at_once(B)
    if step >= B:
        P, h, clearance, clear, limits_ok = plan(*leaves)
    else:
        P, h, clearance, clear, limits_ok = in_steps(plan, tuple(leaves), step)
    segs = _spline.segments(free + 6)
    u = jnp.asarray(np.arange(segs * _LENGTH_SAMPLES + 1) / _LENGTH_SAMPLES, dtype)
    dense = _spline.evaluate(P[:, None], u)  # (B, Q, dof)
    length = jnp.sum(jnp.linalg.norm(jnp.diff(dense, axis=1), axis=-1), axis=1)
    return Trajectory(
        q=_spline.knots(P),
        t=h[:, None] * jnp.arange(segs + 1, dtype=dtype),
        duration=segs * h,
        success=valid & limits_ok & clear,
        goal_ok=valid,
        limits_ok=limits_ok,
        clear=clear,
        clearance=clearance,
        path_length=length,
        control=P,
        segment_time=h,
    )


def _plan(
    model,
    q_start,
    q_goal,
    valid,
    avoid,
    searched,
    base,
    locked_q,
    bounds,
    reach,
    keys,
    locked,
    free: int,
    seeds: int,
    iters: int,
):
    """``(P (B, N, dof), h (B,), clearance (B,), clear (B,), limits_ok (B,))``: each of ``B`` problems' chosen
    curve (control points), its segment time, certified clearance and checks; ``valid`` ``(B,)`` whether its
    ends are (a goal IK missed, a non-finite start: no more rounds for it); ``keys`` ``(B,)``, one per problem
    (a problem's result does not depend on the others planned with it).

    Up to :data:`ROUNDS` rounds (:func:`_round`), while a problem has no successful curve and could have one (its
    ends within the limits and clear of ``searched``, as its first round measured them; else one round): round
    ``r > 0``
    draws its seeds from ``fold_in(key, r)`` and no straight line (round 0 descended it). A problem keeps its
    first success, else its largest certified clearance (its result does not depend on whether others
    planned with it needed more rounds). ``avoid`` is what the certificate measures, ``searched`` what the
    seeds and the descent do (:func:`_searched`)."""

    def attempt(r):
        round_keys = jax.lax.cond(r == 0, lambda: keys, lambda: jax.vmap(lambda key: jax.random.fold_in(key, r))(keys))
        return _round(
            model,
            q_start,
            q_goal,
            avoid,
            searched,
            base,
            locked_q,
            bounds,
            reach,
            round_keys,
            r == 0,
            locked,
            free,
            seeds,
            iters,
        )

    def more(state):
        r, best, hopeful = state
        return (r == 0) | ((r < ROUNDS) & ~jnp.all(best[-1] | ~hopeful))

    def body(state):
        r, best, hopeful = state
        new, possible = attempt(r)
        hopeful = jnp.where(r == 0, valid & possible, hopeful)
        better = (r == 0) | (hopeful & ~best[-1] & (_score(new) > _score(best)))
        keep = lambda n, b: jnp.where(better.reshape((-1,) + (1,) * (n.ndim - 1)), n, b)  # noqa: E731
        return r + 1, jax.tree.map(keep, new, best), hopeful

    B, dof = q_start.shape
    real, no = jnp.zeros((B,), q_start.dtype), jnp.zeros((B,), bool)
    start = (jnp.zeros((B, free + 6, dof), q_start.dtype), real, real, no, no, real, no)  # (round 0 replaces it)
    _, best, _ = jax.lax.while_loop(more, body, (jnp.int32(0), start, no))
    return best[:5]


def _score(result) -> jax.Array:
    """``(B,)`` the preference among a problem's results (higher wins): a success of shorter duration, else a
    larger certified clearance."""
    _, _, clearance, _, _, duration, ok = result
    return jnp.where(ok, 1e9 - duration, jnp.clip(clearance, -1e6, 1e6))


def _round(
    model,
    q_start,
    q_goal,
    avoid,
    searched,
    base,
    locked_q,
    bounds,
    reach,
    keys,
    first,
    locked,
    free: int,
    seeds: int,
    iters: int,
):
    """One round of :func:`_plan`: ``((P, h, clearance, clear, limits_ok, duration, success), possible)``, each
    problem's best curve of ``seeds`` (the straight line among them where ``first``, a traced bool), descended on
    ``searched`` (aiming :data:`~diffkin.traj._descent.EXTRA` beyond the margin in the first round,
    :data:`LATER_EXTRA` in later ones), its best curve timed and certified on ``avoid`` (:func:`_judged`) after
    :data:`CHECKS` iterations and where its descent ends: a problem stops at its first success (most curves clear
    the certificate after a few iterations; the rest of the descent would only smooth them). A check before the
    end certifies only a problem with a curve whose samples clear the margin (a curve through it fails).
    ``possible`` ``(B,)``: whether the problem's ends lie within the limits and clear ``searched`` by the margin
    (else no motion succeeds: a certified clearance is at most the ends' distances, which ``searched``'s are at
    least)."""
    lower, upper = jnp.asarray(model.lower, q_start.dtype), jnp.asarray(model.upper, q_start.dtype)
    B, dof = q_start.shape
    extra = jnp.where(first, EXTRA, LATER_EXTRA)
    ends = Curves(model, q_start, q_goal, lower, upper, locked, locked_q, searched, base, 1, extra)
    X, ends_clear = _seeds.seeds(ends, seeds, free, keys, first)  # (B, k, free, dof), (B,)
    held = jnp.asarray(locked)
    within = jnp.all(((q_start >= lower) & (q_start <= upper) & (q_goal >= lower) & (q_goal <= upper)) | held, axis=1)
    rep = lambda x: None if x is None else jnp.repeat(x, seeds, axis=0)  # noqa: E731
    curves = Curves(model, rep(q_start), rep(q_goal), lower, upper, locked, rep(locked_q), searched, base, seeds, extra)
    judged = lambda state: _judged(model, curves, state, avoid, bounds, reach, base, locked, lower, upper)  # noqa: E731
    until = jnp.asarray(sorted({min(c, iters) for c in CHECKS} | {iters}), jnp.int32)

    def more(carry):
        c, state, _, done = carry
        return (c == 0) | ((c < until.shape[0]) & ~jnp.all(done) & jnp.any(curves.going(state, rep(done))))

    def body(carry):
        c, state, best, done = carry
        state = curves.descend(state, until[c], rep(done))
        # a problem is judged where its descent has ended (its last check) or, among obstacles, where a curve's
        # samples clear the margin (the certificate of a curve through it would fail)
        ended = ~jnp.any(curves.going(state).reshape(B, seeds), axis=1) | (c == until.shape[0] - 1)
        judge = ~done & ended
        if avoid is not None:
            judge = judge | (~done & jnp.any(state.low.reshape(B, seeds) >= avoid.margin, axis=1))
        new = jax.lax.cond(jnp.any(judge), judged, lambda _: best, state)
        keep = lambda n, b: jnp.where(judge.reshape((-1,) + (1,) * (n.ndim - 1)), n, b)  # noqa: E731
        best = jax.tree.map(keep, new, best)
        return c + 1, state, best, done | best[-1]

    state = curves.start(X.reshape(B * seeds, free, dof))
    real, no = jnp.zeros((B,), q_start.dtype), jnp.zeros((B,), bool)
    start = (jnp.zeros((B, free + 6, dof), q_start.dtype), real, real, no, no, real, no)  # (a check replaces it)
    _, _, best, _ = jax.lax.while_loop(more, body, (jnp.int32(0), state, start, no))
    return best, within & ends_clear


def _judged(model, curves: Curves, state, avoid, bounds, reach, base, locked, lower, upper):
    """``(P, h, clearance, clear, limits_ok, duration, success)`` per problem: of its :data:`CERTIFIED` curves of
    lowest cost in the descent's ``state`` (those whose samples clear the margin first), timed and certified on
    ``avoid``, the best (:func:`_score`)."""
    velocity, acceleration, jerk = bounds
    margin = -jnp.inf if avoid is None else avoid.margin
    C, free, dof = state.X.shape
    seeds = curves.k
    B = C // seeds
    P = curves.control(state.X).reshape(B, seeds, free + 6, dof)
    # only the lowest-cost curves of each problem are timed and certified, those whose samples clear the margin
    # first (the certificate's distances cost about as much as a few descent iterations per curve)
    k = min(seeds, CERTIFIED)
    cost = jnp.where(jnp.isnan(state.cost), jnp.inf, state.cost).reshape(B, seeds)
    through = (state.low < margin).reshape(B, seeds)
    kept = jnp.lexsort((cost, through))[:, :k]
    P = jnp.take_along_axis(P, kept[:, :, None, None], axis=1)  # (B, k, N, dof)
    h = _spline.segment_time(P, velocity, acceleration, jerk)  # (B, k)
    v, a, j = _spline.derivative_bounds(P)
    held = jnp.asarray(locked)  # locked joints may be held beyond their limits (as in IK)
    within = jnp.all(((P >= lower) & (P <= upper)) | held, axis=(-1, -2))
    slow = jnp.all(v <= velocity * h[..., None], axis=-1) & jnp.all(a <= acceleration * h[..., None] ** 2, axis=-1)
    if jerk is not None:
        slow = slow & jnp.all(j <= jerk * h[..., None] ** 3, axis=-1)
    limits_ok = within & slow & jnp.all(jnp.isfinite(P), axis=(-1, -2))
    if avoid is not None:
        clearance, _ = certified(model, avoid, reach, P, base, locked)
        clearance = jnp.where(jnp.isnan(clearance), -jnp.inf, clearance)
        clear = clearance >= avoid.margin
    else:
        clearance = jnp.full((B, k), jnp.inf, P.dtype)
        clear = jnp.ones((B, k), bool)
    duration = _spline.segments(free + 6) * h
    ok = limits_ok & clear
    result = (P, h, clearance, clear, limits_ok, duration, ok)
    best = jnp.argmax(_score(result), axis=1)
    pick = lambda x: jnp.take_along_axis(x, best.reshape((B, 1) + (1,) * (x.ndim - 2)), axis=1)[:, 0]  # noqa: E731
    return tuple(pick(x) for x in result)


_solve = solver_jit(_core, TRAJ_COMPILE, static_argnums=(0,), static_argnames=("locked", "free", "seeds", "iters"))
