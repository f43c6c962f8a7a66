"""IK of a whole robot: several frame targets at once, weights, locked joints, secondary
objectives and a floating base (``dk.ik.solve(robot, {frame: target, ...})``)."""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._checks import real_array
from diffkin._sharding import automatic_axes
from diffkin._xla import solver_jit
from diffkin.ik import _args, _rounds, _secondary
from diffkin.ik._implicit import implicit_tree
from diffkin.ik._prepare import cast, detach, inward, method_steps, valid_targets
from diffkin.ik._result import IKResult
from diffkin.ik._targets import BASE_ROWS, TreeProblem
from diffkin.models.robot import Robot


class Spec(NamedTuple):
    """The static part of a robot's IK problem."""

    frames: tuple[int, ...]
    position_only: tuple[bool, ...]
    weights: tuple[tuple[float, ...], ...]
    locked: tuple[bool, ...]
    secondary: tuple[tuple[str, float], ...]
    solve_base: bool


def _weights(robot: Robot, names: list[str], position_only: list[bool], weights) -> tuple:
    """Per target, 6 weights of ``[v; w]`` (rotation weights of position targets unused)."""
    if weights is None:
        return ((1.0,) * 6,) * len(names)
    if not isinstance(weights, Mapping):
        raise TypeError(f"weights: expected a mapping from target frame names to weights, got {type(weights).__name__}")
    for name in weights:
        if name not in names:
            raise ValueError(f"weights: {name!r} is not one of the targets {names}")
    out = []
    for name, pos_only in zip(names, position_only, strict=True):
        w = np.asarray(weights.get(name, (1.0, 1.0)), dtype=float) if np.ndim(weights.get(name, 0.0)) else None
        if w is None or w.shape not in ((2,), (6,)) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(
                f"weights[{name!r}]: expected 6 non-negative weights of [v; w] or a pair "
                f"(w_pos, w_rot), got {weights[name]!r}"
            )
        w = np.repeat(w, 3) if w.shape == (2,) else w
        if not np.any(w[: 3 if pos_only else 6]):
            raise ValueError(f"weights[{name!r}]: every weight is zero (the target would constrain nothing)")
        out.append(tuple(float(v) for v in w))
    return tuple(out)


def _secondary_spec(secondary, rest) -> tuple[tuple[str, float], ...]:
    """Objectives and weights from ``None``, a name, names, or a mapping name -> weight."""
    if secondary is None:
        secondary = ("rest",) if rest is not None else ()
    if isinstance(secondary, str):
        secondary = (secondary,)
    items = secondary.items() if isinstance(secondary, Mapping) else [(s, 1.0) for s in secondary]
    spec = []
    for name, weight in items:
        if name not in _secondary.OBJECTIVES:
            raise ValueError(f"secondary: expected names from {_secondary.OBJECTIVES}, got {name!r}")
        if not isinstance(weight, (int, float, np.floating, np.integer)) or not np.isfinite(weight) or weight <= 0:
            raise ValueError(f"secondary[{name!r}]: expected a positive weight, got {weight!r}")
        spec.append((name, float(weight)))
    if any(name == "rest" for name, _ in spec) and rest is None:
        raise ValueError("rest: the 'rest' objective needs a rest configuration (rest=...)")
    return tuple(spec)


def _locked(robot: Robot, locked, q0, batch) -> tuple[tuple[bool, ...], jax.Array | None]:
    """Per joint, locked or not, and the locked values ``(..., dof)`` (``None`` if nothing is locked)."""
    if locked is None:
        return (False,) * robot.dof, None
    if isinstance(locked, str) or not isinstance(locked, Mapping | Sequence):
        raise TypeError(f"locked: expected a mapping joint name -> value or a sequence of joint names, got {locked!r}")
    for name in locked:
        if name not in robot.joint_names:
            raise ValueError(f"locked: {name!r} is not an actuated joint; expected one of {list(robot.joint_names)}")
    mask = tuple(name in locked for name in robot.joint_names)
    if isinstance(locked, Mapping):
        values = []
        for name in robot.joint_names:
            if name in locked:
                v = real_array(locked[name], f"locked[{name!r}]", "a joint value")
                _args.check_batched(v, f"locked[{name!r}]", (), batch, "(a value per target, or one)")
                values.append(jnp.broadcast_to(v, batch))
            else:
                values.append(jnp.zeros(batch))
        return mask, jnp.stack(values, axis=-1)
    if q0 is None:
        raise ValueError("locked: a sequence of joint names takes their values from q0; pass q0 (or a mapping)")
    return mask, jnp.broadcast_to(jnp.asarray(q0), batch + (robot.dof,))


