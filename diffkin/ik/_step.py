"""``step``: one differential-IK step (velocity IK), a small QP per configuration.

The targets' rows are those of :func:`diffkin.ik.solve` (the terms of :mod:`diffkin.ik._terms`, built
by the same host-side plan and setup): at ``q``, each term's residual ``e`` (metres, and radians
weighted :data:`~diffkin.ik._terms.pose.ROT_WEIGHT`) and its Jacobian ``J = de/d(-q)``. The step is
the joint velocity ``v`` of

    minimise  |J v - gain e / dt|^2 + w_rest^2 |v_free - gain (rest - q)_free / dt|^2 + damping |v|^2
    subject to  lower <= q + v dt <= upper,   |v| <= velocity,   v_locked = 0,
                d_k + dt (dd_k/dq) v >= margin  (each distance ``avoid`` checks, linearised)

solved by :mod:`diffkin.ik._qp`, with ``velocity`` the user's or else the model's (its file's velocity
limits: :attr:`diffkin.Robot.velocity`). When the bounds of a joint contradict each other (``q`` further
outside its limits than ``velocity * dt``), the joint moves back towards its range at its velocity
limit; when the distance rows cannot all hold, the step is that of the rows relaxed by their least
largest violation (:func:`diffkin.ik._qp.least_violation`, rows scaled to unit norm); both give
``feasible=False``. With ``solve_base`` (a floating robot), ``v`` has six more entries, the root's body
twist, without bounds: the columns of the root in the state of :mod:`diffkin.ik._problem`.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._checks import instance, real_array
from diffkin._static import ModelKey, is_concrete, partition
from diffkin._xla import entries_last, solver_jit, summed_products, where_any
from diffkin.ik import _qp
from diffkin.ik._prepare import prepare
from diffkin.ik._problem import Eval, Kinematics, Problem, settle
from diffkin.ik._solve import plan
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

#: Weight of the rest rows (``weights={"rest": w}`` sets it): a posture pull well below the targets'.
REST_WEIGHT = 0.1
#: Metres above ``avoid.margin`` within which a distance is measured exactly and linearised (farther
#: ones are lower bounds that hold: a step must move less than this towards an obstacle).
AVOID_REACH = 0.05


class Step(NamedTuple):
    """One velocity-IK step (a pytree); every field has the batch shape ``...`` of ``q`` and the targets.

    Attributes:
        v: ``(..., dof)`` joint velocities (rad/s, m/s); with ``solve_base``, ``(..., 6 + dof)``: first the
            root's body twist ``[v; w]`` (m/s and rad/s in the root's axes: the columns of
            :func:`diffkin.jacobian`'s ``include_base=True``), then the joints'.
        q: ``(..., dof)`` ``q + v dt``, within ``[lower, upper]`` wherever ``feasible`` (rounding
            clipped away; locked joints held where they are).
        feasible: ``(...,)`` bool: every hard constraint (limits over the step, velocity limits, the
            linearised distances) could be met and is; ``False`` also for non-finite inputs.
        task_err: ``(...,)`` metres: the weighted task error left after the step to first order,
            ``|e - dt J v|`` (radians counting as ``ROT_WEIGHT`` m); ``finfo.max`` for non-finite inputs.
        base: with ``solve_base``, ``(..., 4, 4)`` the root pose after the step, ``base exp(dt [v_root])``
            (``v_root = v[..., :6]``, the root's body twist); else ``None``.
    """

    v: jax.Array
    q: jax.Array
    feasible: jax.Array
    task_err: jax.Array
    base: jax.Array | None = None


def step(
    model,
    q,
    targets,
    *,
    dt,
    gain=1.0,
    weights=None,
    rest=None,
    relative=None,
    com=None,
    locked=None,
    velocity=None,
    avoid=None,
    damping=1e-6,
    base=None,
    solve_base=False,
) -> Step:
    """One differential-IK step: the joint velocity that best moves the targets' errors to zero in
    ``dt / gain``, subject exactly to the joint limits over the step, the velocity limits and, with
    ``avoid``, linearised distance constraints (the module :mod:`diffkin.ik._step`).

    Pure and traceable (``jit``, ``vmap``); batched over the leading axes of ``q`` and the targets
    (broadcast together); float32 or float64 (the targets' dtype). Nothing raises inside ``jit``
    and nothing turns NaN: the damping keeps singular configurations finite.

    Args:
        model: a :class:`~diffkin.DHChain`, :class:`~diffkin.PoEChain` or :class:`~diffkin.Robot`.
        q: ``(..., dof)`` the current joint values (radians, metres).
        targets: as :func:`diffkin.ik.solve`'s ``target``: a chain's ``(..., 4, 4)`` end-effector pose
            or ``(..., 3)`` position; a robot's mapping ``{frame_name: target}`` (world frame).
        dt: seconds, ``> 0``: the step's duration.
        gain: in ``[0, 1]`` usually: the fraction of the error to remove in one step.
        weights: robots: as :func:`diffkin.ik.solve`'s, and ``"rest"``: the rest rows' weight
            (default :data:`REST_WEIGHT`).
        rest: robots: ``(..., dof)`` a rest configuration the free joints are pulled towards.
        relative, com: robots: targets between two frames, the centre of mass (as :func:`diffkin.ik.solve`).
        locked: robots: a sequence of joint names that do not move (``v = 0``).
        velocity: ``()``, ``(dof,)`` or ``(..., dof)`` velocity limits ``|v| <= velocity`` (rad/s,
            m/s; ``inf``: none), in place of the model's; default the model's ``velocity`` (a URDF's
            ``<limit velocity=>``; none for MJCF and for chains built without them). To tighten the
            file's limits rather than replace them, pass ``jnp.minimum(model.velocity, yours)``.
        avoid: robots: a :class:`~diffkin.ik.Avoid`: each distance it checks (within
            :data:`AVOID_REACH` of the margin) keeps ``d + dt (dd/dq) v >= margin``.
        damping: ``> 0``, ``(m/s)^2`` per ``(rad/s)^2``: the cost of ``|v|^2``.
        base: robots: ``(..., 4, 4)`` the root pose ``T_world_root`` (default identity).
        solve_base: floating robots: the root moves too, by a body twist without limits (damped as the
            joints), in ``Step.v`` and ``Step.base``.

    Returns:
        :class:`Step`.

    Raises:
        ValueError: a bad ``q``, ``dt``, ``gain``, ``damping`` or ``velocity`` (named), and every
            error of :func:`diffkin.ik.solve`'s arguments.
        TypeError: a model that is not one, a mapping for ``locked``, non-real arrays.
    """
    instance(model, (DHChain, PoEChain, Robot), "model", "a DHChain, PoEChain or Robot")
    q = real_array(q, "q", "joint values")
    if q.ndim < 1 or q.shape[-1] != model.dof:
        raise ValueError(f"q: expected shape (..., {model.dof}) for a {model.dof}-joint model, got {q.shape}")
    for name, value, strict in (("dt", dt, True), ("gain", gain, False), ("damping", damping, True)):
        _scalar(value, name, 0.0, strict)
    if not isinstance(solve_base, bool):
        raise TypeError(f"solve_base: expected True or False, got {solve_base!r}")
    if isinstance(locked, Mapping):
        raise TypeError("locked: dk.ik.step takes a sequence of joint names (they keep their values: v = 0)")
    if velocity is not None:
        velocity = real_array(velocity, "velocity", "velocity limits")
        if velocity.ndim and velocity.shape[-1] != model.dof:
            raise ValueError(f"velocity: expected shape (), (dof,) or (..., {model.dof}), got {velocity.shape}")
        if is_concrete(velocity) and not np.all(np.asarray(velocity) >= 0):
            raise ValueError("velocity: expected limits >= 0 (inf: none)")
    weights = dict(weights) if isinstance(weights, Mapping) else weights
    rest_weight = REST_WEIGHT
    if isinstance(weights, dict) and "rest" in weights:
        rest_weight = weights.pop("rest")
        _scalar(rest_weight, "weights['rest']", 0.0, False)
    batch = _batch(q.shape[:-1], targets, relative, com)
    targets, relative, com = (_broadcast(x, batch) for x in (targets, relative, com))
    p = plan(
        model,
        targets,
        {"relative": relative, "com": com, "avoid": avoid},
        q0=jnp.broadcast_to(q, batch + (model.dof,)),
        num_seeds=1,
        method="lm",
        max_iters=None,
        pos_tol=0.0,
        rot_tol=0.0,
        optimizer=None,
        weights=weights,
        locked=locked,
        rest=rest,
        secondary=None,
        solve_base=solve_base,
        base=base,
    )
    dtype = p.dtype
    as_dtype = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    static, traced = partition(model)
    return _step(
        traced,
        tuple(p.data),
        as_dtype(q),
        as_dtype(rest),
        as_dtype(base),
        as_dtype(velocity),
        *(jnp.asarray(x, dtype) for x in (dt, gain, damping, rest_weight)),
        static=static,
        spec=p.spec,
        batch=p.batch,
    )


def _model_velocity(model, dtype, n: int):
    """The model's velocity limits, ``(dof, n)`` (a scalar ``inf`` when a concrete model has none: the
    program of no velocity limits)."""
    limit = model.velocity
    if is_concrete(limit) and np.all(np.isposinf(np.asarray(limit))):
        return jnp.inf
    return jnp.broadcast_to(jnp.asarray(limit, dtype)[:, None], (model.dof, n))


def _scalar(value, name: str, low: float, strict: bool) -> None:
    """A real scalar, finite and ``> low`` (``strict``) or ``>= low`` when concrete."""
    if isinstance(value, bool) or np.ndim(value) != 0:
        raise ValueError(f"{name}: expected a number, got {value!r}")
    if not is_concrete(value):
        return
    try:
        x = float(value)
    except TypeError:
        raise TypeError(f"{name}: expected a real number, got {value!r}") from None
    if not np.isfinite(x) or (x <= low if strict else x < low):
        raise ValueError(f"{name}: expected a finite number {'>' if strict else '>='} {low:g}, got {value!r}")


def _shape_of(x) -> tuple[tuple[int, ...], int]:
    """The batch shape of a target (pose ``(..., 4, 4)``, else ``(..., k)``) and its tail's length."""
    shape = np.shape(x)
    tail = 2 if len(shape) >= 2 and shape[-2:] == (4, 4) else 1
    return tuple(shape[: max(len(shape) - tail, 0)]), tail


def _values(x) -> list:
    return [] if x is None else list(x.values()) if isinstance(x, Mapping) else [x]


def _batch(q_batch: tuple[int, ...], *given) -> tuple[int, ...]:
    """The joint batch shape of ``q`` and every target (``targets``, ``relative``, ``com``)."""
    shapes = [q_batch] + [_shape_of(v)[0] for x in given for v in _values(x)]
    try:
        return tuple(np.broadcast_shapes(*shapes))
    except ValueError:
        raise ValueError(f"q: its batch shape {q_batch} and the targets' {shapes[1:]} do not broadcast") from None


def _broadcast(x, batch: tuple[int, ...]):
    """A target (or a mapping of them) broadcast to ``batch`` (left alone if it is not an array: the plan names it)."""
    if x is None:
        return None
    if isinstance(x, Mapping):
        return {k: _broadcast(v, batch) for k, v in x.items()}
    if not hasattr(x, "shape") and not isinstance(x, (list, tuple)):
        return x
    b, tail = _shape_of(x)
    if b == batch:
        return x
    x = jnp.asarray(x)
    return jnp.broadcast_to(x, batch + x.shape[x.ndim - tail :])


@functools.partial(solver_jit, static_argnames=("static", "spec", "batch"))
def _step(
    traced, data, q, rest, base, velocity, dt, gain, damping, rest_weight, *, static: ModelKey, spec, batch
) -> Step:
    """The step, compiled once per model (by value), terms and shapes."""
    s = prepare(static, traced, data, spec, batch, batch, rest=rest, base=base)
    model, dtype, dof = s.model, data[0].dtype, s.model.dof
    n = int(np.prod(batch, dtype=np.int64))
    given = jnp.broadcast_to(q, batch + (dof,)).reshape(n, dof).T  # (dof, P)
    finite_q = jnp.all(jnp.isfinite(given), axis=0)
    x = jnp.where(jnp.isfinite(given), given, 0.0)
    locked = np.asarray(spec.locked)
    targets_only = spec._replace(constraints=())
    root = s.base
    nb = 6 if spec.solve_base else 0  # the root's body twist: unbounded columns after the joints'
    nv = dof + nb
    state = x
    if spec.solve_base:  # the state's root rows: p, then R row by row (diffkin.ik._problem.BASE_ROWS)
        assert root is not None  # (prepare gives the root pose, identity by default, when it is solved)
        state = jnp.concatenate([x, root[:, :3, 3].T, root[:, :3, :3].reshape(n, 9).T])
    problem = targets_only.problem(
        model,
        targets_only.bind(tuple(entries_last(t) for t in s.targets), ()),
        rg.IDENTITY if root is None or spec.solve_base else rg.from_matrix(root),
        None,
        None,
    )
    ev = _rows(problem, state)  # r (m, P), J = de/d(-x) (m, nv, P)
    u = gain * ev.r / dt
    H = summed_products(ev.J[:, :, None], ev.J[:, None, :], axis=0)  # J^T J (nv, nv, P)
    H = H + damping * jnp.eye(nv, dtype=dtype)[:, :, None]
    g = -summed_products(ev.J, u[:, None], axis=0)  # J^T u
    free = jnp.asarray(~locked)[:, None]
    if s.rest is not None:
        w2 = rest_weight**2
        H = H + w2 * jnp.diag(_pad(jnp.where(free[:, 0], 1.0, 0.0).astype(dtype), nb, 0.0))[:, :, None]
        g = g - w2 * _pad(jnp.where(free, gain * (s.rest.T - x) / dt, 0.0), nb, 0.0)

    # The box: position limits over the step and velocity limits; contradictory bounds fix the joint.
    if velocity is None:
        vel = _model_velocity(model, dtype, n)
    else:
        vel = jnp.broadcast_to(velocity, batch + (dof,)).reshape(n, dof).T
    vel = jnp.where(jnp.isnan(vel), 0.0, vel)
    p_lo, p_hi = (s.lower[:, None] - x) / dt, (s.upper[:, None] - x) / dt
    lo, hi = jnp.maximum(p_lo, -vel), jnp.minimum(p_hi, vel)
    conflict = (lo > hi) & free
    fixed = conflict | ~free
    value = jnp.where(conflict, jnp.clip(jnp.clip(0.0, p_lo, p_hi), -vel, vel), 0.0)  # (dof, P)
    value = jnp.broadcast_to(value, (dof, n))
    lo, hi = jnp.where(fixed, -jnp.inf, lo), jnp.where(fixed, jnp.inf, hi)
    lo, hi = jnp.broadcast_to(lo, (dof, n)), jnp.broadcast_to(hi, (dof, n))
    lo, hi, value = _pad(lo, nb, -jnp.inf), _pad(hi, nb, jnp.inf), _pad(value, nb, 0.0)
    fixed_v = _pad(jnp.broadcast_to(fixed, (dof, n)), nb, False)  # (nv, P): the root is never fixed
    # Fixed joints eliminated (when a problem of the batch has one): v_i = value_i exactly.
    H, g = where_any(fixed_v, functools.partial(_eliminate, fixed_v, value), H, g)

    G = jnp.zeros((0, nv, n), dtype)
    h = jnp.zeros((0, n), dtype)
    on = jnp.zeros((0, n), bool)
    if spec.constraints:
        term = spec.constraints[0]
        avoid = s.data[0]
        d, Jd = term.distances(Kinematics(problem, state), avoid, avoid.margin + AVOID_REACH)
        Jd = jnp.where(fixed_v[None], 0.0, Jd)
        h = avoid.margin - d - summed_products(Jd, value[None], axis=1) * dt
        G = Jd * dt
        on = (d < avoid.margin + AVOID_REACH) & jnp.isfinite(d)
        norm = jnp.sqrt(jnp.sum(G**2, axis=1))
        unit = jnp.where(norm > 0, norm, 1.0)
        G, h = G / unit[:, None], jnp.where(on, h / unit, 0.0)
    qp = _qp.QP(H, g, lo, hi, G, h, on)
    rows_ok = jnp.ones((n,), bool)
    if spec.constraints:
        t = _qp.least_violation(qp)
        tol = jnp.sqrt(jnp.finfo(dtype).eps) * (1.0 + jnp.max(jnp.abs(h), axis=0, initial=0.0))
        rows_ok = t <= tol
        slack = jnp.where(rows_ok, 0.0, t + tol)
        qp = qp._replace(h=h - slack)
    v = _qp.solve(qp).v
    v = jnp.where(fixed_v, value, v)
    ok = s.valid & finite_q & jnp.all(jnp.isfinite(v), axis=0)
    if s.base_ok is not None:
        ok = ok & s.base_ok
    v = jnp.where(ok, v, 0.0)
    in_box = ~jnp.any(conflict, axis=0)
    q_new = x + v[:dof] * dt
    q_new = jnp.where(free & in_box, jnp.clip(q_new, s.lower[:, None], s.upper[:, None]), q_new)
    q_new = jnp.where(fixed & ~conflict, x, q_new)  # locked joints exactly where they were
    if spec.constraints:
        violation = jnp.max(jnp.where(on, h - summed_products(G, v[None], axis=1), 0.0), axis=0, initial=0.0)
        rows_ok = rows_ok & (violation <= tol)
    err = jnp.sqrt(jnp.sum((ev.r - dt * summed_products(ev.J, v[None], axis=1)) ** 2, axis=0))
    big = jnp.finfo(dtype).max
    shaped = lambda a, *tail: a.reshape(batch + tail)  # noqa: E731
    moved, v_out = None, v
    if spec.solve_base:  # the root moved by its body twist over the step; v: the twist first (dk.jacobian's order)
        twist = v[dof:] * dt
        T = rg.compose(rg.from_matrix(root), rg.screw_exp(tuple(twist[:3]), tuple(twist[3:]), jnp.ones((), dtype)))
        moved = shaped(rg.to_matrix(T, (n,), dtype), 4, 4)
        v_out = jnp.concatenate([v[dof:], v[:dof]])
    return Step(
        v=shaped(v_out.T, nv),
        q=shaped(jnp.where(finite_q, q_new, given).T, dof),
        feasible=shaped(ok & in_box & rows_ok),
        task_err=shaped(jnp.where(ok, jnp.minimum(err, big), big)),
        base=moved,
    )


def _eliminate(fixed: jax.Array, value: jax.Array, H: jax.Array, g: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The QP ``H`` ``(nv, nv, P)``, ``g`` ``(nv, P)`` with the variables where ``fixed`` ``(nv, P)`` held at ``value``
    ``(nv, P)``: their rows and columns of ``H`` those of the identity, ``g`` theirs ``-value`` and the others' moved
    by ``H_free,fixed value`` (``H`` and ``g`` as they are where nothing is fixed)."""
    g = g + summed_products(jnp.where(fixed[None, :, :], H, 0.0), value[None], axis=1)
    eye = jnp.eye(H.shape[0], dtype=H.dtype)[:, :, None]
    return jnp.where(fixed[:, None, :] | fixed[None, :, :], eye, H), jnp.where(fixed, -value, g)


def _rows(problem: Problem, state: jax.Array) -> Eval:
    """The targets' rows ``r`` ``(m, P)`` and their Jacobian ``J`` ``(m, nv, P)`` at ``state``; the cost and the
    errors are left out (zeros and empty): the step does not read them, and each is a kernel of its own that
    recomputes a pose's rotation log."""
    return settle(problem.residual(state)._replace(cost=0.0, pos_err=[], rot_err=[]))


def _pad(a: jax.Array, rows: int, fill) -> jax.Array:
    """``a`` ``(k, ...)`` with ``rows`` more rows of ``fill`` (the root's columns of the state)."""
    if not rows:
        return a
    return jnp.concatenate([a, jnp.full((rows,) + a.shape[1:], fill, a.dtype)])
