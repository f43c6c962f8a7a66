"""The terms of an IK problem: one small class per kind of residual, one file each.

A problem is a list of terms; the solver sums their squared residuals and knows nothing of their
kinds. A term is static (hashable: a field of the compiled solver's static arguments): the frames
it reads, its kind, its weights. Its numbers are arrays passed beside it. There are two kinds (as
mink's tasks and limits):

- a :class:`Target` reports errors (metres, radians) and binds one target per problem: a frame's
  pose (:mod:`~diffkin.ik._terms.pose`), one frame's pose in another
  (:mod:`~diffkin.ik._terms.relative`), the centre of mass (:mod:`~diffkin.ik._terms.com`);
- a :class:`Constraint` reports its own value and whether it is met, and binds data every problem
  shares: the clearance (:mod:`~diffkin.ik._terms.avoid`).

Every term provides:

- ``frames``: the frames whose motion it reads (which joints can move it, for the seeds).
- ``deferred``: its rows cost more than every other term's together, so a search may first
  iterate without it and check :meth:`Constraint.clearance` after (:meth:`diffkin.ik._problem.Problem.undeferred`).
- ``bind(data)``: its entries, what :meth:`rows` and :meth:`screen` read: a target's from an array
  whose leading axis is the problem (``(P, 4, 4)`` poses or ``(P, 3)`` positions), a constraint's
  from its data in the solver's dtype.
- ``rows(kin, bound, jacobian) -> Rows``: its residual entries ``r``, the rows of
  ``J = d(-r)/dx`` (one entry per column of the state; empty without ``jacobian``) and its
  errors, from the state's kinematics ``kin`` (``kin.pose(frame)``: the frame's world pose,
  ``kin.columns(frame)``: per column of the state, the space twist of the frame's motion; see
  :class:`diffkin.ik._problem.Kinematics`).
- ``screen(kin, bound)``: a cheap cost (no Jacobian) for choosing among seeds.

Entries are arrays of the problem shape or folded Python floats (:mod:`diffkin._rigid`). Which
keyword of :func:`diffkin.ik.solve` makes which terms: :mod:`diffkin.ik._keywords`.
"""

from __future__ import annotations

from typing import ClassVar, NamedTuple, Protocol

import jax

from diffkin import _rigid as rg


class Rows(NamedTuple):
    """A term's residual entries ``r``, its Jacobian rows ``J`` (``J[i][c]``, or all of them as one array
    ``(len(r), C, P)``) and its errors (metres, radians).

    A term with many rows computed together gives them as one ``block`` instead: ``(r (m, P),
    J (m, C, P))`` arrays (``J`` ``(m, 0, P)`` without Jacobian), after the entries.
    """

    r: list[rg.Entry]
    J: list[list[rg.Entry]] | jax.Array
    pos_err: rg.Entry
    rot_err: rg.Entry
    block: tuple[jax.Array, jax.Array] | None = None


class Term(Protocol):
    """What the solver asks of every term (see the package docstring)."""

    deferred: ClassVar[bool]
    frames: tuple[int | None, ...]

    def bind(self, data) -> tuple: ...

    def rows(self, kin, bound, jacobian: bool) -> Rows: ...

    def screen(self, kin, bound) -> rg.Entry: ...


class Target(Term, Protocol):
    """A term that reports errors: its ``Rows.pos_err``/``rot_err`` are ``IKResult.pos_err``/``rot_err``
    (one column per target, in the order of the keywords), or, with a ``result_field``, that field of
    :class:`~diffkin.ik.IKResult` alone (its position error: the centre of mass's ``com_err``).

    ``bind(target)`` takes ``(P, 4, 4)`` poses or ``(P, 3)`` positions (``position_only``), one per
    problem; success needs the errors within the tolerances on the axes its ``weights`` keep.
    """

    deferred: ClassVar[bool] = False
    result_field: ClassVar[str | None] = None
    position_only: bool
    weights: tuple[float, ...]


class Constraint(Term, Protocol):
    """A term that reports its own value, ``clearance(kin, bound, exact=True) -> (P,)`` (``IKResult.clearance``),
    computed exactly at the returned states (``exact`` false, a bool that may be traced: exact only where
    it is not met), and by how much it holds, ``slack_of(value, bound) -> (P,)`` (in its own unit): it is
    met where the slack is ``>= 0``, which success needs.

    ``bind(data)`` takes its data (a pytree in the solver's dtype: :class:`~diffkin.ik.Avoid`), which
    has ``cast(dtype)``, ``flat(lead)`` (parts per problem, of problem axes broadcasting to the
    targets' ``lead``, flattened to ``(n, ...)``; shared parts as they are) and ``tiled(tile)``
    (``tile`` applied to the flat parts per problem: the problems a search runs). Its
    ``Rows.pos_err`` is 0 where it is met and the largest float elsewhere.
    """

    def rows(self, kin, bound, jacobian: bool, off=None) -> Rows:
        """As :meth:`Term.rows`, told ``off`` ``(P,)``: the targets' largest error at the state (metres, a
        radian counting as :data:`diffkin.ik._problem.OFF_PER_RADIAN`), ``None`` without targets."""
        ...

    def clearance(self, kin, bound, exact=True) -> jax.Array: ...

    def slack_of(self, value: jax.Array, bound) -> jax.Array:
        """The slack of ``value`` ``(P,)``, what :meth:`clearance` returned (no second measure)."""
        ...
