"""Forward kinematics, Jacobians and manipulability for every model (chains and whole robots), and a
robot's centre of mass."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from diffkin import _rigid as rg
from diffkin._static import is_concrete
from diffkin._xla import configurations_in_steps, materialize
from diffkin.models import forward
from diffkin.models.forward import Model
from diffkin.models.robot import Robot

_FRAMES = ("world", "space", "body")
_METHODS = ("analytic", "autodiff")


def _base(model: Model, base) -> rg.Rigid:
    """``T_world_root`` of a robot as entries (identity by default); chains take no base."""
    if base is None:
        return rg.IDENTITY
    if not isinstance(model, Robot):
        raise ValueError("base: only a Robot takes a base pose (a chain's base is its own field)")
    shape = jnp.shape(base)
    if len(shape) < 2 or shape[-2:] != (4, 4):
        raise ValueError(f"base: expected a (..., 4, 4) pose T_world_root, got shape {shape}")
    return rg.from_matrix(base)


def _pass(model: Model, q, base=None):
    """Check ``q`` and run the model's forward pass; returns the pass, its batch shape and its dtype."""
    q = forward.joint_values(model, q)
    B = _base(model, base)
    kin = model.forward(forward.JointValues(q), B)
    arrays = [e for e in rg.leaves(B) if not isinstance(e, float)]
    shape = jnp.broadcast_shapes(q.shape[:-1], *(jnp.shape(e) for e in arrays))
    return kin, shape, jnp.result_type(q, *arrays)


def _frame_indices(robot: Robot, frames) -> tuple[list[int], bool]:
    """Indices of one frame name or a sequence of names; and whether one name was given."""
    if isinstance(frames, str):
        return [robot.frame_index(frames)], True
    if not isinstance(frames, Sequence) or not frames:
        raise TypeError(f"frames: expected a frame name or a non-empty sequence of names, got {frames!r}")
    return [robot.frame_index(f) for f in frames], False


def fk(model: Model, q: ArrayLike, frames: str | Sequence[str] | None = None, *, base=None) -> jax.Array:
    """Pose of a chain's end effector, or of named frames of a robot.

    Args:
        model: a :class:`DHChain` (DH product), a :class:`PoEChain` (product of exponentials) or
            a :class:`Robot` (tree).
        q: ``(..., dof)`` joint values, radians (revolute) or metres (prismatic); for a robot the
            actuated joints in ``robot.joint_names`` order (mimic joints follow).
        frames: robots only: a frame name, or a sequence of ``k`` names (``robot.frame_names``).
        base: robots only: ``(..., 4, 4)`` pose ``T_world_root`` of the root (default identity),
            for a floating base or a robot placed in the world.

    Returns:
        A chain: ``(..., 4, 4)`` pose ``T_base_ee`` of the end effector, tool included.
        A robot: ``(..., 4, 4)`` pose ``T_world_frame`` of one frame, or ``(..., k, 4, 4)``.
    """
    if not isinstance(model, Robot):
        if frames is not None:
            raise ValueError("frames: a chain has one end effector; name frames only for a Robot")
        kin, shape, dtype = _pass(model, q, base)
        return rg.to_matrix(kin.pose(), shape, dtype)
    if frames is None:
        raise ValueError(f"frames: name the frame(s) of the robot, one of {list(model.frame_names)}")
    indices, single = _frame_indices(model, frames)
    kin, shape, dtype = _pass(model, q, base)
    if single:
        return rg.to_matrix(kin.pose(indices[0]), shape, dtype)
    return _matrices(kin, indices, shape, dtype)


def link_poses(model: Model, q: ArrayLike, *, base=None) -> jax.Array:
    """Poses of every link (chain) or every named frame (robot).

    Args:
        model: any model.
        q: ``(..., dof)`` joint values.
        base: robots only: ``(..., 4, 4)`` pose ``T_world_root`` (default identity).

    Returns:
        A chain: ``(..., dof + 1, 4, 4)``: the base frame (DH frame 0, or the identity for a
        :class:`PoEChain`), then the frame of each moving link (DH frame ``i``, or the URDF
        child link of joint ``i``), all in the base frame.
        A robot: ``(..., len(robot.frame_names), 4, 4)`` in ``robot.frame_names`` order, in the world.
    """
    kin, shape, dtype = _pass(model, q, base)
    if isinstance(kin, forward.StackedPass):
        return _matrices(kin, list(range(kin.frames)), shape, dtype)
    return rg.to_matrices(kin.poses(), shape, dtype)


