"""Closed kinematic loops: joints whose values are solved from ``q`` so that every loop closes.

A loop is a pair of points that must coincide: ``anchor`` in body ``a`` and ``point`` in body ``b``
(MJCF ``<equality><connect>``: the anchor in ``body1``, and where it sits in ``body2`` at the model's
reference configuration, MuJoCo's ``qpos0``). The robot keeps every joint in its tree; the
*dependent* ones are not in ``q``: they are the entries ``dof + d`` of an extended vector
``[q; q_dep]`` (``robot.sources``), and the forward pass first solves ``q_dep(q)``:

- Gauss-Newton steps on the loops' residual ``r = p_a - p_b`` (stacked, ``3 * loops`` rows; a planar
  loop's rows are rank-deficient, so the step is the least-squares one, lightly damped), without
  gradients, while ``q`` moves from the reference configuration to its value in a few stages: the
  solution follows the mechanism's branch (assembly mode) of the reference configuration. An unlimited
  hinge (no limits, every joint it drives revolute by a whole multiple of it) places the bodies by its
  value modulo a turn only: it is first moved by whole turns to within half a turn of the reference, so
  that a crank turned any number of times is followed over at most half a turn, the shorter way round,
  and closes on its branch (a hinge the loops keep from turning fully whose range reaches more than half
  a turn from the reference on one side needs its limits given: a limited joint is followed along the
  straight path inside them);
- then, at ``q`` and the values found, the residual and its Jacobian with gradients, so that the derivatives
  are those of the implicit function: ``dq_dep/dq = -pinv(C_dep) C_q`` (``C`` the residual's Jacobian;
  damped as the steps), carried to autodiff by a step of value 0.

The pass's Jacobian columns then fold each dependent column into the columns of ``q`` through that
``dq_dep/dq``, and autodiff of the pass gets the same. Where a loop cannot close (a ``q`` out of the
mechanism's range) the solve returns its last Gauss-Newton iterate: with a large residual the steps need
not converge (to the least-squares nearest or at all), so the returned values need not be a smooth, or
even continuous, function of ``q``, and no Jacobian is their derivative. The pass's ``loop_gap``
(``dk.loop_closure``, IK's success) says by how much it stays open: measured (:func:`gap`) on the poses
the pass returns. The derivatives there are still ``-pinv(C_dep) C_q`` at those poses (analytic and
autodiff alike): the motion that keeps the loops' residual unchanged to first order, in least squares.

Which joints are dependent (:func:`close`): per robot, among the joints on the loops' paths (from
each body up to their common ancestor) that no actuator drives (directly or through a fixed tendon)
and that follow no other joint: first the joints without stiffness (springs are the mechanism's
passive coordinates), nearest the closure first, alternating the two sides; a joint is taken if it
raises the rank of the loops' Jacobian at the reference configuration, until that rank is the rank
of the loops' Jacobian over every candidate. The others stay in ``q``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._static import ModelKey, combine, host, partition, traced_only
from diffkin._xla import top_level
from diffkin.models import _ball

TURN = 2 * np.pi
STAGES, STEPS_PER_STAGE = 8, 3  # q moved from the reference to its value in 8 stages, 3 Gauss-Newton steps each
DAMPING = 1e-10  # relative to the trace of J^T J: keeps a step finite where the loops leave a joint free
# (a ball joint's spin about a rod's axis): the least-squares step of least norm there


@dataclasses.dataclass(frozen=True)
class Connect:
    """One ``<equality><connect>`` as the loader reads it: ``anchor`` (in frame ``body1``) coincides with the
    point of frame ``body2`` that is there at the reference configuration (``point2 is None``: MuJoCo's
    ``body1``/``body2`` form) or with ``point2`` (in frame ``body2``: the ``site1``/``site2`` form, two sites'
    origins); ``where`` names the element."""

    body1: str
    body2: str
    anchor: np.ndarray
    where: str
    point2: np.ndarray | None = None


def _world(robot, bodies: list[rg.Rigid]) -> list[tuple[rg.Vec3, rg.Vec3]]:
    """Per loop, the world positions of its two points, given every body's world pose ``bodies``."""
    world = []
    for (a, b), (pa, pb) in zip(robot.loop_bodies, _loop_points(robot), strict=True):
        Ta, Tb = bodies[a], bodies[b]
        world.append((rg.vadd(rg.rotate(Ta.R, pa), Ta.p), rg.vadd(rg.rotate(Tb.R, pb), Tb.p)))
    return world


