"""An IK problem: a model, its terms, the state's projection and retraction, and the residual of
every term from one forward pass.

All arrays here are flat over ``P = seeds x targets`` problems, with that axis last: ``q`` is
``(dof, P)`` and vectors and matrices are stacks of per-entry arrays (structure of arrays, as in
:mod:`diffkin._rigid`), so that one select or copy moves a whole field.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple, cast

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._static import host
from diffkin._xla import materialize
from diffkin.ik._terms import Constraint, Term
from diffkin.models.ranges import into_cones
from diffkin.models.robot import Robot

BASE_ROWS = 12  # state rows of a solved root pose: p (3), then R row by row (9)


class Eval(NamedTuple):
    """The residual of a problem's terms at states ``x``, stacked.

    Attributes:
        r: ``(m, P)`` every term's rows.
        J: ``(m, n, P)`` ``d(-r)/dx``, ``n`` columns of the state (``(0, 0, P)`` where only the
            cost is needed).
        cost: ``(P,)`` ``|r|^2``.
        pos_err: ``(k, P)`` metres, per term.
        rot_err: ``(k, P)`` radians, per term.
    """

    r: jax.Array
    J: jax.Array
    cost: jax.Array
    pos_err: jax.Array
    rot_err: jax.Array


class Entries(NamedTuple):
    """The fields of an :class:`Eval` before they are computed into arrays: one entry (an array of
    the problem shape, or a folded Python float) per value, ``J`` row by row (a row a list of
    entries, or several rows as one array ``(k, n, P)``: :data:`Rows.J`); ``pos_err`` and
    ``rot_err`` one entry per term (see :func:`settle`). Rows that terms give as blocks
    (:class:`diffkin.ik._terms.Rows`) are ``blocks``: ``(r (m_b, P), J (m_b, n, P))``, stacked after
    the entries' rows; ``cost`` counts them."""

    r: list
    J: list
    cost: rg.Entry
    pos_err: list
    rot_err: list
    blocks: tuple[jax.Array, jax.Array] | None = None


class Kinematics:
    """The kinematics of a problem's state, as its terms read them.

    ``pose(frame)``: the frame's world pose; ``columns(frame)``: per column of the state, the
    space twist of the frame's motion: one per joint (zero for a locked joint), then, when the
    root is solved, the six of the root's body twist; ``com()``: a robot's centre of mass and its
    velocity per column. ``dtype``, ``shape``: the solver's dtype and the problems' shape ``(P,)``.

    Where the problem's Jacobian reads joints' screws twice or more (:attr:`Problem.in_arrays`: the frames
    share joints, or a centre of mass is asked for), the forward pass is the robot's in arrays
    (:meth:`diffkin.Robot.forward_by_depth`), and :meth:`point_columns` and :meth:`com_columns` give each
    frame's and the centre's Jacobian as one array read from it.
    """

    def __init__(self, problem: Problem, x: jax.Array, jacobian: bool = True):
        """``jacobian``: whether a Jacobian is read (without, the unrolled pass: a residual alone reads a few
        frames, whose entries XLA fuses into their consumers)."""
        self.arrays = jacobian and problem.in_arrays
        self.locked = problem.locked
        self.dtype = x.dtype
        self.shape = x.shape[1:]
        self.solve_base = problem.solve_base
        joints = problem.joints(x)
        if self.arrays:
            self.kin = problem.model.forward_by_depth(joints, _root_matrix(problem, x))
            self.root_columns: list = []
            return
        root = problem.root(x)
        self.kin = problem.model.forward(list(joints), root)
        self.root_columns = rg.root_screws(root) if problem.solve_base else []

    def pose(self, frame: int | None) -> rg.Rigid:
        return self.kin.pose(frame)

    def columns(self, frame: int | None) -> list:
        zero = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        joints = [zero if lock else c for lock, c in zip(self.locked, self.kin.columns(frame), strict=True)]
        return joints + self.root_columns

    def point_columns(self, frame: int | None) -> jax.Array | None:
        """``(6, n) + shape``: per column of the state, the velocity of ``frame``'s origin and its angular
        velocity ``[v; w]`` (world axes; :meth:`columns` moved to the frame's origin), as one array; ``None``
        without the pass in arrays (:attr:`Problem.in_arrays`: the entry-wise :meth:`columns` are then as few
        kernels, one arm's or two arms' apart).

        XLA's CPU backend compiles each kernel apart (~10 ms each): a whole robot's Jacobian entry by entry
        is hundreds of kernels, its columns read from the pass in arrays one per frame.
        """
        if not self.arrays:
            return None
        return self.kin.point_columns(frame, self.kin.pose(frame).p, self.locked, self.solve_base)

    def com_columns(self) -> tuple[rg.Vec3, jax.Array] | None:
        """The centre of mass and its velocity per column of the state ``(3, n) + shape`` (as :meth:`com`),
        from the pass in arrays (the bodies' first moments and axes); ``None`` without it."""
        if not self.arrays:
            return None
        masses, coms = _mass_model(self.kin.robot)
        return self.kin.com_columns(masses, coms, self.locked, self.solve_base)

    def com(self, velocities: bool = True) -> tuple[rg.Vec3, list[rg.Vec3]]:
        """The robot's centre of mass and its velocity per column of the state (empty without ``velocities``)."""
        c, joint_velocities = self.kin.com(velocities)
        if not velocities:
            return c, []
        zero = (0.0, 0.0, 0.0)
        joints = [zero if lock else v for lock, v in zip(self.locked, joint_velocities, strict=True)]
        return c, joints + [v for v, _ in rg.world_from_space(self.root_columns, c)]


