"""The IK residual, its Jacobian and the joint-limit projection, from one forward pass.

All arrays here are flat over ``P = seeds x targets`` problems, with that axis last: ``q`` is
``(dof, P)`` and vectors and matrices are stacks of per-entry arrays (structure of arrays, as in
:mod:`diffkin._rigid`), so that one select or copy moves a whole field.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin import kinematics
from diffkin._xla import materialize
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain

#: Metres per radian in the residual: the rotation error enters as ``ROT_WEIGHT * angle``, so a
#: 1e-4 rad rotation error counts like a 2e-5 m position error (about a tenth of an arm's reach).
ROT_WEIGHT = 0.2


class Eval(NamedTuple):
    """The residual at configurations ``q``: ``r = [p_t - p; ROT_WEIGHT log(R_t R^T)]``.

    Attributes:
        r: ``(m, P)`` (``m = 6`` for poses, 3 for positions).
        J: ``(m, dof, P)`` ``d(-r)/dq``: the world Jacobian, rotation rows weighted (``(m, 0, P)``
            where only the cost is needed).
        cost: ``(P,)`` ``|r|^2``.
        pos_err: ``(P,)`` metres.
        rot_err: ``(P,)`` radians.
    """

    r: jax.Array
    J: jax.Array
    cost: jax.Array
    pos_err: jax.Array
    rot_err: jax.Array


class Entries(NamedTuple):
    """The fields of an :class:`Eval` before they are computed into arrays: one entry (an array of
    the problem shape, or a folded Python float) per value, ``J`` row by row; ``pos_err`` and
    ``rot_err`` one entry, or a list of one per target of a tree (see :func:`settle`)."""

    r: list
    J: list
    cost: rg.Entry
    pos_err: rg.Entry | list
    rot_err: rg.Entry | list


class Problem(NamedTuple):
    """A flat batch of targets with the chain and its limits, all in one dtype.

    Attributes:
        chain: the chain model.
        p: target position entries, each ``(P,)``.
        R: target rotation entries ``3 x 3``, each ``(P,)``, or ``None`` for position targets.
        lower, upper: ``(dof,)`` limits used for the projection (``-inf``/``inf`` if unlimited).
        wrap: ``(dof,)`` bool, unlimited revolute joints (wrapped to ``[-pi, pi)``).
        respect_limits: static; clip every iterate to ``[lower, upper]``.
    """

    chain: DHChain | PoEChain
    p: tuple
    R: tuple | None
    lower: jax.Array
    upper: jax.Array
    wrap: jax.Array
    respect_limits: bool

    def project(self, q: jax.Array) -> jax.Array:
        """Wrap unlimited revolute joints and (with ``respect_limits``) clip to the limits."""
        return project(q, self.lower, self.upper, self.wrap, self.respect_limits)

    def retract(self, q: jax.Array, dq: jax.Array) -> jax.Array:
        """``q + dq``, projected."""
        return self.project(q + dq)

    def evaluate(self, q: jax.Array) -> Eval:
        return evaluate(self, q)

    def residual(self, q: jax.Array) -> Entries:
        return residual(self, q)

    def screen_cost(self, q: jax.Array) -> jax.Array:
        """``(P,)`` cheap cost for choosing seeds: ``|p_t - p|^2 + ROT_WEIGHT^2 (3 - trace(R_t^T R))``.

        One forward pass without Jacobian; the rotation term is ``2 (1 - cos angle)``, the
        squared angle near 0.
        """
        ee = self.chain._frames(list(q)).ee
        terms = [rg.add(self.p[i], -ee.p[i]) ** 2 for i in range(3)]
        if self.R is not None:
            trace = rg.add(*(rg.mul(ee.R[i][j], self.R[i][j]) for i in range(3) for j in range(3)))
            terms.append(ROT_WEIGHT**2 * (3.0 - trace))
        return jnp.asarray(rg.add(*terms))


def project(q: jax.Array, lower, upper, wrap, respect_limits: bool) -> jax.Array:
    """``q`` ``(dof, P)`` with unlimited revolute joints (``wrap``) wrapped to ``[-pi, pi)`` and,
    with ``respect_limits``, every joint clipped to ``[lower, upper]`` ``(dof,)``."""
    wrapped = jnp.where(wrap[:, None], jnp.mod(q + np.pi, 2 * np.pi) - np.pi, q)
    return jnp.clip(wrapped, lower[:, None], upper[:, None]) if respect_limits else wrapped


def residual(problem: Problem, q: jax.Array) -> Entries:
    """The entries of the residual, weighted Jacobian and errors at ``q`` ``(dof, P)``, from one forward pass."""
    frames = problem.chain._frames(list(q))
    shape, dtype = q.shape[1:], q.dtype
    ee = frames.ee
    columns = kinematics._world_from_space(frames.screws, ee.p)
    e_p = [rg.add(problem.p[i], -ee.p[i]) for i in range(3)]
    J = [[v[i] for v, _ in columns] for i in range(3)]
    # Capped at the largest float: a target ~1e154 m away would square to inf (issue 18: outputs stay finite).
    pos_err = jnp.minimum(jnp.sqrt(rg.add(*(rg.mul(e, e) for e in e_p))), jnp.finfo(dtype).max)
    if problem.R is None:
        r, rot_err = e_p, jnp.zeros(shape, dtype)
    else:
        w, rot_err = rg.so3_log(rg.matmul(problem.R, tuple(rg.column(ee.R, j) for j in range(3))))
        r = e_p + [rg.mul(ROT_WEIGHT, e) for e in w]
        J = J + [[rg.mul(ROT_WEIGHT, c[1][i]) for c in columns] for i in range(3)]
    return Entries(r, J, rg.add(*(rg.mul(e, e) for e in r)), pos_err, rot_err)


def evaluate(problem: Problem, q: jax.Array) -> Eval:
    """Residual, weighted Jacobian and errors at ``q`` ``(dof, P)``, from one forward pass."""
    return settle(residual(problem, q))


def _errors(e) -> list:
    """Error entries: one (a chain) or a list of one per target (a tree)."""
    return e if isinstance(e, list) else [e]


def _head(entries: Entries) -> list:
    """The residual, cost and error entries, in the order :func:`_arrays` reads them."""
    return [*entries.r, entries.cost, *_errors(entries.pos_err), *_errors(entries.rot_err)]


def _arrays(entries: Entries, head, J) -> Eval:
    """An :class:`Eval` of arrays from ``head`` (:func:`_head`, stacked) and ``J`` ``(m * n, P)``."""
    m, n = len(entries.r), len(entries.J[0]) if len(entries.J) else 0
    shape = head.shape[1:]
    errors = (len(entries.pos_err),) if isinstance(entries.pos_err, list) else ()
    k = len(_errors(entries.pos_err))
    return Eval(
        head[:m],
        J.reshape((m, n) + shape),
        head[m],
        head[m + 1 : m + 1 + k].reshape(errors + shape),
        head[m + 1 + k :].reshape(errors + shape),
    )


def settle(entries: Entries) -> Eval:
    """The entries computed once into the arrays of an :class:`Eval`."""
    head, J = _head(entries), [e for row in entries.J for e in row]
    # Materialised: XLA's CPU fusion would otherwise recompute the whole forward pass inside
    # every kernel of the solver that consumes these entries (20x slower).
    done = materialize(head + J)
    return _arrays(entries, done[: len(head)], done[len(head) :])


def settle_choosing(entries: Entries, old: Eval, choose) -> tuple[Eval, jax.Array, object]:
    """The entries computed once where ``choose`` takes them, ``old``'s values elsewhere.

    ``choose(cost)`` maps the new cost ``(P,)`` to ``(take, extra)``, ``take`` ``(P,)`` bool;
    returns ``(ev, take, extra)`` with ``take`` computed once. The residual, cost and errors are
    computed first (``choose`` reads the cost); the Jacobian's entries are then computed and
    chosen inside the same kernels. That saves writing the new Jacobian and then a pass that reads
    it with the old one and writes one, the largest memory traffic of an LM iteration
    (:func:`diffkin.ik._rounds._iterate`).
    """
    head_try = materialize(_head(entries))
    take, extra = choose(head_try[len(entries.r)])
    take = materialize([take])[0]
    shape = take.shape
    old_head = jnp.concatenate(
        [old.r, old.cost[None], old.pos_err.reshape((-1,) + shape), old.rot_err.reshape((-1,) + shape)]
    )
    J_try = [e for row in entries.J for e in row]
    J = materialize([jnp.where(take, e, o) for e, o in zip(J_try, old.J.reshape((-1,) + shape), strict=True)])
    return _arrays(entries, jnp.where(take, head_try, old_head), J), take, extra


def gradient(ev: Eval) -> jax.Array:
    """``(dof, P)`` gradient of ``cost / 2`` with respect to ``q``: ``-J^T r`` (exact, SO(3) log included)."""
    return -jnp.sum(ev.J * ev.r[:, None], axis=0)