def _points(robot, entries: list):
    """The pass at the extended joint values ``entries`` and the world positions of each loop's two points."""
    kin = robot.tree_pass(entries)
    return kin, _world(robot, kin.bodies)


def _jacobian(robot, kin, world, columns: range) -> list[list]:
    """Rows ``3 * loops`` of entries: ``d (p_a - p_b) / d x_k`` for the extended entries ``columns``."""
    ancestors = {b: set(robot.ancestors(b)) for pair in robot.loop_bodies for b in pair}
    rows: list[list[rg.Entry]] = [[0.0] * len(columns) for _ in range(3 * len(world))]
    index = {k: c for c, k in enumerate(columns)}
    for j, (v, w) in enumerate(kin.screws):
        c = index.get(robot.sources[j])
        if c is None:
            continue
        m = kin.multipliers[j]
        for l_, ((a, b), (pa, pb)) in enumerate(zip(robot.loop_bodies, world, strict=True)):
            for sign, body, p in ((1.0, a, pa), (-1.0, b, pb)):
                if j in ancestors[body]:
                    moved = rg.scale(rg.mul(sign, m), rg.vadd(v, rg.cross(w, p)))
                    for i in range(3):
                        rows[3 * l_ + i][c] = rg.add(rows[3 * l_ + i][c], moved[i])
    return rows


def _array(rows: list[list], shape, dtype) -> jax.Array:
    """``(..., m, n)`` from rows of entries."""
    return jnp.stack([jnp.stack([jnp.broadcast_to(jnp.asarray(e, dtype), shape) for e in row], -1) for row in rows], -2)


def _normal_equations(robot, q: list, dep: jax.Array, shape, dtype):
    """At ``q`` and the dependent values ``dep`` ``(..., nd)``: the pass, the loops' points, the residual ``r``
    ``(..., 3 loops)``, its Jacobian ``J`` ``(..., 3 loops, nd)`` in ``dep`` and the damped ``A = J^T J``."""
    dof, nd = robot.dof, len(robot.dependent_names)
    kin, world = _points(robot, list(q) + [dep[..., d] for d in range(nd)])
    r = _array([[e] for pa, pb in world for e in rg.vadd(pa, rg.scale(-1.0, pb))], shape, dtype)[..., 0]
    J = _array(_jacobian(robot, kin, world, range(dof, dof + nd)), shape, dtype)
    A = jnp.einsum("...ki,...kj->...ij", J, J)
    A = A + (DAMPING * jnp.trace(A, axis1=-2, axis2=-1)[..., None, None] + jnp.finfo(dtype).tiny) * jnp.eye(
        nd, dtype=dtype
    )
    return kin, world, r, J, A


def _least_squares(A: jax.Array, J: jax.Array, r: jax.Array) -> jax.Array:
    """``A^-1 J^T r`` ``(..., nd)``: the damped least-squares step that cancels ``r``."""
    return jnp.linalg.solve(A, jnp.einsum("...ki,...k->...i", J, r)[..., None])[..., 0]


def _step(robot, q: list, dep: jax.Array, shape, dtype) -> jax.Array:
    """One Gauss-Newton step from ``dep`` ``(..., nd)``: the new values."""
    _, _, r, J, A = _normal_equations(robot, q, dep, shape, dtype)
    return dep - _least_squares(A, J, r)


def _distance(g: rg.Vec3) -> jax.Array:
    """``|g|``, NaN-free derivative at 0, and ``inf`` where ``g`` is not finite (a non-finite ``q``: never closed)."""
    sq = jnp.asarray(rg.dot(g, g))
    return jnp.where(jnp.isnan(sq), jnp.inf, rg.norm(g))


