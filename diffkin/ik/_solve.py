"""``solve``: the front door (argument checks) and the solver of one chain's end effector.

A :class:`~diffkin.Robot` with a mapping of targets goes to :mod:`diffkin.ik._tree`.
"""

from __future__ import annotations

import functools
import importlib

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import real_array, rigid_poses, rigid_tol
from diffkin._rigid import is_concrete
from diffkin.ik import _lm, _rounds
from diffkin.ik._implicit import implicit_q
from diffkin.ik._problem import Problem
from diffkin.ik._result import IKResult
from diffkin.models.dh import DHChain
from diffkin.models.poe import PoEChain
from diffkin.models.robot import Robot

_METHODS = ("lm", "optax")
_DEFAULT_ITERS = {"lm": 10, "optax": 1000}


def detach(tree):
    """``stop_gradient`` on traced leaves only (concrete model constants stay foldable)."""
    return jax.tree.map(lambda x: x if is_concrete(x) else jax.lax.stop_gradient(x), tree)


def cast(tree, dtype):
    """Traced floating leaves to ``dtype``; concrete ones are folded as Python floats by the model."""
    def cast_leaf(x):
        if not is_concrete(x) and jnp.issubdtype(x.dtype, jnp.floating):
            return x.astype(dtype)
        return x
    return jax.tree.map(cast_leaf, tree)


def inward(limit, dtype, side: int) -> jax.Array:
    """``limit`` in ``dtype``, rounded towards the inside of the range (``side`` -1: lower, +1: upper)."""
    limit = jnp.asarray(limit)
    rounded = limit.astype(dtype)
    outside = side * (rounded.astype(limit.dtype) - limit) > 0
    return jnp.where(outside, jnp.nextafter(rounded, jnp.asarray(-side * jnp.inf, dtype)), rounded)


def method_steps(method: str, optimizer):
    """``(init, step_fn)`` of the method (see :func:`diffkin.ik._rounds.search`)."""
    if method == "lm":
        return _lm.init, _lm.step
    _optax = optax_module()
    opt = _optax.default_optimizer() if optimizer is None else optimizer
    return functools.partial(_optax.init, opt), functools.partial(_optax.step, opt)