def _mass_model(robot) -> tuple[np.ndarray, np.ndarray]:
    """``(masses (nb,), body_coms (nb, 3))`` of ``robot`` on the host (float64)."""
    return np.asarray(host(robot.masses), np.float64), np.asarray(host(robot.body_coms), np.float64)


def _root_matrix(problem: Problem, x: jax.Array) -> jax.Array:
    """``(3, 4) + shape``: ``T_world_root`` ``[R p]`` (:meth:`diffkin.Robot.forward_by_depth`)."""
    if problem.solve_base:  # the state's rows [p; R row by row], gathered
        return x[problem.dof + np.asarray([[3, 4, 5, 0], [6, 7, 8, 1], [9, 10, 11, 2]])]
    B = problem.base
    entries = [e for i in range(3) for e in (*B.R[i], B.p[i])]
    return rg.stack(entries, x.shape[1:], x.dtype, axis=0).reshape((3, 4) + x.shape[1:])


class Spec(NamedTuple):
    """The static part of a problem: its terms, locked joints, secondary objectives, solved root.

    Attributes:
        targets: the terms that report errors (:class:`~diffkin.ik._terms.Target`), in ``IKResult`` order.
        constraints: the terms that report their own value (:class:`~diffkin.ik._terms.Constraint`).
        locked: per joint, whether it is locked.
        secondary: the secondary objectives ``(name, weight)`` (:mod:`diffkin.ik._secondary`).
        solve_base: the root pose is part of the state.
        errors_per_term: ``IKResult`` errors ``(..., k)`` (a robot) or ``(...)`` (a chain).
    """

    targets: tuple
    constraints: tuple
    locked: tuple[bool, ...]
    secondary: tuple[tuple[str, float], ...]
    solve_base: bool
    errors_per_term: bool

    @property
    def terms(self) -> tuple:
        """The targets, then the constraints (deferred terms come last: :meth:`Problem.padded`)."""
        return self.targets + self.constraints

    def bind(self, targets: Iterable, data: tuple) -> tuple:
        """Every term's entries: the targets' from ``targets`` (per target, ``(P, 4, 4)`` or ``(P, 3)``;
        any iterable, each bound as it comes), the constraints' from ``data`` (per constraint)."""
        bound = tuple(t.bind(a) for t, a in zip(self.targets, targets, strict=True))
        return bound + tuple(c.bind(d) for c, d in zip(self.constraints, data, strict=True))

    def problem(self, model, bound: tuple, root=rg.IDENTITY, locked_q=None, limits=None) -> Problem:
        """The :class:`Problem` of these terms, ``bound`` (:meth:`bind`), with root pose ``root`` (entries
        ``(P,)`` or constants), locked values ``locked_q`` ``(dof, P)`` (``None``: none are read) and
        ``limits`` ``(lower, upper, wrap, respect_limits)`` (``None``: none, for a residual only)."""
        if limits is None or locked_q is None:
            none = jnp.zeros(0)
            limits = (none, none, none, False) if limits is None else limits
            locked_q = none if locked_q is None else locked_q
        lower, upper, wrap, respect_limits = limits
        return Problem(
            model,
            self.terms,
            bound,
            lower,
            upper,
            wrap,
            respect_limits,
            self.locked,
            locked_q,
            root,
            self.solve_base,
            len(self.targets),
        )


