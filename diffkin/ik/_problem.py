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
from diffkin._trig import atan2

#: Metres per radian in the residual: the rotation error enters as ``ROT_WEIGHT * angle``, so a
#: 1e-4 rad rotation error counts like a 2e-5 m position error (about a tenth of an arm's reach).
ROT_WEIGHT = 0.2


class Eval(NamedTuple):
    """The residual at configurations ``q``: ``r = [p_t - p; ROT_WEIGHT log(R_t R^T)]``.

    Attributes:
        r: ``(m, P)`` (``m = 6`` for poses, 3 for positions).
        J: ``(m, dof, P)`` ``d(-r)/dq``: the world Jacobian, rotation rows weighted.
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

    chain: object
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
        cost = sum(rg.add(self.p[i], -ee.p[i]) ** 2 for i in range(3))
        if self.R is not None:
            trace = rg.add(*(rg.mul(ee.R[i][j], self.R[i][j]) for i in range(3) for j in range(3)))
            cost = cost + ROT_WEIGHT**2 * (3.0 - trace)
        return cost


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
        w, rot_err = _log(rg.matmul(problem.R, tuple(rg.column(ee.R, j) for j in range(3))))
        r = e_p + [rg.mul(ROT_WEIGHT, e) for e in w]
        J = J + [[rg.mul(ROT_WEIGHT, c[1][i]) for c in columns] for i in range(3)]
    m, n = len(r), len(J[0])
    cost = rg.add(*(rg.mul(e, e) for e in r))
    # Materialised: XLA's CPU fusion would otherwise recompute the whole forward pass inside
    # every kernel of the solver that consumes these entries (20x slower).
    flat = rg.materialize([*r, *(e for row in J for e in row), cost, pos_err, rot_err])
    return Eval(flat[:m], flat[m : m + m * n].reshape(m, n, -1), *flat[m + m * n :])


def _log(M: rg.Mat3) -> tuple[rg.Vec3, jax.Array]:
    """Rotation vector and angle of ``M`` (entries), elementwise; as :func:`diffkin.se3.so3_log`.

    Near the identity ``w = theta / sin(theta) vee(M)`` (series below 1e-4 rad); near a
    half-turn the axis is the column of ``(M + M^T)/2 - cos(theta) I`` of largest diagonal,
    oriented by ``vee(M)``. Written without gathers so that XLA fuses it over the batch.
    """
    v = (0.5 * rg.add(M[2][1], -M[1][2]), 0.5 * rg.add(M[0][2], -M[2][0]), 0.5 * rg.add(M[1][0], -M[0][1]))
    sin2 = rg.dot(v, v)
    sin_ = jnp.sqrt(sin2)
    cos_ = 0.5 * (rg.add(M[0][0], M[1][1], M[2][2]) - 1.0)
    theta = atan2(sin_, cos_)
    small = theta < 1e-4
    factor = jnp.where(small, 1.0 + theta * theta / 6.0, theta / jnp.where(small, 1.0, sin_))
    S = [[rg.add(0.5 * rg.add(M[i][j], M[j][i]), -cos_ if i == j else 0.0) for j in range(3)] for i in range(3)]
    first = (S[0][0] >= S[1][1]) & (S[0][0] >= S[2][2])
    second = S[1][1] >= S[2][2]
    col = [jnp.where(first, S[i][0], jnp.where(second, S[i][1], S[i][2])) for i in range(3)]
    norm = jnp.sqrt(jnp.maximum(sum(c * c for c in col), jnp.finfo(theta.dtype).tiny))
    signed = jnp.where(rg.dot(col, v) < 0, -theta, theta) / norm
    near_pi = cos_ < -0.99
    w = tuple(jnp.where(near_pi, signed * col[i], factor * v[i]) for i in range(3))
    return w, theta


def gradient(ev: Eval) -> jax.Array:
    """``(dof, P)`` gradient of ``cost / 2`` with respect to ``q``: ``-J^T r`` (exact, SO(3) log included)."""
    return -jnp.sum(ev.J * ev.r[:, None], axis=0)