def solve(
    robot: Robot,
    targets,
    *,
    weights,
    locked,
    q0,
    rest,
    secondary,
    solve_base,
    base,
    key,
    num_seeds,
    method,
    max_iters,
    pos_tol,
    rot_tol,
    respect_limits,
    optimizer,
) -> IKResult:
    """Host-side checks of a robot's IK, then the compiled solver (see :func:`diffkin.ik.solve`)."""
    _args.check_settings(num_seeds, method, max_iters, pos_tol, rot_tol, optimizer)
    if not isinstance(targets, Mapping) or not targets:
        raise TypeError(f"target: for a Robot, expected a non-empty mapping frame name -> target, got {targets!r}")
    names = list(targets)
    frames = tuple(robot.frame_index(name) for name in names)
    arrays, kinds = [], []
    batch: tuple[int, ...] = ()
    for i, name in enumerate(names):
        array, pos_only, b = _args.check_target(targets[name], f"target[{name!r}]")
        if i and b != batch:
            raise ValueError(f"target[{name!r}]: batch shape {b} differs from target[{names[0]!r}]'s {batch}")
        arrays.append(array)
        kinds.append(pos_only)
        batch = b
    dtype = jnp.result_type(*arrays)
    if q0 is not None:
        _args.check_batched(q0, "q0", (robot.dof,), batch, f"for a {robot.dof}-joint robot")
    if rest is not None:
        _args.check_batched(rest, "rest", (robot.dof,), batch, f"for a {robot.dof}-joint robot")
    if base is not None:
        _args.check_target(base, "base")
        _args.check_batched(base, "base", (4, 4), batch, "(T_world_root)")
    if solve_base and not robot.floating:
        raise ValueError(f"solve_base: robot {robot.name!r} has a fixed root (load it with floating=True)")
    if solve_base and method != "lm":
        raise ValueError(f"solve_base: needs method='lm', got method={method!r}")
    mask, locked_q = _locked(robot, locked, q0, batch)
    if robot.dof == 0 and not solve_base:
        raise ValueError(f"robot: {robot.name!r} has no joints to solve")
    spec = Spec(
        frames,
        tuple(kinds),
        _weights(robot, names, kinds, weights),
        mask,
        _secondary_spec(secondary, rest),
        bool(solve_base),
    )
    if 0 in batch:
        empty = lambda *shape, dt=dtype: jnp.zeros(batch + shape, dt)  # noqa: E731
        return IKResult(
            empty(robot.dof),
            empty(dt=bool),
            empty(len(names)),
            empty(len(names)),
            empty(dt=jnp.int32),
            empty(4, 4) if solve_base else None,
        )
    known, traced = _args.split_model(robot)
    as_dtype = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    return automatic_axes(_solve_tree, arrays[0], len(batch))(
        traced,
        tuple(jnp.asarray(a, dtype) for a in arrays),
        _args.default_key() if key is None else key,
        as_dtype(q0),
        as_dtype(rest),
        as_dtype(base),
        as_dtype(locked_q),
        _args.tolerance(pos_tol, dtype),
        _args.tolerance(rot_tol, dtype),
        known=known,
        spec=spec,
        num_seeds=int(num_seeds),
        method=method,
        max_iters=int(max_iters),
        respect_limits=bool(respect_limits),
        optimizer=optimizer,
        batch=batch,
    )


def _moves(robot: Robot, frames: tuple[int, ...]) -> np.ndarray:
    """``(dof, k)`` bool: whether ``q_i`` drives a joint on the path of frame ``frames[k]``."""
    out = np.zeros((robot.dof, len(frames)), bool)
    for k, f in enumerate(frames):
        for j in robot.ancestors(robot.frame_bodies[f]):
            out[robot.sources[j], k] = True
    return out


def _flat(x, batch, tail, n, dtype, default=None):
    """``x`` broadcast to ``batch + tail`` and flattened to ``(n,) + tail`` (non-finite entries to ``default``)."""
    if x is None:
        return None
    x = jnp.broadcast_to(x, batch + tail).reshape((n,) + tail).astype(dtype)
    return detach(jnp.where(jnp.isfinite(x), x, 0.0 if default is None else default))