def _check_args(chain, target, q0, num_seeds, method, max_iters, pos_tol, rot_tol, optimizer):
    """Host-side checks; returns the target array and its kind (``True`` for position targets)."""
    if not isinstance(chain, (DHChain, PoEChain)):
        hint = " (for a frame of a whole robot, solve robot.chain(frame_name))" if isinstance(chain, Robot) else ""
        raise TypeError(f"chain: expected a DHChain or PoEChain{hint}, got {type(chain).__name__}")
    if method not in _METHODS:
        raise ValueError(f"method: expected one of {_METHODS}, got {method!r}")
    for name, value, low in (("num_seeds", num_seeds, 1), ("max_iters", max_iters, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
    for name, value in (("pos_tol", pos_tol), ("rot_tol", rot_tol)):
        if isinstance(value, jax.Array) and value.shape == () and not jnp.issubdtype(value.dtype, jnp.complexfloating):
            if not is_concrete(value):
                continue  # a traced tolerance (a jit argument): its value is not known here
            value = value.item()
        if not isinstance(value, (int, float, np.floating, np.integer)) or not value >= 0:
            raise ValueError(f"{name}: expected a non-negative number, got {value!r}")
    if method == "optax":
        optax_module()  # ImportError with the extra to install, before tracing
    if optimizer is not None:
        if method != "optax":
            raise ValueError(f"optimizer: only used with method='optax', got method={method!r}")
        import optax

        if not isinstance(optimizer, optax.GradientTransformation):
            raise TypeError(f"optimizer: expected an optax.GradientTransformation, got {type(optimizer).__name__}")
    target = real_array(target, "target", "poses or positions")
    if jnp.finfo(target.dtype).bits < 32:
        # float16 rounding (~5e-4 m at 1 m) exceeds the default tolerances: errors would read 0.
        raise TypeError(f"target: expected float32 or float64, got {target.dtype} (cast it to float32)")
    if target.ndim >= 2 and target.shape[-2:] == (4, 4):
        position_only = False
    elif target.ndim >= 1 and target.shape[-1] == 3:
        position_only = True
    else:
        raise ValueError(f"target: expected shape (..., 4, 4) for poses or (..., 3) for positions, got {target.shape}")
    batch = target.shape[:-1] if position_only else target.shape[:-2]
    if not position_only and is_concrete(target):
        bad = ~np.asarray(rigid_poses(target)) & np.all(np.isfinite(np.asarray(target)), axis=(-2, -1))
        if np.any(bad):  # non-finite targets are not errors: they fail (success=False)
            i = tuple(int(k) for k in np.argwhere(bad)[0])
            raise ValueError(f"target[{', '.join(map(str, i))}]: expected a rigid transform (R^T R = I, det R = +1, "
                             f"last row [0, 0, 0, 1], within {rigid_tol(target.dtype):g}), "
                             f"got {np.asarray(target)[i].tolist()}")
    if q0 is not None:
        q0_shape = np.shape(q0)
        if len(q0_shape) == 0 or q0_shape[-1] != chain.dof:
            raise ValueError(f"q0: expected shape (..., {chain.dof}) for a {chain.dof}-joint chain, got {q0_shape}")
        try:
            fits = np.broadcast_shapes(q0_shape[:-1], batch) == batch
        except ValueError:
            fits = False
        if not fits:
            raise ValueError(f"q0: batch shape {q0_shape[:-1]} does not broadcast to the targets' {batch}")
    return target, position_only, batch


def solve(chain, target, *, key=None, q0=None, num_seeds: int = 32, method: str = "lm", max_iters: int | None = None,
          pos_tol: float = 1e-5, rot_tol: float = 1e-4, respect_limits: bool = True, optimizer=None) -> IKResult:
    """Inverse kinematics for a batch of targets, from random seeds (and an optional warm start).

    Every target gets up to ``num_seeds`` seeds, each the best (least pose error) of 8
    configurations drawn uniformly within the limits, in rounds of 4: the first round (plus
    ``q0`` when given) for every target at once, each later one only for the targets still
    unsolved, packed into small chunks; with LM, three final rounds go on from the best seed so
    far and small perturbations of it. Each round iterates its seeds together in a
    ``lax.while_loop`` that exits when every target in it is done, so easy targets cost one
    round and only hard (or unreachable) ones cost more. A target's
    result does not depend on the rest of the batch. Pure and traceable:
    works under ``jit``/``vmap``/``grad``; ``num_seeds``, ``method``, ``max_iters``,
    ``respect_limits`` and ``optimizer`` are static. Nothing raises inside ``jit``: a target
    that cannot be reached (or holds NaN) gives ``success=False`` and finite values.

    The residual is ``[p_t - p; 0.2 m/rad * log(R_t R^T)]`` (world frame). ``method="lm"``
    takes Levenberg-Marquardt steps ``dq = J^T (J J^T + lam I)^-1 r`` (or the ``dof x dof``
    form, whichever is smaller) with error-proportional damping ``lam = mu |r|^2`` adapted by
    accepting only steps that lower ``|r|^2``. ``method="optax"`` follows the exact gradient of
    ``|r|^2 / 2`` with an optax transformation; it needs far more iterations than LM for the
    same accuracy and is meant for combining with costs of your own. Iterates are projected:
    unlimited revolute joints wrap to ``[-pi, pi)`` and, with ``respect_limits``, every joint is
    clipped to ``[lower, upper]``.

    The returned ``q`` is differentiable with respect to ``target`` and the chain's parameters
    through the implicit function theorem (``dq = J^+ dx``, see :func:`implicit_q`), not through
    the iterations; the derivative is that of a successful, non-singular solution off the limits.

    Args:
        chain: a :class:`~diffkin.DHChain` or :class:`~diffkin.PoEChain`.
        target: ``(..., 4, 4)`` end-effector poses ``T_base_ee`` or ``(..., 3)`` positions in the
            base frame (metres; orientation free). The solver runs in this dtype (float32 default).
        key: PRNG key for the seeds; default ``jax.random.key(0)``. Target ``b`` of the flattened
            batch draws round ``r``'s seeds from ``fold_in(fold_in(key, b), r)``.
        q0: optional ``(..., dof)`` warm start broadcastable to the targets' batch; it is an extra
            seed and, among successful seeds, the solution nearest to ``q0`` is returned.
        num_seeds: most random seeds per target (static, >= 1), in rounds of 4; only unsolved
            targets use more than the first round.
        method: ``"lm"`` (default) or ``"optax"``.
        max_iters: iterations per seed (static); default 10 for LM, 1000 for optax. Each
            iteration is one forward pass.
        pos_tol: success tolerance on the position error, metres (may be a traced scalar: one
            compilation serves every tolerance).
        rot_tol: success tolerance on the rotation angle error, radians (may be traced).
        respect_limits: keep every iterate (and the result) within ``[chain.lower, chain.upper]``.
        optimizer: an ``optax.GradientTransformation`` for ``method="optax"``; default
            ``optax.adam(1e-2)``.

    Returns:
        :class:`IKResult`, each field with the batch shape of ``target``. Without a success the
        seed of least residual is returned. Non-finite targets give ``success=False``, ``q`` of
        that seed and errors ``finfo(dtype).max``.

    Raises:
        ValueError: a bad target shape, ``q0`` of the wrong length or batch, an unknown method,
            ``num_seeds < 1``, ``max_iters < 0``, negative tolerances, ``optimizer`` without
            ``method="optax"``.
        ValueError: also a concrete pose target that is not a rigid transform (within 1e-5 in
            float32, 1e-9 in float64), naming its batch index; traced ones give ``success=False``.
        TypeError: a chain that is not a chain model, an optimizer that is not an optax
            ``GradientTransformation``, a bool, complex or float16 target.
    """
    max_iters = _DEFAULT_ITERS[method] if max_iters is None and method in _METHODS else max_iters
    target, position_only, batch = _check_args(
        chain, target, q0, num_seeds, method, max_iters, pos_tol, rot_tol, optimizer)
    if 0 in batch:  # no targets: empty results of the batch's shape
        empty = lambda *shape, dtype=target.dtype: jnp.zeros(batch + shape, dtype)  # noqa: E731
        return IKResult(empty(chain.dof), empty(dtype=bool), empty(), empty(), empty(dtype=jnp.int32))
    known, traced = _split_chain(chain)
    return _solve(known, traced, target, jax.random.key(0) if key is None else key,
                  None if q0 is None else jnp.asarray(q0), jnp.asarray(pos_tol, target.dtype),
                  jnp.asarray(rot_tol, target.dtype), num_seeds=int(num_seeds), method=method,
                  max_iters=int(max_iters), respect_limits=bool(respect_limits), optimizer=optimizer,
                  position_only=position_only, batch=tuple(batch))


class _KnownLeaves:
    """The concrete leaves of a chain (and its structure), hashed and compared by value.

    It is a static argument of the jitted :func:`_solve`: equal chains (by structure and
    numbers) share one compilation, and their numbers stay trace-time constants that the
    forward pass folds (as for a chain closed over by ``jit``).
    """

    def __init__(self, treedef, leaves: tuple):
        self.treedef, self.leaves = treedef, leaves
        self._key = (treedef, tuple(None if x is None else (np.asarray(x).dtype.str, np.shape(x),
                                                           bool(getattr(x, "weak_type", False)),
                                                           np.asarray(x).tobytes()) for x in leaves))
        self._hash = hash(self._key)

    def __hash__(self):
        return self._hash

    def __eq__(self, other):
        return isinstance(other, _KnownLeaves) and self._key == other._key


def _split_chain(chain) -> tuple[_KnownLeaves, tuple]:
    """``(concrete leaves, traced leaves)`` of ``chain``, each with ``None`` in the other's slots."""
    leaves, treedef = jax.tree_util.tree_flatten(chain)
    known = tuple(x if is_concrete(x) else None for x in leaves)
    traced = tuple(None if is_concrete(x) else x for x in leaves)
    return _KnownLeaves(treedef, known), traced


def optax_module():
    """``diffkin.ik._optax`` (which needs optax), or an ImportError naming the extra to install."""
    try:
        return importlib.import_module("diffkin.ik._optax")
    except ImportError as e:
        raise ImportError("method='optax' needs optax: pip install 'diffkin[ik]' (or pip install optax)") from e


def valid_targets(flat: jax.Array, position_only: bool) -> tuple[jax.Array, jax.Array]:
    """``(valid, safe)``: which of the targets ``(n, 4, 4)``/``(n, 3)`` are finite (and rigid), and the
    targets with the others replaced by the identity (so that nothing NaN enters the solver)."""
    n = flat.shape[0]
    valid = jnp.all(jnp.isfinite(flat.reshape(n, -1)), axis=-1)
    valid = valid if position_only else valid & rigid_poses(flat)  # a non-rigid traced target fails
    identity = jnp.eye(4, dtype=flat.dtype)
    safe = jnp.where(valid.reshape((n,) + (1,) * (flat.ndim - 1)), flat,
                     identity[:3, 3] if position_only else identity)
    return valid, safe


@functools.partial(jax.jit, static_argnames=("known", "num_seeds", "method", "max_iters", "respect_limits",
                                             "optimizer", "position_only", "batch"))
def _solve(known: _KnownLeaves, traced: tuple, target, key, q0, pos_tol, rot_tol, *, num_seeds, method, max_iters,
           respect_limits, optimizer, position_only, batch) -> IKResult:
    """The solver, compiled once per chain (by value), shapes and static settings.

    Every closure (problems, ranks) is built here, inside the trace, so that repeated eager
    calls of :func:`solve` hit jit's cache instead of retracing and recompiling.
    """
    chain = jax.tree_util.tree_unflatten(
        known.treedef, [t if k is None else k for k, t in zip(known.leaves, traced, strict=True)])
    dtype = target.dtype
    dof = chain.dof
    n = int(np.prod(batch, dtype=np.int64))
    valid, safe = valid_targets(target.reshape((n,) + target.shape[len(batch):]), position_only)
    model = cast(detach(chain), dtype)
    lower, upper = inward(detach(chain.lower), dtype, -1), inward(detach(chain.upper), dtype, 1)
    wrap = jnp.asarray([t == "R" for t in chain.joint_types]) & ~jnp.isfinite(lower) & ~jnp.isfinite(upper)
    fixed = detach(safe)
    q0_flat = None
    if q0 is not None:
        q0_flat = jnp.broadcast_to(jnp.asarray(q0, dtype), batch + (dof,)).reshape(n, dof)
        q0_flat = jnp.where(jnp.isfinite(q0_flat), detach(q0_flat), 0.0)

    def build(idx, copies: int) -> Problem:
        T = jnp.broadcast_to(fixed[idx], (copies,) + fixed[idx].shape).reshape((copies * idx.shape[0],)
                                                                                + fixed.shape[1:])
        p = tuple(T[:, i] if position_only else T[:, i, 3] for i in range(3))
        R = None if position_only else tuple(tuple(T[:, i, j] for j in range(3)) for i in range(3))
        return Problem(model, p, R, lower, upper, wrap, respect_limits)

    def rank(idx, q):  # among successes: nearest the warm start
        return None if q0_flat is None else jnp.sum((q - q0_flat[idx].T[:, None, :]) ** 2, axis=0)

    init, step_fn = method_steps(method, optimizer)
    settings = _rounds.Settings(num_seeds, max_iters, _rounds.POLISH if method == "lm" else 0, pos_tol, rot_tol)
    best = _rounds.search(build, lambda idx, q: q, rank, key, n, lower, upper, q0_flat, init, step_fn, settings)
    big = jnp.finfo(dtype).max
    q_best = implicit_q(chain, safe, best.x.T)
    return IKResult(
        q=q_best.reshape(batch + (dof,)),
        success=(best.success & valid).reshape(batch),
        pos_err=jnp.where(valid, best.ev.pos_err, big).reshape(batch),
        rot_err=jnp.where(valid, best.ev.rot_err, big).reshape(batch),
        iters=best.iters.reshape(batch),
    )
