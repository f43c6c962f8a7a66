"""The search every IK problem shares: seeds in rounds, the iteration loop, the choice of seed.

Layout, stated once: inside the search every array is flat over ``P = copies x targets``
problems with that axis last. The state ``x`` is ``(n, P)``: the ``dof`` joint values, then (when
a floating base is solved) the 12 entries of the root pose ``[p; R row by row]``. Seeds are drawn
as ``(copies, targets, dof)`` and enter the flat layout in :func:`_run_from` only.

A *problem* (:class:`diffkin.ik._problem.Problem`) provides ``project(x)``, ``retract(x, dx)``,
``evaluate(x) -> Eval``, ``residual(x) -> Entries`` (the same, not yet computed into arrays),
``screen_cost(x)`` and, for terms it may defer (``defers``), ``undeferred()``,
``deferred_measure(x, exact)`` and ``padded(x, ev, met)``. The search builds one with
``build(idx, copies)`` for the targets ``idx``, each repeated ``copies`` times.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._xla import materialize
from diffkin.ik import _uniform
from diffkin.ik._problem import Eval, settle_choosing

GROUP = 4  # seeds per target in a round
# Seeds per target in a later round without the deferred terms: their iterations cost ~1/30 of one
# with them, and every seed that reaches the pose is checked (a narrow clear branch is found by
# many cheap seeds, not by a few expensive ones).
_DEFERRED_GROUP = 4 * GROUP
# Rounds after the first run only for the targets still unsolved, packed into chunks of
# max(n / 32, 8) targets (one compiled loop serves every later round, and small chunks keep its
# iterations cheap).
_CHUNK_DIV, _MIN_CHUNK = 32, 8
# Rounds with the deferred terms (their iterations cost ~30x) take 2 targets at a time: few targets
# need them (most find a clear branch in a random round without them), and a pass costs its whole
# size, padding included (docs/performance.md, "Collision-aware IK").
_WHOLE = 2
_SCREEN = 8  # each random seed is the best (least screening cost) of this many uniform draws
_JITTER = 0.05  # a polishing round's perturbations: each a step of this fraction towards a random seed


def redrawn(moves: jax.Array, reached: jax.Array, own: bool = True) -> jax.Array:
    """``(dof, m)`` the joints a later round's random seeds draw anew; the others keep the best state's values.

    Args:
        moves: ``(dof, k)`` bool, whether joint ``i`` moves target ``k``.
        reached: ``(k, m)`` bool, whether the best state of problem ``m`` reached target ``k``.
        own: ``False``: every joint that moves an unreached target (with deferred terms: the
            clearance, moved by every joint, is not cleared by the joints of its own, such as a
            finger's, alone).

    Per unreached target, the joints that move it and no reached target, or, where there are none,
    every joint that moves it: a joint shared with a reached target is drawn anew only where the
    unreached target has no joint of its own. A two-arm problem with one arm solved searches for
    the other arm only, whether its targets are two world poses or the second hand in the first
    hand's frame (a relative target, which both arms move: the seeds draw the unsolved arm alone).
    Unchanged where nothing is reached: every joint that moves a target.
    """
    drawn = moves[:, :, None]  # (dof, k, m)
    if own:
        on_reached = jnp.any(moves[:, :, None] & reached[None], axis=1)  # (dof, m)
        alone = drawn & ~on_reached[:, None]
        drawn = jnp.where(jnp.any(alone, axis=0, keepdims=True), alone, drawn)
    return jnp.any(drawn & ~reached[None], axis=1)


class Seeds(NamedTuple):
    """Iteration state of every seed (problem axis last)."""

    x: jax.Array  # (n, P) the accepted state
    ev: Eval  # the residual at x
    aux: object  # method state: LM damping or optax state
    x_try: jax.Array  # (n, P) the next trial state
    success: jax.Array  # (P,) bool, sticky
    stalled: jax.Array  # (P,) bool
    iters: jax.Array  # (P,) int32


class Best(NamedTuple):
    """The best seed of every target (leaves end with the target axis).

    ``slack``: the deferred terms' least slack (the clearance less the margin: met where ``>= 0``) at
    ``x`` where ``x`` is on its targets and a round without those terms measured it, ``-inf``
    elsewhere. Without a success, a larger slack is better (a later round starts from the state
    nearest to a solution), then (several targets, none deferred) fewer targets missed, then a smaller
    residual.
    """

    x: jax.Array
    ev: Eval
    success: jax.Array
    iters: jax.Array
    slack: jax.Array


class Settings(NamedTuple):
    """Static settings of a search (and the traced tolerances)."""

    num_seeds: int
    max_iters: int
    polish: int
    pos_tol: jax.Array
    rot_tol: jax.Array


def within_tolerance(ev: Eval, pos_tol, rot_tol) -> jax.Array:
    """Each target within tolerance: shaped as the errors, ``(P,)`` or ``(k, P)``."""
    return (ev.pos_err <= pos_tol) & (ev.rot_err <= rot_tol)


def succeeded(ev: Eval, pos_tol, rot_tol) -> jax.Array:
    """``(P,)`` every target of the problem within tolerance (errors ``(P,)`` or ``(k, P)``)."""
    ok = within_tolerance(ev, pos_tol, rot_tol)
    return jnp.all(ok, axis=tuple(range(ok.ndim - 1)))


def _where(mask, new, old):
    """Per-problem select over a pytree whose leaves all end with the problem axis."""
    return jax.tree.map(lambda a, b: jnp.where(mask, a, b), new, old)


def _seed_configs(key, targets: jax.Array, rounds: jax.Array, lower, upper, count: int, dtype) -> jax.Array:
    """``(count, len(targets), dof)`` uniform within the limits (one turn / one metre if unlimited).

    Target ``b = targets[i]`` draws its seeds of round ``r = rounds[i]`` from a hash of ``(key, b, r)``
    (:mod:`diffkin.ik._uniform`): they depend neither on the batch nor on the pass that tries them.
    """
    lo = jnp.where(jnp.isfinite(lower), lower, -np.pi)
    hi = jnp.where(jnp.isfinite(upper), upper, np.pi)
    return lo + _uniform.uniform(key, targets, rounds, count, lower.shape[0], dtype) * (hi - lo)


def _iterate(
    problem,
    x,
    live,
    method,
    num_targets: int,
    has_first: bool,
    settings: Settings,
    every_seed: bool = False,
    draws=None,
) -> Seeds:
    """Iterate every seed from ``x`` ``(n, P)`` until its target is done or ``max_iters``; finished targets are frozen.

    A target is done once one of its seeds succeeded (with a warm start: once the warm seed,
    seed 0, also succeeded or stalled), or all its seeds stalled; with ``every_seed``, once every
    one of its seeds succeeded or stalled (each is a candidate for a check after). Seeds of done targets and
    successful seeds no longer move, so each target's result does not depend on the others in
    the batch; the loop exits as soon as every target is done. ``live`` ``(P,)`` (or ``None``)
    marks the seeds that are not padding: padding is finished before it starts.

    One loop iteration evaluates the trial state (the first one the starting state, accepted
    as it is), judges it and proposes the next trial: the residual is traced once per loop. The
    trial's Jacobian is kept or dropped inside the kernels that compute it
    (:func:`diffkin.ik._problem.settle_choosing`).

    ``draws`` ``(k, n, P)`` (or ``None``): the seeds are screened in the loop: its first ``k`` iterations
    evaluate ``x`` and then each further draw as the trial state, each seed keeping the one of least
    cost, before the iterations proper (``max_iters`` more; a screening iteration counts in no
    ``iters``). The screening is then the loop's own evaluation, not another traced copy of the
    residual (with the clearance, ~300 kernels: docs/performance.md, "Collision-aware IK").
    """
    screen = 1 if draws is None else draws.shape[0]

    def active(s: Seeds):
        success = s.success.reshape(-1, num_targets)
        finished = success | s.stalled.reshape(-1, num_targets)
        done = jnp.all(finished, axis=0)
        if not every_seed:
            done = done | (jnp.any(success, axis=0) & (finished[0] if has_first else True))
        return (~done[None] & ~finished).reshape(-1)

    def body(carry):
        i, s = carry
        first = i == 0
        screening = first if draws is None else i < screen  # the trial is x or a draw, not a step
        move = materialize([active(s)])[0]  # read by many kernels: computed once

        def choose(cost_try):
            accept, aux, stalled = method.judge(s.ev.cost, cost_try, s.aux)
            if draws is not None:  # a draw is taken where it is lower, the damping kept
                accept = jnp.where(screening, cost_try < s.ev.cost, accept)
            return move & (accept | first), (aux, stalled)

        ev, take, (aux, stalled) = settle_choosing(problem.residual(s.x_try), s.ev, choose)
        x = _where(take, s.x_try, s.x)
        aux = _where(move & ~screening, aux, s.aux)
        x_try, aux = method.propose(problem, x, ev, aux)
        proposed = move
        if draws is not None:  # the next draw while there is one, else the first step from the best
            proposed = move & (i + 1 >= screen)
            x_try = jnp.where(i + 1 < screen, draws[jnp.minimum(i + 1, screen - 1)], x_try)
        new = Seeds(
            x=x,
            ev=ev,
            aux=_where(proposed, aux, s.aux),
            x_try=x_try,
            success=s.success | (take & succeeded(ev, settings.pos_tol, settings.rot_tol)),
            stalled=s.stalled | (move & ~screening & stalled),
            iters=s.iters + (move & ~screening).astype(jnp.int32),
        )
        return i + 1, new

    def cond(carry):
        i, s = carry
        return (i <= settings.max_iters + screen - 1) & jnp.any(active(s))

    shape = x.shape[1:]
    ev = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(problem.evaluate, x))
    start = Seeds(
        x,
        ev,
        method.init(x),
        x,
        jnp.zeros(shape, bool),
        jnp.zeros(shape, bool) if live is None else ~live,
        jnp.zeros(shape, jnp.int32),
    )
    return jax.lax.while_loop(cond, body, (jnp.asarray(0), start))[1]


def _unmeasured(s: Seeds) -> jax.Array:
    """``(P,)`` ``-inf``: the slack of states no round without the deferred terms measured (:class:`Best`)."""
    return jnp.full(s.success.shape, -jnp.inf, s.ev.cost.dtype)


def _best(s: Seeds, num_targets: int, rank, slack=None, on_pose=None, missed=None) -> Best:
    """The best seed of every target (leaves end with ``(num_targets,)``).

    A successful seed wins, the one of least ``rank`` (``(seeds, targets)``, e.g. the distance to
    a warm start) when given, else of least residual; without a success, the seed of least residual,
    or, given the deferred terms' ``slack`` ``(P,)`` at every seed and which seeds are ``on_pose``
    ``(P,)``, the seed on the pose of greatest slack where there is one. Given ``missed(ev)``
    ``(P,)``, the targets a seed has not reached, the seeds without a success that miss the fewest
    compete on residual. Ties go to the first seed.
    """

    def per_target(x):  # (..., P) -> (..., seeds, targets)
        return x.reshape(x.shape[:-1] + (-1, num_targets))

    success, cost = per_target(s.success), per_target(s.ev.cost)
    order_by = cost if rank is None else rank
    best_success = jnp.argmin(jnp.where(success, order_by, jnp.inf), axis=0)
    if missed is not None:
        fewest = per_target(missed(s.ev))
        cost = jnp.where(fewest == jnp.min(fewest, axis=0), cost, jnp.inf)
    fallback = jnp.argmin(cost, axis=0)
    if slack is None:
        slack = _unmeasured(s)
    else:
        clearest = per_target(jnp.where(on_pose, slack, -jnp.inf))
        fallback = jnp.where(jnp.any(clearest > -jnp.inf, axis=0), jnp.argmax(clearest, axis=0), fallback)
    order = jnp.where(jnp.any(success, axis=0), best_success, fallback)[None]  # (1, targets)

    def take(x):
        x = per_target(x)
        return jnp.take_along_axis(x, order.reshape((1,) * (x.ndim - 2) + order.shape), axis=-2)[..., 0, :]

    return jax.tree.map(take, Best(s.x, s.ev, s.success, s.iters, slack))


def search(
    build: Callable,
    lift: Callable,
    rank: Callable,
    key,
    n: int,
    lower,
    upper,
    first,
    method,
    settings: Settings,
    moves=None,
    finish=None,
) -> tuple[Best, jax.Array | None]:
    """Solve ``n`` targets from seeds in rounds: the best seed of each (leaves end with ``(n,)``) and, with
    deferred terms, their value at it, exactly (``(n,)``: :meth:`~diffkin.ik._problem.Problem.deferred_measure`;
    else ``None``).

    Args:
        build: ``build(idx, copies)``: the problem of the targets ``idx`` ``(m,)``, each repeated
            ``copies`` times (``P = copies * m``).
        lift: ``lift(idx, q)``: joint seeds ``(copies, m, dof)`` to states ``(copies, m, n_state)``.
        rank: ``rank(idx, x)``: ``(seeds, m)`` preference among successful seeds ``x``
            ``(n_state, seeds, m)`` (lower wins), or ``None`` for the least residual.
        key: PRNG key of the random seeds.
        lower, upper: ``(dof,)`` limits the seeds are drawn within.
        first: ``(n, n_state)`` warm-start states (seed 0 of the first round), or ``None``.
        method: the iteration (:class:`diffkin.ik._methods.Steps`).
        settings: seeds, iterations, polishing rounds and tolerances.
        moves: ``(dof, k)`` bool (NumPy: static), which joints move which of ``k`` targets
            (several targets), or ``None``. Then (without deferred terms) a target's best state
            without a success is one that misses the fewest targets (then of least residual), and
            the random seeds of later rounds draw anew only the joints :func:`redrawn` names for
            its unreached targets (with deferred terms, every joint that moves one) and keep the
            others (and its root pose if it reached any): a two-arm problem with one arm solved searches for
            the other arm only, also where the second hand's target is in the first hand's frame
            (a least residual alone would prefer a state with both hands near their targets,
            where seeds must restart both arms). Where a joint moves two of the targets, an
            unsolved target gets twice the random rounds (``num_seeds`` counts those of targets
            that share no joint).
        finish: ``finish(best, moving)``: the best states after the rounds, those ``moving`` ``(n,)`` (the
            successes) refined (the secondary objectives), before the deferred terms' final value; or ``None``.
    """
    dtype, dof = lower.dtype, lower.shape[0]

    def on_target(ev: Eval) -> jax.Array:  # (k, P)
        return within_tolerance(ev, settings.pos_tol, settings.rot_tol)

    first_group = min(settings.num_seeds, GROUP)
    random_rounds = -(-(settings.num_seeds - first_group) // GROUP)
    rounds = 1 + random_rounds + settings.polish
    # Deferred terms (the clearance) are left out of the first round, which then costs what the
    # problem without them costs, and of a target's random rounds; a target whose states break them
    # gets them in its last random round and its polishing rounds.
    defer = rounds > 1 and build(jnp.arange(1), 1).defers
    # A target that reached its pose, but only where it breaks the deferred terms, gets as many random
    # rounds again without them before those with them: its pose is reachable, and a narrow clear
    # branch is found by more cheap seeds.
    escalate = random_rounds if defer else 0
    # Several targets without deferred ones: a state that misses fewer targets is the better start.
    several = moves is not None and not defer
    missed = (lambda ev: jnp.sum(~on_target(ev), axis=0)) if several else None
    if several and np.any(np.sum(moves, axis=1) > 1):
        # Targets that share joints (a relative target, which both arms move; a humanoid's grippers on
        # its torso): a seed's steps settle between them, each a few mm off (nearly every unsolved
        # relative problem on Baxter reached neither hand), so fewer seeds reach one and let `redrawn`
        # search for the other alone: a target still unsolved there gets twice the random rounds.
        random_rounds *= 2
        rounds = 1 + random_rounds + settings.polish
    moves = None if moves is None else jnp.asarray(moves)

    def run_from(idx, x, live=None, x_first=None, defer: bool = False, every: bool = False) -> Best:
        """Iterate the states ``x`` ``(copies, m, n_state)`` of the targets ``idx``; the best of each.

        ``x`` may be ``(_SCREEN, copies, m, n_state)``: each seed's draws, screened by the iterations'
        own evaluation (:func:`_iterate`'s ``draws``).
        ``live`` marks the targets that are not padding of a chunk; ``x_first`` is a warm start.
        With ``defer``, the seeds iterate without the problem's deferred terms and the best seed of
        each target is returned unchecked, its evaluation without them (the caller checks it:
        :func:`checked`); with ``every`` too, every seed iterates until it reaches the pose or stalls
        and the deferred terms are checked at every seed: one that holds them succeeds, and without a
        success the seed on the pose that comes nearest to holding them is kept.
        """
        if x_first is not None:
            x = jnp.concatenate([x_first[None], x], axis=0)
        copies, m = x.shape[-3], idx.shape[0]
        problem = build(idx, copies)
        flat = lambda x: problem.project(x.reshape(copies * m, -1).T)  # noqa: E731
        draws = jax.vmap(flat)(x) if x.ndim == 4 else None
        x = flat(x) if draws is None else draws[0]
        live = None if live is None else jnp.tile(live, copies)
        iterated = problem.undeferred() if defer else problem
        first_seed = x_first is not None
        seeds = _iterate(iterated, x, live, method, m, first_seed, settings, every_seed=defer and every, draws=draws)
        per_target = seeds.x.reshape(seeds.x.shape[0], copies, m)
        if not (defer and every):
            return _best(seeds, m, rank(idx, per_target), missed=missed)
        slack = problem.deferred_measure(seeds.x)[1]
        on_pose = seeds.success
        best = _best(seeds._replace(success=on_pose & (slack >= 0)), m, rank(idx, per_target), slack, on_pose)
        return checked(build(idx, 1), best)

    def checked(whole, best: Best) -> Best:
        """``best``, evaluated without the deferred terms and with their ``slack`` measured, as a state of the
        ``whole`` problem (:meth:`~diffkin.ik._problem.Problem.padded`): a success where it also holds them."""
        on_pose, met = succeeded(best.ev, settings.pos_tol, settings.rot_tol), best.slack >= 0
        return best._replace(
            ev=whole.padded(best.x, best.ev, met),
            success=on_pose & met,
            slack=jnp.where(on_pose, best.slack, -jnp.inf),
        )

    def seeds(idx, round_index, group: int, best=None, defer: bool = False, in_loop: bool = False):
        """``group`` random seeds per target, ``(group, len(idx), n_state)``, each the best of ``_SCREEN`` draws.

        With ``best`` (and ``moves``), the joints :func:`redrawn` leaves keep their best values.
        With ``defer``, the draws are screened without the deferred terms; with ``in_loop``, not here:
        every draw is returned, ``(_SCREEN, group, len(idx), n_state)``, for the iterations to screen.
        """
        q = _seed_configs(key, idx, round_index, lower, upper, _SCREEN * group, dtype)
        x = lift(idx, q)
        if best is not None and moves is not None:
            near = best.x[:, idx].T  # (m, n_state)
            reached = on_target(best.ev)[:, idx]
            keep = jnp.concatenate(
                [
                    ~redrawn(moves, reached, own=several).T,
                    jnp.broadcast_to(jnp.any(reached, axis=0)[:, None], (idx.shape[0], x.shape[-1] - dof)),
                ],
                axis=-1,
            )
            x = jnp.where(keep, near, x)
        if in_loop:
            return x.reshape((_SCREEN, group) + x.shape[1:])
        problem = build(idx, _SCREEN * group)
        problem = problem.undeferred() if defer else problem
        cost = problem.screen_cost(problem.project(x.reshape(-1, x.shape[-1]).T)).reshape(_SCREEN, group, -1)
        best = jnp.argmin(cost, axis=0)
        return jnp.take_along_axis(x.reshape((_SCREEN, group) + x.shape[1:]), best[None, ..., None], axis=0)[0]

    first_seeds = seeds(jnp.arange(n), jnp.zeros(n, jnp.int32), first_group, defer=defer)
    best = run_from(jnp.arange(n), first_seeds, x_first=first, defer=defer)
    chunk = min(n, max(_MIN_CHUNK, -(-n // _CHUNK_DIV)))
    if rounds > 1:
        deferring = defer  # the search's (an attempt's own `defer`: whether its round leaves them out)

        def attempt(idx, round_index, live, best, defer: bool = False):
            """Round ``round_index`` (per target) for the targets ``idx``: random or polishing seeds.

            A polishing round goes on from the best state and perturbations of it; where that state
            reached some of several targets (and no term is deferred), the perturbations are the
            random seeds, which keep the joints of the reached targets (a small step rarely leaves
            the local minimum of the others).

            The rounds with the deferred terms screen their random draws in their iterations (their
            residual is the loop's evaluation: one traced copy of the clearance serves both), and
            perturb a polishing round's state towards each seed's first draw."""
            in_loop = deferring and not defer
            fresh = seeds(idx, round_index, _DEFERRED_GROUP if defer else GROUP, best, defer, in_loop)
            drawn = fresh[0] if in_loop else fresh  # (seeds, m, n_state): one per seed
            near = best.x[:, idx].T  # (m, n_state)
            joints = near[:, :dof] + _JITTER * (drawn[1:, :, :dof] - near[:, :dof])
            nearby = jnp.concatenate([joints, jnp.broadcast_to(near[:, dof:], drawn[1:, :, dof:].shape)], axis=-1)
            if several:
                some = jnp.any(on_target(best.ev)[:, idx], axis=0)  # (m,) unsolved: some targets, not all
                nearby = jnp.where(some[:, None], drawn[1:], nearby)
            nearby = jnp.concatenate([near[None], nearby])
            polishing = round_index > random_rounds + _extra_rounds(best.slack[idx], escalate)
            found = run_from(idx, jnp.where(polishing[:, None], nearby, fresh), live, defer=defer, every=defer)
            return found._replace(iters=found.iters + jnp.where(polishing, best.iters[idx], 0))

    def later(best: Best, skip=False) -> Best:
        """The later rounds (none where ``skip``, a traced bool), then ``finish``."""
        if rounds > 1:
            best = _retry_unsolved(
                attempt,
                best,
                rounds,
                chunk,
                defer,
                whole_from=max(1, random_rounds),
                escalate=escalate,
                missed=missed,
                skip=skip,
            )
        return best if finish is None else finish(best, best.success & jnp.logical_not(skip))

    if not defer:
        return later(best), None
    # The deferred terms are measured twice at every target: the first round's check (exact where they
    # are broken) and the final value at the returned state (exact). Both are one loop's evaluation (one
    # traced copy of the clearance, ~300 kernels: docs/performance.md, "Collision-aware IK"); the later
    # rounds run in its first pass.
    whole, first_best = build(jnp.arange(n), 1), best

    def phase(carry):
        i, best, _ = carry
        final = i == 1
        value, slack = whole.deferred_measure(best.x, exact=final)
        best = _where(final, best, checked(whole, first_best._replace(slack=slack)))
        return i + 1, later(best, skip=final), value

    start = checked(whole, first_best._replace(slack=jnp.zeros(n, dtype)))  # (its shapes; phase 0 measures)
    _, best, value = jax.lax.while_loop(lambda c: c[0] < 2, phase, (jnp.asarray(0), start, jnp.zeros(n, dtype)))
    return best, value


def follow(problem, x: jax.Array, method, settings: Settings) -> Best:
    """Iterate one state per problem from ``x`` ``(n_state, P)`` (a warm start, no random seeds)."""
    s = _iterate(problem, problem.project(x), None, method, x.shape[1], False, settings)
    return Best(s.x, s.ev, s.success, s.iters, _unmeasured(s))


def _extra_rounds(slack: jax.Array, escalate: int) -> jax.Array:
    """The rounds a target has beyond the usual: ``escalate`` where its best state reached the pose but broke
    the deferred terms (``slack`` measured, ``> -inf``: :class:`Best`), else 0."""
    return jnp.where(slack > -jnp.inf, escalate, 0)


def _retry_unsolved(
    attempt,
    best: Best,
    rounds: int,
    chunk: int,
    defer: bool = False,
    whole_from: int = 1,
    escalate: int = 0,
    missed=None,
    skip=False,
) -> Best:
    """Rounds ``1 .. rounds - 1`` for every unsolved target, ``chunk`` targets at a time.

    Each pass takes the first unsolved targets with rounds left, runs
    ``attempt(idx, round_index, live, best)`` on them (each at its own next round) and keeps
    whatever is better per target (:class:`Best`; given ``missed(ev)`` ``(P,)``, the number of
    targets a state misses, fewer missed wins over a smaller residual). A target's result does not
    depend on the others: its rounds are tried in order, from its own keys and its own best so far.

    With ``defer``, a target's rounds leave the deferred terms out (``attempt(..., defer=True)``: a
    result that breaks them costs ``inf``); once its best state or a round's result has broken them,
    its rounds from ``whole_from`` on include them (another random round without them often finds a
    clear branch: docs/performance.md, "Collision-aware IK"). The passes without them go first, with
    ``_DEFERRED_GROUP`` seeds per target (so ``chunk * GROUP / _DEFERRED_GROUP`` targets at a time);
    the others take ``_WHOLE`` targets at a time (their iterations cost far more). A target whose
    best state is on its pose but breaks them (its ``slack`` measured, ``> -inf``) has ``escalate``
    more rounds without them before those with them (``rounds + escalate`` in all; ``attempt`` numbers
    its polishing rounds accordingly). ``skip`` (a traced bool): no rounds, ``best`` as it is.
    """
    n = best.success.shape[0]

    def pending(best, done):
        return ~best.success & (done < rounds + _extra_rounds(best.slack, escalate))

    def passes(state, due, size: int, attempt):
        def body(state):
            best, done, broke = state
            idx = jnp.nonzero(due(*state), size=size, fill_value=n)[0]
            live = idx < n
            safe_idx = jnp.where(live, idx, 0)
            new = attempt(safe_idx, done[safe_idx], live, best)
            old_slack = best.slack[safe_idx]
            lower = new.ev.cost < best.ev.cost[safe_idx]
            if missed is not None:  # fewer targets missed first
                new_missed, old_missed = missed(new.ev), missed(best.ev)[safe_idx]
                lower = (new_missed < old_missed) | ((new_missed == old_missed) & lower)
            lower = (new.slack == old_slack) & lower
            better = live & (new.success | (new.slack > old_slack) | lower)
            best = jax.tree.map(
                lambda old, x: old.at[..., idx].set(jnp.where(better, x, old[..., safe_idx]), mode="drop"), best, new
            )
            broke = broke.at[idx].set(broke[safe_idx] | jnp.isinf(new.ev.cost), mode="drop")
            return best, done.at[idx].add(1, mode="drop"), broke

        return jax.lax.while_loop(lambda state: jnp.any(due(*state)), body, state)

    done = jnp.where(skip, rounds + escalate, 1)  # (rounds + escalate: no target has any left)
    state = (best, jnp.full(n, done, jnp.int32), jnp.isinf(best.ev.cost))
    if defer:  # (each of these rounds has _DEFERRED_GROUP seeds per target: a pass as many seeds as another)
        state = passes(
            state,
            lambda b, d, broke: pending(b, d) & (~broke | (d < whole_from + _extra_rounds(b.slack, escalate))),
            max(1, chunk * GROUP // _DEFERRED_GROUP),
            partial(attempt, defer=True),
        )
        chunk = min(chunk, _WHOLE)
    return passes(state, lambda b, d, _: pending(b, d), chunk, attempt)[0]