@functools.partial(
    solver_jit,
    static_argnames=("known", "spec", "num_seeds", "method", "max_iters", "respect_limits", "optimizer", "batch"),
)
def _solve_tree(
    traced: tuple,
    targets: tuple,
    key,
    q0,
    rest,
    base,
    locked_q,
    pos_tol,
    rot_tol,
    *,
    known: _args.KnownLeaves,
    spec: Spec,
    num_seeds,
    method,
    max_iters,
    respect_limits,
    optimizer,
    batch,
) -> IKResult:
    """The compiled solver of a robot's targets (once per robot by value, spec, shapes and settings)."""
    robot = _args.join(known, traced)
    dtype, dof, k = targets[0].dtype, robot.dof, len(spec.frames)
    n = int(np.prod(batch, dtype=np.int64))
    checked = [
        valid_targets(t.reshape((n,) + t.shape[len(batch) :]), pos)
        for t, pos in zip(targets, spec.position_only, strict=True)
    ]
    valid = jnp.all(jnp.stack([v for v, _ in checked]), axis=0)
    safe = tuple(s for _, s in checked)
    fixed = [detach(s) for s in safe]
    model = cast(detach(robot), dtype)
    lower, upper = inward(detach(robot.lower), dtype, -1), inward(detach(robot.upper), dtype, 1)
    wrap = jnp.asarray([t == "R" for t in robot.actuated_types]) & ~jnp.isfinite(lower) & ~jnp.isfinite(upper)
    q0_flat = _flat(q0, batch, (dof,), n, dtype)
    rest_flat = _flat(rest, batch, (dof,), n, dtype)
    locked_flat = _flat(locked_q, batch, (dof,), n, dtype)
    eye = jnp.eye(4, dtype=dtype)
    base_in = jnp.broadcast_to(eye if base is None else base, batch + (4, 4)).reshape(n, 4, 4)
    base_ok = jnp.all(jnp.isfinite(base_in.reshape(n, -1)), axis=-1)
    base_in = jnp.where(base_ok[:, None, None], base_in, eye)
    base_flat = detach(base_in)
    base_rows = jnp.concatenate([base_flat[:, :3, 3], base_flat[:, :3, :3].reshape(n, 9)], axis=-1)  # (n, 12)
    free = jnp.asarray([not lock for lock in spec.locked])

    def build(idx, copies: int) -> TreeProblem:
        def tile(x):  # (n, ...) -> (copies * m, ...)
            x = x[idx]
            return jnp.broadcast_to(x, (copies,) + x.shape).reshape((copies * idx.shape[0],) + x.shape[1:])

        p, R = [], []
        for T, pos in zip(fixed, spec.position_only, strict=True):
            T = tile(T)
            p.append(tuple(T[:, i] if pos else T[:, i, 3] for i in range(3)))
            R.append(None if pos else tuple(tuple(T[:, i, j] for j in range(3)) for i in range(3)))
        root = rg.IDENTITY if base is None and not spec.solve_base else rg.from_matrix(tile(base_flat))
        locked_values = tile(locked_flat).T if locked_flat is not None else jnp.zeros((dof, 1), dtype)
        return TreeProblem(
            model,
            spec.frames,
            spec.weights,
            tuple(p),
            tuple(R),
            lower,
            upper,
            wrap,
            respect_limits,
            spec.locked,
            locked_values,
            root,
            spec.solve_base,
        )

    moves = _moves(robot, spec.frames)
    still = jnp.asarray(~np.any(moves, axis=1))  # joints that move no target

    def lift(idx, q):  # joint seeds (copies, m, dof) -> states: joints that move nothing at q0, the root at its guess
        if q0_flat is not None:
            q = jnp.where(still, q0_flat[idx], q)
        if not spec.solve_base:
            return q
        return jnp.concatenate([q, jnp.broadcast_to(base_rows[idx], q.shape[:2] + (BASE_ROWS,))], axis=-1)

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
        first = q0_flat if not spec.solve_base else jnp.concatenate([q0_flat, base_rows], axis=-1)
    settings = _rounds.Settings(num_seeds, max_iters, _rounds.POLISH if method == "lm" else 0, pos_tol, rot_tol)
    best = _rounds.search(
        build,
        lift,
        rank,
        key,
        n,
        lower,
        upper,
        first,
        method_steps(method, optimizer),
        settings,
        moves=jnp.asarray(moves) if k > 1 else None,
    )
    x, ev = best.x, best.ev
    if spec.secondary:
        everything = jnp.arange(n)
        x, ev = _secondary.refine(build(everything, 1), x, ev, best.success, h_of(everything), pos_tol, rot_tol)
    big = jnp.finfo(dtype).max
    q = x[:dof].T
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
    q, T_world_root = implicit_tree(robot, spec, safe, q, T_world_root, base_in)
    return IKResult(
        q=q.reshape(batch + (dof,)),
        success=(best.success & valid & base_ok).reshape(batch),
        pos_err=jnp.where(valid, ev.pos_err, big).T.reshape(batch + (k,)),
        rot_err=jnp.where(valid, ev.rot_err, big).T.reshape(batch + (k,)),
        iters=best.iters.reshape(batch),
        base=None if T_world_root is None else T_world_root.reshape(batch + (4, 4)),
    )
