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


def evaluate(problem: Problem, q: jax.Array) -> Eval:
    """Residual, weighted Jacobian and errors at ``q`` ``(dof, P)``, from one forward pass."""
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
    m, n = len(r), len(J[0])
    cost = rg.add(*(rg.mul(e, e) for e in r))
    # Materialised: XLA's CPU fusion would otherwise recompute the whole forward pass inside
    # every kernel of the solver that consumes these entries (20x slower).
    flat = materialize([*r, *(e for row in J for e in row), cost, pos_err, rot_err])
    return Eval(flat[:m], flat[m : m + m * n].reshape(m, n, -1), *flat[m + m * n :])


def gradient(ev: Eval) -> jax.Array:
    """``(dof, P)`` gradient of ``cost / 2`` with respect to ``q``: ``-J^T r`` (exact, SO(3) log included)."""
    return -jnp.sum(ev.J * ev.r[:, None], axis=0)