def _matrices(kin, frames: list, shape: tuple[int, ...], dtype) -> jax.Array:
    """``shape + (len(frames), 4, 4)``: the poses of ``frames``, a stacked pass's as one stacked pose."""
    if isinstance(kin, forward.StackedPass):
        return jnp.moveaxis(rg.to_matrix(kin.stacked_poses(frames), (len(frames), *shape), dtype), 0, -3)
    return rg.to_matrices([kin.pose(f) for f in frames], shape, dtype)


def _analytic(model: Model, q, frame: str, f: int | None, base, include_base: bool) -> jax.Array:
    kin, shape, dtype = _pass(model, q, base)
    T = kin.pose(f)
    stacked = isinstance(kin, forward.StackedPass)
    if stacked:  # one twist whose entries have a leading axis of columns
        columns = [kin.stacked_columns(f)]
        if include_base:
            columns = [_stacked_twists(rg.root_screws(_base(model, base)), shape, dtype), *columns]
    else:
        columns = kin.columns(f)
        if include_base:
            columns = rg.root_screws(_base(model, base)) + columns
    if frame != "space":
        columns = rg.world_from_space(columns, T.p)
    if frame == "body":
        Rt = tuple(rg.column(T.R, j) for j in range(3))
        columns = [(rg.rotate(Rt, v), rg.rotate(Rt, w)) for v, w in columns]
    if stacked:
        blocks = [rg.stack([*v, *w], (jnp.shape(v[0])[0], *shape), dtype, axis=0) for v, w in columns]  # (6, n) + shape
        return jnp.moveaxis(jnp.concatenate(blocks, axis=1), (0, 1), (-2, -1))
    return _stack_columns(columns, shape, dtype)


def _stacked_twists(twists: list[forward.Twist], shape: tuple[int, ...], dtype) -> forward.Twist:
    """Twists ``(v, w)`` (entries) as one twist whose entries are ``(len(twists),) + shape``."""
    return tuple(  # type: ignore[return-value]
        tuple(rg.stack([t[part][i] for t in twists], shape, dtype, axis=0) for i in range(3)) for part in (0, 1)
    )