def _loop_points(robot) -> list[tuple[rg.Vec3, rg.Vec3]]:
    P = robot.loop_points
    return [(rg.vector(P[k, 0]), rg.vector(P[k, 1])) for k in range(len(robot.loop_bodies))]


def solve(robot, q: list) -> tuple[list, list[list[rg.Entry]]]:
    """The dependent joints' values at ``q`` (``dof`` entries), with the implicit function's derivatives
    ``G[d][i] = d q_dep_d / d q_i`` (entries). How far the loops stay open: :func:`gap`, on the pass at
    ``q`` and these values.

    Called outside any trace (an eager ``dk.fk``), the solve runs compiled, once per model (its
    :class:`~diffkin._static.ModelKey`: equal models share it) and shapes of ``q`` (``_compiled``): run op by
    op, its Gauss-Newton loop was lowered and compiled again at every call. Inside a transformation it is
    traced into the caller's program as it is."""
    if not top_level(robot, q):
        return _solve(robot, q)
    static, traced = partition(robot)
    floats = tuple(e if isinstance(e, float) else None for e in q)  # Python floats fold, as in a trace
    return _compiled(traced, [None if isinstance(e, float) else e for e in q], static=static, floats=floats)


def _solve_keyed(traced: tuple, arrays: list, *, static: ModelKey, floats: tuple) -> tuple[list, list]:
    """:func:`_solve` of the model ``combine(static, traced)`` at ``q``: ``arrays`` where ``floats`` is ``None``."""
    return _solve(combine(static, traced), [a if f is None else f for a, f in zip(arrays, floats, strict=True)])


_compiled = jax.jit(_solve_keyed, static_argnames=("static", "floats"))