#: how a target's rotation error counts in the targets' error a constraint is told (metres per
#: radian: a point 10 cm from the frame, a gripper's size)
OFF_PER_RADIAN = 0.1


class Problem(NamedTuple):
    """A flat batch of ``P`` problems of one model: its terms, limits, locked joints and root, in one dtype.

    The state ``x`` is ``(n, P)``: the ``dof`` joint values, then, when the root is solved, its pose
    ``[p; R row by row]`` (:data:`BASE_ROWS` rows), moved by ``T_world_root exp([dv; dw])``.

    Attributes:
        model: the model (any kind: :mod:`diffkin.models.forward`).
        terms: static, the terms (:mod:`diffkin.ik._terms`); ``bound``: per term, its target entries.
        lower, upper: ``(dof,)`` limits (or ``(dof, P)``: a path's step bounds); ``wrap``: ``(dof,)``
            unlimited revolute joints.
        respect_limits: static; clip the joints to the limits.
        locked: static, per joint, whether it is locked; ``locked_q``: ``(dof, P)`` its values.
        base: the root pose ``T_world_root`` (entries ``(P,)`` or constants) when not solved.
        solve_base: static; the root pose is part of the state.
        targets: static; the leading terms that are targets (the others are constraints, whose rows
            are told how far the targets are: :meth:`residual`).
    """

    model: Any
    terms: tuple[Term, ...]
    bound: tuple
    lower: jax.Array
    upper: jax.Array
    wrap: jax.Array
    respect_limits: bool
    locked: tuple[bool, ...]
    locked_q: jax.Array
    base: rg.Rigid
    solve_base: bool
    targets: int = 0

    @property
    def dof(self) -> int:
        return self.model.dof

    @property
    def pose_frames(self) -> tuple:
        """The frames whose Jacobian a term reads as one array (:meth:`Kinematics.point_columns`), once each."""
        return tuple(dict.fromkeys(f for t in self.terms if getattr(t, "point_columns", False) for f in t.frames))

    @property
    def in_arrays(self) -> bool:
        """Whether the state's forward pass is the robot's in arrays (:meth:`diffkin.Robot.forward_by_depth`): a tree
        that pass takes, whose Jacobian reads joints' screws more than once: a centre of mass, or frames
        (:attr:`pose_frames`) whose paths share a joint that moves or a solved root. Otherwise (a chain, one
        arm, two arms apart) the unrolled pass's entry-wise Jacobian is as few kernels and faster. Only for
        terms that read the pass through :meth:`Kinematics.pose`, :meth:`Kinematics.point_columns` and
        :meth:`Kinematics.com_columns` (pose and centre-of-mass targets)."""
        model = self.model
        kinds = all(getattr(t, "point_columns", False) or getattr(t, "com_columns", False) for t in self.terms)
        if not kinds or not isinstance(model, Robot) or not model.by_depth:
            return False
        if any(getattr(t, "com_columns", False) for t in self.terms):
            return True
        frames = self.pose_frames
        if self.solve_base:
            return len(frames) > 1
        paths = [
            {j for j in model.ancestors(model.frame_bodies[f]) if not self.locked[model.sources[j]]} for f in frames
        ]
        return len(set().union(*paths)) < sum(map(len, paths))

    def joints(self, x: jax.Array) -> jax.Array:
        """The joint rows of the state."""
        return x[: self.dof] if self.solve_base else x

    def project(self, x: jax.Array) -> jax.Array:
        """Unlimited revolute joints wrapped to ``[-pi, pi)``, joints clipped (``respect_limits``), ball
        joints scaled into their cones (:func:`diffkin.models.ranges.into_cones`), locked joints at their
        values; the root pose unchanged."""
        q = into_cones(self.joints(x), self.model, self.respect_limits)  # (then within the box around the cone)
        q = project(q, self.lower, self.upper, self.wrap, self.respect_limits)
        if any(self.locked):
            q = jnp.where(jnp.asarray(self.locked)[:, None], self.locked_q, q)
        return jnp.concatenate([q, x[self.dof :]]) if self.solve_base else q

    def retract(self, x: jax.Array, dx: jax.Array) -> jax.Array:
        """``q + dq``, and the root pose moved by ``exp`` of the body twist ``dx[dof:]``, projected."""
        if not self.solve_base:
            return self.project(x + dx)
        q = x[: self.dof] + dx[: self.dof]
        T = rg.compose(
            self.root(x),
            rg.screw_exp(tuple(dx[self.dof : self.dof + 3]), tuple(dx[self.dof + 3 :]), jnp.ones((), x.dtype)),
        )
        return self.project(jnp.concatenate([q, jnp.stack(list(T.p) + [e for row in T.R for e in row])]))

    def root(self, x: jax.Array) -> rg.Rigid:
        """``T_world_root`` at the state ``x``."""
        if not self.solve_base:
            return self.base
        b = x[self.dof :]
        return rg.Rigid(tuple(tuple(b[3 + 3 * i + j] for j in range(3)) for i in range(3)), tuple(b[:3]))

    def residual(self, x: jax.Array, jacobian: bool = True) -> Entries:
        """The entries of every term's residual, Jacobian and errors at ``x``, from one forward pass."""
        kin = Kinematics(self, x, jacobian)
        r: list = []
        J: list = []
        pos_err: list = []
        rot_err: list = []
        blocks: list = []
        for i, (term, bound) in enumerate(zip(self.terms, self.bound, strict=True)):
            if i < self.targets:
                rows = term.rows(kin, bound, jacobian)
            else:  # a constraint, told the targets' largest error ``(P,)`` (None without targets)
                errors = [rg.add(e, rg.mul(OFF_PER_RADIAN, a)) for e, a in zip(pos_err, rot_err, strict=True)]
                zero = jnp.zeros(kin.shape, kin.dtype)
                off = jnp.max(jnp.stack(jnp.broadcast_arrays(*errors, zero)), 0) if errors else None
                rows = cast(Constraint, term).rows(kin, bound, jacobian, off)
            r += rows.r
            J += rows.J if isinstance(rows.J, list) else [rows.J]
            pos_err.append(rows.pos_err)
            rot_err.append(rows.rot_err)
            if rows.block is not None:
                blocks.append(rows.block)
        gap = getattr(kin.kin, "loop_gap", 0.0)  # a robot's loops that do not close: no target is met
        if not isinstance(gap, float):
            pos_err = [jnp.maximum(e, gap) for e in pos_err]
        cost = rg.add(*(rg.mul(e, e) for e in r), *(jnp.sum(b**2, axis=0) for b, _ in blocks))
        stacked = (jnp.concatenate([b for b, _ in blocks]), jnp.concatenate([j for _, j in blocks])) if blocks else None
        return Entries(r, J, cost, pos_err, rot_err, stacked)

    def evaluate(self, x: jax.Array, jacobian: bool = True) -> Eval:
        """Residual, Jacobian and per-term errors ``(k, P)`` at ``x``, from one forward pass."""
        return settle(self.residual(x, jacobian))

    @property
    def defers(self) -> bool:
        """Whether a term is deferred: its rows cost more than every other term's together (the
        clearance), so a search may first iterate without it (:meth:`undeferred`) and check it after
        (:meth:`deferred_measure`)."""
        return any(t.deferred for t in self.terms)

    def undeferred(self) -> Problem:
        """The problem without its deferred terms."""
        keep = [i for i, t in enumerate(self.terms) if not t.deferred]
        return self._replace(terms=tuple(self.terms[i] for i in keep), bound=tuple(self.bound[i] for i in keep))

    def deferred_measure(self, x: jax.Array, exact=False) -> tuple[jax.Array, jax.Array]:
        """``(P,)`` twice: the deferred term's value at ``x`` (a constraint's ``clearance(kin, bound, exact)``;
        one deferred term), exact where ``exact`` (a bool, may be traced), else exact only where it is
        not met, and its slack: it holds where that is ``>= 0``."""
        ((term, bound),) = [(t, b) for t, b in zip(self.terms, self.bound, strict=True) if t.deferred]
        value = cast(Constraint, term).clearance(Kinematics(self, x), bound, exact)
        return value, cast(Constraint, term).slack_of(value, bound)

    def padded(self, x: jax.Array, ev: Eval, met: jax.Array) -> Eval:
        """The evaluation ``ev`` of :meth:`undeferred` at ``x`` as one of this problem, without computing
        the deferred terms' rows: those rows zero, their errors 0 where ``met`` ``(P,)`` and the largest
        float elsewhere, and the cost ``inf`` where not ``met`` (such a state ranks below any evaluated
        one). The deferred terms come last (their rows and errors trail the others')."""
        deferred = [t.deferred for t in self.terms]
        if sorted(deferred) != deferred:
            raise ValueError("deferred terms must come after the others")
        shape = jax.eval_shape(self.evaluate, x)
        m, k = ev.r.shape[0], ev.pos_err.shape[0]
        zeros = lambda a, n: jnp.zeros((a.shape[0] - n,) + a.shape[1:], a.dtype)  # noqa: E731
        err = jnp.broadcast_to(
            jnp.where(met, 0.0, jnp.finfo(ev.cost.dtype).max), (shape.pos_err.shape[0] - k,) + met.shape
        )
        return Eval(
            jnp.concatenate([ev.r, zeros(shape.r, m)]),
            jnp.concatenate([ev.J, zeros(shape.J, m)]),
            jnp.where(met, ev.cost, jnp.inf),
            jnp.concatenate([ev.pos_err, err.astype(ev.pos_err.dtype)]),
            jnp.concatenate([ev.rot_err, err.astype(ev.rot_err.dtype)]),
        )

    def screen_cost(self, x: jax.Array) -> jax.Array:
        """``(P,)`` the terms' cheap costs for choosing seeds (one forward pass without Jacobian)."""
        kin = Kinematics(self, x, jacobian=False)
        return jnp.asarray(rg.add(*(t.screen(kin, b) for t, b in zip(self.terms, self.bound, strict=True))))