def _autodiff(model: Model, q, frame: str, f: int | None, base, include_base: bool) -> jax.Array:
    """Columns from forward-mode derivatives of the frame's pose along each joint (and root axis).

    An unrolled pass takes one JVP per column, each with the other entries constant (the joints before its
    own then carry no tangent: the fastest to run). A scanned pass (``model.scanned``) takes one JVP with the
    unit tangents vmapped: one scan traced and compiled, not one per joint (docs/performance.md).
    """
    q = forward.joint_values(model, q)
    B = _base(model, base)
    shape = jnp.broadcast_shapes(q.shape[:-1], jnp.shape(base)[:-2] if base is not None else ())
    zero, unit = (0.0, 0.0, 0.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    steps = [(e, zero) for e in unit] + [(zero, e) for e in unit] if include_base else []
    qs = [q[..., i] for i in range(model.dof)]
    if not steps and not qs:  # a robot without joints
        return jnp.zeros(shape + (6, 0), q.dtype)

    def pose(x: list) -> tuple:  # the root moved by exp(t_k e_k) in its own frame, axis by axis; the joints at x
        B_ = B
        for (v, w), t in zip(steps, x, strict=False):
            if not isinstance(t, float):  # (a step by a Python 0.0 is no step)
                B_ = rg.compose(B_, rg.screw_exp(v, w, t))
        return tuple(jnp.asarray(e, q.dtype) for e in rg.leaves(model.forward(x[len(steps) :], B_).pose(f)))

    if model.scanned:
        x = [jnp.zeros(shape, q.dtype)] * len(steps) + qs

        def along(unit_row: jax.Array) -> tuple:  # the pose and its derivative along one unit vector of x
            return jax.jvp(pose, (x,), ([u * jnp.ones_like(e) for u, e in zip(unit_row, x, strict=True)],))

        T, dT = jax.vmap(along, out_axes=(None, 0))(jnp.eye(len(x), dtype=q.dtype))  # dT: (columns, ...)
        v, w = _twist(frame, T, tuple(_columns_first(e, shape) for e in dT))
        rows = rg.outputs([*v, *w], (len(x), *shape), q.dtype)  # (columns, ..., 6)
        return jnp.moveaxis(rows, 0, -1)
    x = [0.0] * len(steps) + qs
    columns = []
    for k in range(len(x)):
        x_k = jnp.zeros(shape, q.dtype) if k < len(steps) else x[k]
        T, dT = jax.jvp(lambda t, k=k: pose(x[:k] + [t] + x[k + 1 :]), (x_k,), (jnp.ones_like(x_k),))
        columns.append(_twist(frame, T, dT))
    return _stack_columns(columns, shape, q.dtype)


def _columns_first(e: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    """A vmapped entry ``(columns,) + s`` (``s`` broadcastable to ``shape``) as ``(columns,) + shape``."""
    return jnp.broadcast_to(
        e.reshape(e.shape[:1] + (1,) * (len(shape) + 1 - e.ndim) + e.shape[1:]), e.shape[:1] + shape
    )


def _twist(frame: str, T: tuple, dT: tuple) -> forward.Twist:
    """The twist ``(v, w)`` in ``frame`` of a pose's :func:`rg.leaves` ``T`` moving at ``dT``."""
    R, p, dR, dp = _split(T), T[9:], _split(dT), dT[9:]
    if frame == "body":  # [R^T dp; vee(R^T dR)]
        Rt, dRt = tuple(rg.column(R, j) for j in range(3)), tuple(rg.column(dR, j) for j in range(3))
        return rg.rotate(Rt, dp), _vee_of_product(Rt, dRt)
    w = _vee_of_product(dR, R)  # vee(dR R^T)
    return (dp if frame == "world" else rg.vadd(dp, rg.cross(p, w))), w


def _stack_columns(columns, shape, dtype) -> jax.Array:
    """Twist columns ``(v, w)`` (entries) as one ``shape + (6, len(columns))`` array, in one stack."""
    rows = [column[part][i] for part in (0, 1) for i in range(3) for column in columns]
    if not rows:  # a robot without joints
        return jnp.zeros(shape + (6, 0), dtype)
    return rg.outputs(rows, shape, dtype).reshape(shape + (6, len(columns)))


def _split(entries) -> rg.Mat3:
    """The rotation of a pose's :func:`rg.leaves`."""
    return tuple(tuple(entries[3 * i : 3 * i + 3]) for i in range(3))


def _vee_of_product(A: rg.Mat3, B: rg.Mat3) -> rg.Vec3:
    """``vee`` of the skew part of ``A B^T`` (only its off-diagonal entries are formed)."""
    W = lambda a, b: rg.dot(A[a], B[b])  # noqa: E731
    return tuple(0.5 * (W(a, b) - W(b, a)) for a, b in ((2, 1), (0, 2), (1, 0)))


def _where(model: Model, where: tuple, frame: str | None, frame_name: str | None) -> tuple[int | None, str]:
    """The frame index (robots) and the reference frame of a :func:`jacobian` call."""
    names = list(where)
    if isinstance(model, Robot):
        if frame_name is None and names:
            frame_name = names.pop(0)
        if frame_name is None:
            raise TypeError(f"frame_name: name the frame of the robot, one of {list(model.frame_names)}")
        f = model.frame_index(frame_name)
    else:
        if frame_name is not None:
            raise TypeError("frame_name: a chain has one end effector; name frames only for a Robot")
        f = None
    if names and frame is not None:
        raise TypeError(f"frame: given twice ({names[0]!r} and {frame!r})")
    if len(names) > 1:
        raise TypeError(f"jacobian: too many positional arguments: {tuple(names)!r}")
    frame = names[0] if names else ("world" if frame is None else frame)
    if frame not in _FRAMES:
        raise ValueError(f"frame: expected one of {_FRAMES}, got {frame!r}")
    return f, frame


def jacobian(
    model: Model,
    q: ArrayLike,
    *where: str,
    frame: str | None = None,
    frame_name: str | None = None,
    method: str | None = None,
    base=None,
    include_base: bool = False,
) -> jax.Array:
    """Geometric Jacobian of a chain's end effector or of a robot's frame, rows ``[v; w]``.

    Called as ``jacobian(chain, q, frame="world")`` or ``jacobian(robot, q, frame_name, frame="world")``
    (positionally or by keyword).

    Args:
        model: any model.
        q: ``(..., dof)`` joint values.
        frame_name: robots only: the frame whose motion the Jacobian gives.
        frame: ``"world"``: linear velocity of the frame's origin and angular velocity, both
            in base (world) axes (pytorch-kinematics' ``jacobian``, Pinocchio's ``LOCAL_WORLD_ALIGNED``);
            ``"space"``: spatial twist Jacobian ``J_s`` (column ``i`` is the current screw axis of
            joint ``i`` in the base frame; Pinocchio's ``WORLD``); ``"body"``: body twist
            Jacobian ``J_b = Ad(T^-1) J_s`` in the frame itself (Pinocchio's ``LOCAL``).
        method: ``"analytic"`` (the default) uses the screw axes of the forward pass;
            ``"autodiff"`` differentiates :func:`fk` with JAX (forward mode). Both agree to
            rounding. The analytic one is as fast or faster on every backend, and its compile
            time grows linearly with the number of joints (docs/performance.md, "Analytic and
            autodiff Jacobians").
        base: robots only: ``(..., 4, 4)`` pose ``T_world_root`` (default identity).
        include_base: robots only: prepend the six columns of the root's body twist ``[v; w]``
            (a floating base moving as ``T_world_root exp([V] t)``).

    Returns:
        ``(..., 6, dof)`` Jacobian (``(..., 6, 6 + dof)`` with ``include_base``); column ``i``
        is the twist per unit ``q_i``. A mimic joint adds its motion (times its multiplier) to
        the column of its source joint; joints off the frame's path give zero columns. On a robot
        with closed loops the dependent joints move as the loops' implicit function,
        ``dq_dep/dq = -pinv(C_dep) C_q``: the derivative of :func:`fk` where the loops close. Where
        one cannot (:func:`loop_closure`'s gap above 0), both methods give that same motion (the
        loops' residual held to first order, in least squares) at the returned poses, but the
        poses are the loop solve's last iterate, not a smooth function of ``q``: no Jacobian is
        their derivative there.
    """
    forward.check(model)
    f, frame = _where(model, where, frame, frame_name)
    method = "analytic" if method is None else method
    if method not in _METHODS:
        raise ValueError(f"method: expected one of {_METHODS}, got {method!r}")
    if include_base and not isinstance(model, Robot):
        raise ValueError("include_base: only a Robot has a root pose to move")
    return (_analytic if method == "analytic" else _autodiff)(model, q, frame, f, base, bool(include_base))


def manipulability(model: Model, q: ArrayLike, frame_name: str | None = None, *, base=None) -> jax.Array:
    """Yoshikawa's manipulability of the world Jacobian (of a chain, or of a robot's frame).

    ``sqrt(det(J J^T))`` for 6 or more joints, ``sqrt(det(J^T J))`` for fewer (both the
    product of the singular values of ``J``). At a singular configuration the value is 0
    and its gradient is finite (0 there: a subgradient of the measure at its minimum).

    Args:
        model: any model.
        q: ``(..., dof)`` joint values.
        frame_name: robots only: the frame.
        base: robots only: ``(..., 4, 4)`` pose ``T_world_root``.

    Returns:
        ``(...,)`` manipulability (units of the Jacobian's entries).
    """
    names = () if frame_name is None else (frame_name,)
    J = jacobian(model, q, *names, frame="world", method="analytic", base=base)
    Jt = jnp.swapaxes(J, -1, -2)
    G = J @ Jt if model.dof >= 6 else Jt @ J
    det = jnp.linalg.det(G)
    tiny = jnp.finfo(G.dtype).eps ** 2
    singular = jax.lax.stop_gradient(det) <= tiny
    eye = jnp.eye(G.shape[-1], dtype=G.dtype)
    det_safe = jnp.linalg.det(jnp.where(singular[..., None, None], eye, G))
    return jnp.where(singular, 0.0, jnp.sqrt(det_safe))


def massive(model: Model) -> Robot:
    """``robot``, checked for a centre of mass on the host: a Robot whose masses the file determines
    and (when concrete) do not sum to 0."""
    if not isinstance(model, Robot):
        raise TypeError(f"robot: the centre of mass needs a Robot (its masses), got {type(model).__name__}")
    forward.check(model)
    if model.unknown_masses:
        raise ValueError(f"robot {model.name!r}: unknown masses: {'; '.join(model.unknown_masses)}")
    if is_concrete(model.masses) and not np.sum(np.asarray(model.masses, np.float64)) > 0:
        raise ValueError(f"robot {model.name!r}: its masses sum to 0 (no <inertial> in the file): no centre of mass")
    return model


#: Centre-of-mass batches above twice this go in steps of this many configurations
#: (:func:`diffkin._xla.configurations_in_steps`: a whole robot's pass is memory-bound at 100,000).
COM_STEP = 1024


def com(robot: Robot, q: ArrayLike, *, base=None) -> jax.Array:
    """The robot's centre of mass in the world: ``sum_b m_b p_b / sum_b m_b`` over every body.

    Every body counts, those fixed to the root included (MuJoCo's ``subtree_com`` of the world;
    Pinocchio's ``centerOfMass`` of a fixed-base URDF leaves out the root link's mass).
    Differentiable with respect to ``q``, ``base`` and the robot's ``masses`` and ``body_coms``.

    Args:
        robot: a :class:`Robot` with masses (URDF ``<inertial>``, MJCF inertials or geoms).
        q: ``(..., dof)`` joint values.
        base: ``(..., 4, 4)`` pose ``T_world_root`` (default identity).

    Returns:
        ``(..., 3)`` centre of mass in the world (metres).

    Raises:
        TypeError: a chain (it has no masses).
        ValueError: a massless robot, or masses the file does not determine (named).
    """
    q, base = _checked(robot, q, base)
    return configurations_in_steps(lambda q_, b_: _centre(robot, q_, b_, False), q, base, COM_STEP)


def com_jacobian(robot: Robot, q: ArrayLike, *, base=None, include_base: bool = False) -> jax.Array:
    """``d com / d q``: the velocity of the centre of mass (world axes) per unit joint motion.

    Args:
        robot: a :class:`Robot` with masses.
        q: ``(..., dof)`` joint values.
        base: ``(..., 4, 4)`` pose ``T_world_root`` (default identity).
        include_base: prepend the six columns of the root's body twist ``[v; w]`` (as
            :func:`jacobian`: the root moving as ``T_world_root exp([V] t)``).

    Returns:
        ``(..., 3, dof)`` (``(..., 3, 6 + dof)`` with ``include_base``); a mimic joint adds its
        motion (times its multiplier) to its source's column.

    Raises:
        TypeError, ValueError: as :func:`com`.
    """
    q, base = _checked(robot, q, base)
    return configurations_in_steps(lambda q_, b_: _centre(robot, q_, b_, True, bool(include_base)), q, base, COM_STEP)


def _checked(robot: Robot, q, base) -> tuple:
    """``(q, base)`` of a centre-of-mass call, checked on the host (see :func:`com`)."""
    massive(robot)
    q = forward.joint_values(robot, q)
    _base(robot, base)
    return q, base


def _centre(robot: Robot, q, base, jacobian: bool, include_base: bool = False) -> jax.Array:
    """The centre of mass ``(N, 3)``, or its Jacobian ``(N, 3, columns)``, of flat configurations.

    The pass runs in the root's frame and its results are moved by the root pose ``base`` once at the
    end (a root pose threaded through the pass costs more than rotating its few results)."""
    B = _base(robot, base)
    kin, shape, dtype = _pass(robot, q, None)
    traced = [e for e in rg.leaves(B) if not isinstance(e, float)]
    shape, dtype = jnp.broadcast_shapes(shape, *(jnp.shape(e) for e in traced)), jnp.result_type(dtype, *traced)
    c_root, columns = kin.com(velocities=jacobian)
    if traced:  # the pass's results and the root pose computed once, then moved
        flat = list(materialize([*c_root, *(e for col in columns for e in col), *rg.leaves(B)]))
        B = rg.Rigid(tuple(tuple(flat[-12 + 3 * i + j] for j in range(3)) for i in range(3)), tuple(flat[-3:]))
        c_root, columns = tuple(flat[:3]), [tuple(flat[3 + 3 * k : 6 + 3 * k]) for k in range(len(columns))]
    c = rg.vadd(rg.rotate(B.R, c_root), B.p)
    if not jacobian:
        return rg.stack(list(c), shape, dtype)
    columns = [rg.rotate(B.R, v) for v in columns]
    if include_base:
        columns = [v for v, _ in rg.world_from_space(rg.root_screws(B), c)] + columns
    rows = [column[i] for i in range(3) for column in columns]
    if not rows:  # a robot without joints
        return jnp.zeros(shape + (3, 0), dtype)
    return rg.outputs(rows, shape, dtype).reshape(shape + (3, len(columns)))


def loop_closure(robot: Robot, q: ArrayLike) -> tuple[jax.Array, jax.Array]:
    """The dependent joints of a robot with closed loops, solved at ``q``, and how far the loops stay open.

    Args:
        robot: a :class:`Robot` (with loops: MJCF ``<equality><connect>``; :mod:`diffkin.models._loops`).
        q: ``(..., dof)`` joint values.

    Returns:
        ``(q_dependent (..., nd), gap (...))``: the values of ``robot.dependent_names`` (radians or metres;
        each ball joint's three components among them) and the largest distance between a loop's two
        points after the solve (metres; zero to rounding where every loop closes). Differentiable
        (implicit-function derivatives).
    """
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected a Robot, got {type(robot).__name__}")
    kin, shape, dtype = _pass(robot, q)
    nd = len(robot.dependent_names)
    dependent = rg.stack(kin.dependent, shape, dtype) if nd else jnp.zeros(shape + (0,), dtype)
    return dependent, jnp.broadcast_to(jnp.asarray(kin.loop_gap, dtype), shape)