def _solve(robot, q: list) -> tuple[list, list[list[rg.Entry]]]:
    """:func:`solve`, traced where it is called."""
    dof, nd = robot.dof, len(robot.dependent_names)
    arrays = [e for e in q if not isinstance(e, float)]
    shape = jnp.broadcast_shapes(*(jnp.shape(e) for e in arrays)) if arrays else ()
    dtype = jnp.result_type(*arrays, robot.loop_points) if arrays else jnp.result_type(robot.loop_points)
    home = jnp.broadcast_to(jnp.asarray(robot.dependent_home, dtype), shape + (nd,))
    frozen = [jax.lax.stop_gradient(e) if not isinstance(e, float) else e for e in q]
    frozen_robot = traced_only(jax.lax.stop_gradient, robot)  # (concrete numbers stay foldable)
    own = {robot.sources[j]: j for j in range(len(robot.sources)) if robot.tree_joints[j] in robot.joint_names}
    ref = [-frozen_robot.offsets[own[i]] for i in range(dof)]  # q at the reference configuration (qpos0)
    goal = [_one_turn(e, r_i, p) for e, r_i, p in zip(frozen, ref, _periodic(robot), strict=True)]

    def stage(k, x):  # Newton steps along q_ref -> goal: the branch of the reference configuration, followed
        t = jnp.minimum((k // STEPS_PER_STAGE + 1) / STAGES, 1.0)
        q_t = [rg.add(r_i, rg.mul(t, rg.add(e, rg.mul(-1.0, r_i)))) for r_i, e in zip(ref, goal, strict=True)]
        return _step(frozen_robot, q_t, x, shape, dtype)

    dep = jax.lax.fori_loop(0, (STAGES + 1) * STEPS_PER_STAGE + 1, stage, home)  # (a last stage at the goal itself)
    dep = jax.lax.stop_gradient(dep)
    # At q and these values, with gradients: a step of value 0 (r - r) whose derivative, -A^-1 J^T dr, is the
    # implicit function's, the same as G's below, whether the loops close or not (a Gauss-Newton step's would
    # add d(A^-1 J^T) r, which is not 0 where they stay open).
    kin, world, r, J_dep, A = _normal_equations(robot, q, dep, shape, dtype)
    dep = dep - _least_squares(A, J_dep, r - jax.lax.stop_gradient(r))
    C_q = _array(_jacobian(robot, kin, world, range(dof)), shape, dtype)
    G = -jnp.linalg.solve(A, jnp.einsum("...ki,...kj->...ij", J_dep, C_q))  # (..., nd, dof)
    return [dep[..., d] for d in range(nd)], [[G[..., d, i] for i in range(dof)] for d in range(nd)]


def gap(robot, kin) -> jax.Array:
    """The largest distance between a loop's two points (metres) in the pass ``kin`` (``Robot.tree_pass`` at
    ``q`` and the solved dependent joints: the poses the caller returns); ``inf`` where one is not finite."""
    gaps = jnp.broadcast_arrays(*(_distance(rg.vadd(pa, rg.scale(-1.0, pb))) for pa, pb in _world(robot, kin.bodies)))
    return jnp.max(jnp.stack(gaps), axis=0)


def _periodic(robot) -> list[bool | jax.Array]:
    """Per entry of ``q``, whether it is an unlimited hinge: no limits, and every joint it drives revolute with a
    whole-number multiplier, so that only its value modulo a turn places the bodies (concrete numbers: a bool)."""
    lower, upper, m = (host(x) for x in (robot.lower, robot.upper, robot.multipliers))
    concrete = all(isinstance(x, np.ndarray) for x in (lower, upper, m))
    xp = np if concrete else jnp
    periodic: list[bool | jax.Array] = []
    for i in range(robot.dof):
        driven = np.asarray([j for j, s in enumerate(robot.sources) if s == i], np.int64)
        if any(robot.joint_types[j] != "R" for j in driven):
            periodic.append(False)
            continue
        whole = xp.all(m[driven] == xp.round(m[driven]))
        unlimited = (lower[i] == -xp.inf) & (upper[i] == xp.inf) & whole
        periodic.append(bool(unlimited) if concrete else unlimited)
    return periodic


def _one_turn(value: rg.Entry, ref: rg.Entry, periodic: bool | jax.Array) -> rg.Entry:
    """``value`` moved by whole turns to within half a turn of ``ref`` where ``periodic`` (see :func:`_periodic`)."""
    if periodic is False:
        return value
    d = rg.add(value, rg.mul(-1.0, ref))
    reduced = rg.add(ref, d - TURN * jnp.round(d / TURN))
    return reduced if periodic is True else jnp.where(periodic, reduced, value)


def close(robot, connects: list[Connect], passive: set[str], stiff: set[str], where: str = "MJCF"):
    """The robot with its loops closed: the dependent joints moved out of ``q`` (see the module docstring).

    Args:
        robot: the tree with every joint in ``q`` (as the loader builds it).
        connects: the loop constraints.
        passive: names of the entries of ``q`` that may become dependent (driven by no actuator).
        stiff: names of the joints with stiffness (taken last).
        where: the description's name, for errors.
    """
    q_ref = -np.asarray(robot.offsets, np.float64)  # MuJoCo's qpos0: every joint angle zero
    q_ref_actuated = np.zeros(robot.dof)
    for j, s in enumerate(robot.sources):
        if robot.tree_joints[j] == robot.joint_names[s]:
            q_ref_actuated[s] = q_ref[j]
    bodies, points = [], []
    kin = robot.tree_pass([jnp.asarray(x) for x in q_ref_actuated])
    # (in the default float dtype: asking for float64 with x64 off warns and gets float32 anyway)
    poses = np.stack([np.asarray(rg.to_matrix(T, (), jnp.result_type(float)), np.float64) for T in kin.bodies])
    for c in connects:
        ends = []
        for name in (c.body1, c.body2):
            if name not in robot.frame_names:
                raise ValueError(f"{c.where}: unknown body or site {name!r}")
            f = robot.frame_index(name)
            ends.append((robot.frame_bodies[f], np.asarray(robot.frame_poses[f], np.float64)))
        (a, Ta_f), (b, Tb_f) = ends
        if a == b:
            raise ValueError(f"{c.where}: bodies {c.body1!r} and {c.body2!r} move as one (no loop to close)")
        pa = Ta_f[:3, :3] @ c.anchor + Ta_f[:3, 3]
        if c.point2 is None:
            pb = np.linalg.solve(poses[b], poses[a] @ np.append(pa, 1.0))[:3]
        else:
            pb = Tb_f[:3, :3] @ c.point2 + Tb_f[:3, 3]
        bodies.append((a, b))
        points.append((pa, pb))
    loop_joints: list[list[int]] = []  # per loop, the q entries on its path, nearest the closure first, alternating
    for a, b in bodies:
        side_a, side_b = robot.ancestors(a)[::-1], robot.ancestors(b)[::-1]
        common = set(side_a) & set(side_b)
        side_a, side_b = [j for j in side_a if j not in common], [j for j in side_b if j not in common]
        order = [x for pair in zip(side_a, side_b, strict=False) for x in pair]
        order += side_a[len(side_b) :] + side_b[len(side_a) :]
        loop_joints.append(
            [robot.sources[j] for j in order if robot.tree_joints[j] == robot.joint_names[robot.sources[j]]]
        )
    open_robot = dataclasses.replace(
        robot,
        loop_points=jnp.asarray(np.array(points, np.float64).reshape(-1, 2, 3)),
        loop_bodies=tuple(bodies),
    )
    balls = {i + k: i for i in _ball.starts(robot.actuated_types) for k in range(3)}  # a ball joint: one unit
    candidates = [balls.get(i, i) for js in loop_joints for i in js if robot.joint_names[i] in passive]
    candidates = list(dict.fromkeys([i for i in candidates if robot.joint_names[i] not in stiff] + candidates))
    units = {i: [i, i + 1, i + 2] if i in balls else [i] for i in candidates}
    C = _generic_jacobian(open_robot, q_ref_actuated, [k for i in candidates for k in units[i]])  # (3 loops, dof)
    tol = 1e-9 * max(1.0, np.abs(C).max())
    everything = [k for i in candidates for k in units[i]]
    target = np.linalg.matrix_rank(C[:, everything], tol) if candidates else 0
    chosen: list[int] = []
    for i in candidates:
        rank = np.linalg.matrix_rank(C[:, chosen], tol) if chosen else 0
        if rank == target:
            break
        if np.linalg.matrix_rank(C[:, chosen + units[i]], tol) > rank:
            chosen += units[i]
    if target < np.linalg.matrix_rank(C, tol) and not chosen:
        raise ValueError(f"{where}: the loops {[c.where for c in connects]} have no joint left to solve (all actuated)")
    keep = [i for i in range(robot.dof) if i not in chosen]
    new_index = {old: k for k, old in enumerate(keep)} | {old: len(keep) + d for d, old in enumerate(chosen)}
    return dataclasses.replace(
        open_robot,
        sources=tuple(new_index[s] for s in robot.sources),
        joint_names=tuple(robot.joint_names[i] for i in keep),
        lower=robot.lower[jnp.asarray(keep, jnp.int32)],
        upper=robot.upper[jnp.asarray(keep, jnp.int32)],
        dependent_names=tuple(robot.joint_names[i] for i in chosen),
        dependent_home=jnp.asarray(q_ref_actuated[chosen]),
    )


def _generic_jacobian(robot, q_ref: np.ndarray, free: list[int]) -> np.ndarray:
    """``(3 loops, dof)`` Jacobian of the loops' residual with respect to every entry of ``q`` (no dependents
    yet), at a closed configuration near ``q_ref`` moved off any singular one: every entry turned by up to
    0.05 (fixed seed), then the loops closed again by least-squares steps of the ``free`` entries."""
    q = q_ref + np.random.default_rng(0).uniform(-0.05, 0.05, q_ref.shape)
    for _ in range(30):
        kin, world = _points(robot, [jnp.asarray(x) for x in q])
        r = np.array([float(e) for pa, pb in world for e in rg.vadd(pa, rg.scale(-1.0, pb))])
        C = np.asarray(_array(_jacobian(robot, kin, world, range(robot.dof)), (), jnp.result_type(float)), np.float64)
        if np.abs(r).max() < 1e-13:
            break
        q[free] -= np.linalg.lstsq(C[:, free], r, rcond=None)[0]
    return C