def project(q: jax.Array, lower, upper, wrap, respect_limits: bool) -> jax.Array:
    """``q`` ``(dof, P)`` with unlimited revolute joints (``wrap``) wrapped to ``[-pi, pi)`` and,
    with ``respect_limits``, every joint clipped to ``[lower, upper]`` (``(dof,)``, or ``(dof, P)``
    per problem)."""
    wrapped = jnp.where(wrap[:, None], jnp.mod(q + np.pi, 2 * np.pi) - np.pi, q)
    per_problem = lambda x: x if x.ndim == 2 else x[:, None]  # noqa: E731
    return jnp.clip(wrapped, per_problem(lower), per_problem(upper)) if respect_limits else wrapped


def _head(entries: Entries) -> list:
    """The residual, cost and error entries, in the order :func:`_arrays` reads them."""
    return [*entries.r, entries.cost, *entries.pos_err, *entries.rot_err]


def _arrays(entries: Entries, head, J, blocks=None) -> Eval:
    """An :class:`Eval` of arrays from ``head`` (:func:`_head`, stacked), ``J`` ``(m, n, P)`` (:func:`_assembled`)
    and the row blocks (``entries.blocks``, or ones chosen from them)."""
    m, k = len(entries.r), len(entries.pos_err)
    r = head[:m]
    if blocks is not None:
        r, J = jnp.concatenate([r, blocks[0]]), jnp.concatenate([J, blocks[1]])
    return Eval(r, J, head[m], head[m + 1 : m + 1 + k], head[m + 1 + k :])


