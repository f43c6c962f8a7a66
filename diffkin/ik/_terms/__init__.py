"""The terms of an IK problem: one small class per kind of residual, one file each.

A problem is a list of terms; the solver sums their squared residuals and knows nothing of their
kinds. A term is static (hashable: a field of the compiled solver's static arguments): the frames
it reads, its kind, its weights. Its numbers (a target per problem) are arrays passed beside it.

Every term provides:

- ``frames``: the frames whose motion it reads (which joints can move it, for the seeds).
- ``bind(target)``: its target entries from an array whose leading axis is the problem
  (``(P, 4, 4)`` poses or ``(P, 3)`` positions): what :meth:`rows` and :meth:`screen` read.
- ``rows(kin, bound, jacobian) -> Rows``: its residual entries ``r``, the rows of
  ``J = d(-r)/dx`` (one entry per column of the state; empty without ``jacobian``) and its
  errors, from the state's kinematics ``kin`` (``kin.pose(frame)``: the frame's world pose,
  ``kin.columns(frame)``: per column of the state, the space twist of the frame's motion; see
  :class:`diffkin.ik._problem.Kinematics`).
- ``screen(kin, bound)``: a cheap cost (no Jacobian) for choosing among seeds.

Entries are arrays of the problem shape or folded Python floats (:mod:`diffkin._rigid`).
The kinds: :class:`~diffkin.ik._terms.pose.PoseTarget` (a frame's pose or position in the world,
weighted per axis), :class:`~diffkin.ik._terms.relative.RelativeTarget` (the pose of one frame in
another).
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import jax

from diffkin import _rigid as rg


class Rows(NamedTuple):
    """A term's residual entries ``r``, its Jacobian rows ``J`` (``J[i][c]``) and its errors (metres, radians).

    A term with many rows computed together gives them as one ``block`` instead: ``(r (m, P),
    J (m, C, P))`` arrays (``J`` ``(m, 0, P)`` without Jacobian), after the entries.
    """

    r: list[rg.Entry]
    J: list[list[rg.Entry]]
    pos_err: rg.Entry
    rot_err: rg.Entry
    block: tuple[jax.Array, jax.Array] | None = None


class Term(Protocol):
    """What the solver asks of a term (see the package docstring)."""

    @property
    def frames(self) -> tuple[int | None, ...]: ...

    def bind(self, target) -> tuple: ...

    def rows(self, kin, bound: tuple, jacobian: bool) -> Rows: ...

    def screen(self, kin, bound: tuple) -> rg.Entry: ...