def _pieces(J: list) -> list:
    """``J``'s rows (:class:`Entries`) as pieces: each run of entry rows one list of rows, each array as it is."""
    pieces: list = []
    for row in J:
        if not isinstance(row, list):
            pieces.append(row)
        elif pieces and isinstance(pieces[-1], list):
            pieces[-1].append(row)
        else:
            pieces.append([row])
    return pieces


def _entries_of(pieces: list) -> list:
    """The entries of the pieces of entry rows, row by row."""
    return [e for piece in pieces if isinstance(piece, list) for row in piece for e in row]


def _assembled(pieces: list, entries: Entries, values: jax.Array, arrays: list) -> jax.Array:
    """``(m, n, P)``: the pieces in order, entry rows from ``values`` ``(entries, P)`` (:func:`_jacobian`),
    array pieces from ``arrays`` (one per array piece)."""
    if not pieces:  # no Jacobian, or only blocks': no rows of n columns
        n = 0 if entries.blocks is None else entries.blocks[1].shape[1]
        return values.reshape((len(entries.r), n) + values.shape[1:])
    n = len(pieces[0][0]) if isinstance(pieces[0], list) else pieces[0].shape[1]
    out, at, given = [], 0, iter(arrays)
    for piece in pieces:
        if isinstance(piece, list):
            out.append(values[at : at + len(piece) * n].reshape((len(piece), n) + values.shape[1:]))
            at += len(piece) * n
        else:
            out.append(next(given))
    return out[0] if len(out) == 1 else jnp.concatenate(out)


def _computed(J: list) -> np.ndarray:
    """The indices of the Jacobian entries that are computed (not folded zeros: a joint off a frame's path)."""
    return np.asarray([i for i, e in enumerate(J) if not (isinstance(e, float) and e == 0.0)], dtype=np.int64)


def _jacobian(J: list, computed: np.ndarray, values: jax.Array) -> jax.Array:
    """``(len(J), P)``: ``values`` ``(len(computed), P)`` at the computed entries, zeros elsewhere.

    Only the computed entries are stacked: XLA's CPU backend gives every operand of a stack a kernel
    of its own, and most of a whole robot's Jacobian is zero (four frames of a humanoid: 912
    entries, ~60 % zero). They are put in place by a gather and a select, not a scatter into zeros,
    which XLA's CPU backend runs as a loop over the computed entries, one row at a time.
    """
    if len(computed) == len(J):
        return values
    if not len(computed):
        return jnp.zeros((len(J),) + values.shape[1:], values.dtype)
    row = np.zeros(len(J), np.int64)  # per entry, its row of `values` (0 for a zero entry: masked below)
    row[computed] = np.arange(len(computed))
    is_computed = np.zeros((len(J),) + (1,) * (values.ndim - 1), bool)
    is_computed[computed] = True
    return jnp.where(is_computed, values[row], jnp.zeros((), values.dtype))


def settle(entries: Entries) -> Eval:
    """The entries computed once into the arrays of an :class:`Eval`."""
    head, pieces = _head(entries), _pieces(entries.J)
    J = _entries_of(pieces)
    computed = _computed(J)
    # Materialised: XLA's CPU fusion would otherwise recompute the whole forward pass inside
    # every kernel of the solver that consumes these entries (20x slower).
    done = materialize(head + [J[i] for i in computed])
    arrays = [piece for piece in pieces if not isinstance(piece, list)]
    J_all = _assembled(pieces, entries, _jacobian(J, computed, done[len(head) :]), arrays)
    return _arrays(entries, done[: len(head)], J_all, entries.blocks)


def settle_choosing(entries: Entries, old: Eval, choose) -> tuple[Eval, jax.Array, Any]:
    """The entries computed once where ``choose`` takes them, ``old``'s values elsewhere.

    ``choose(cost)`` maps the new cost ``(P,)`` to ``(take, extra)``, ``take`` ``(P,)`` bool;
    returns ``(ev, take, extra)`` with ``take`` computed once. The residual, cost and errors are
    computed first (``choose`` reads the cost); the Jacobian's entries are then computed and
    chosen inside the same kernels (a term's rows given as one array: one select). That saves
    writing the new Jacobian and then a pass that reads it with the old one and writes one, the
    largest memory traffic of an LM iteration (:func:`diffkin.ik._search._iterate`).
    """
    head_try = materialize(_head(entries))
    take, extra = choose(head_try[len(entries.r)])
    take = materialize([take])[0]
    shape = take.shape
    old_head = jnp.concatenate(
        [
            old.r[: len(entries.r)],
            old.cost[None],
            old.pos_err.reshape((-1,) + shape),
            old.rot_err.reshape((-1,) + shape),
        ]
    )
    pieces = _pieces(entries.J)
    J_try = _entries_of(pieces)
    computed = _computed(J_try)
    m = len(entries.r)
    rows, arrays, at = [], [], 0  # the old rows of the entry pieces; the array pieces chosen
    for piece in pieces:
        k = len(piece) if isinstance(piece, list) else piece.shape[0]
        if isinstance(piece, list):
            rows.append(np.arange(at, at + k))
        else:
            arrays.append(jnp.where(take, piece, old.J[at : at + k]))
        at += k
    entry_rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    contiguous = len(entry_rows) == m  # (every row an entry row: the old Jacobian's rows as they are)
    J_old = (old.J[:m] if contiguous else old.J[entry_rows]).reshape((-1,) + shape)
    J = materialize([jnp.where(take, J_try[i], J_old[i]) for i in computed]) if len(computed) else J_old[:0]
    blocks = None
    if entries.blocks is not None:
        blocks = tuple(
            jnp.where(take, new, old_b[m:]) for new, old_b in zip(entries.blocks, (old.r, old.J), strict=True)
        )
    J_all = _assembled(pieces, entries, _jacobian(J_try, computed, J), arrays)
    return _arrays(entries, jnp.where(take, head_try, old_head), J_all, blocks), take, extra


def gradient(ev: Eval) -> jax.Array:
    """``(dof, P)`` gradient of ``cost / 2`` with respect to ``q``: ``-J^T r`` (exact, SO(3) log included)."""
    return -jnp.sum(ev.J * ev.r[:, None], axis=0)
