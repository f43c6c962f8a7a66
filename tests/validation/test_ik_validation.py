"""dk.ik.solve on the robots: round trips of 1,000 poses checked by independent FK (pytorch-kinematics /
NumPy DH, float64), position targets, and the optax method."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
import pytorch_kinematics as pk
import torch
from _reference import URDF_ROBOTS, dh_fk, pose_errors, random_q

import diffkin as dk
import diffkin.ik as ik

ROBOTS = ("iiwa7", "iiwa14", "panda", "ur5")


def _pk_fk(name):
    path, end = URDF_ROBOTS[name]
    with open(path, "rb") as f:
        chain = pk.build_serial_chain_from_urdf(f.read(), end).to(dtype=torch.float64)
    return lambda q: chain.forward_kinematics(torch.as_tensor(q, dtype=torch.float64)).get_matrix().numpy()


_solve32 = {}


def _solver(chain, key_name, **kw):
    """One jitted solver per (robot, settings): each configuration compiles once per module."""
    k = (key_name, tuple(sorted(kw.items())))
    if k not in _solve32:
        _solve32[k] = jax.jit(lambda target, key, q0=None: ik.solve(chain, target, key=key, q0=q0, **kw))
    return _solve32[k]


def _case(kind, name, urdf_chains):
    if kind == "builtin":
        chain = getattr(dk.robots, name)()
        return chain, lambda q: dh_fk(chain, q)
    return urdf_chains[name], _pk_fk(name)


@pytest.mark.parametrize("kind", ["builtin", "urdf"])  # urdf: vs pk
@pytest.mark.parametrize("name", ROBOTS)
def test_round_trip_success_rate_float32(kind, name, urdf_chains):
    """1,000 poses of random in-limit configurations, float32, default settings: >= 99.5 % success,
    every success confirmed by an independent float64 FK, every q within limits."""
    chain, fk64 = _case(kind, name, urdf_chains)
    q_true = random_q(chain, 1000, seed=1)
    target = fk64(q_true)
    res = _solver(chain, f"{kind}-{name}")(jnp.asarray(target, jnp.float32), jax.random.key(7))
    q = np.asarray(res.q, np.float64)
    success = np.asarray(res.success)
    assert res.q.dtype == jnp.float32 and res.q.shape == (1000, chain.dof) and success.shape == (1000,)
    assert np.all(q >= np.asarray(chain.lower)) and np.all(q <= np.asarray(chain.upper))
    pos, rot = pose_errors(fk64(q), target)
    # float32 FK rounding (~1e-7 m) separates diffkin's error from the float64 one; allow that margin only.
    assert np.all(pos[success] <= 1e-5 + 1e-6) and np.all(rot[success] <= 1e-4 + 5e-6)
    # the solver's float32 error vs float64 FK: each float32 pose is off by up to ~5e-7 m at 1 m reach
    np.testing.assert_allclose(np.asarray(res.pos_err)[success], pos[success], atol=1e-6)
    assert success.mean() >= 0.995, f"{kind} {name}: success {success.mean():.4f}"


def test_position_only_targets(urdf_chains):
    chain, fk64 = urdf_chains["iiwa14"], _pk_fk("iiwa14")
    target = fk64(random_q(chain, 200, seed=2))[:, :3, 3]
    res = jax.jit(lambda t: ik.solve(chain, t, key=jax.random.key(0), num_seeds=4))(jnp.asarray(target, jnp.float32))
    pos = np.linalg.norm(fk64(np.asarray(res.q, np.float64))[:, :3, 3] - target, axis=-1)
    assert np.all(np.asarray(res.rot_err) == 0)
    assert np.all(pos[np.asarray(res.success)] <= 1e-5 + 5e-7)
    assert np.asarray(res.success).mean() >= 0.995


def test_optax_method_reaches_loose_tolerance(urdf_chains):
    """Default Adam, 1,000 steps: a first-order method settles to ~1e-3 m (see the bench for the trade-off)."""
    chain, fk64 = urdf_chains["iiwa14"], _pk_fk("iiwa14")
    target = fk64(random_q(chain, 100, seed=11))
    res = jax.jit(lambda t: ik.solve(chain, t, method="optax", num_seeds=4, pos_tol=5e-3, rot_tol=5e-2))(
        jnp.asarray(target, jnp.float32)
    )
    success = np.asarray(res.success)
    pos, rot = pose_errors(fk64(np.asarray(res.q, np.float64)), target)
    assert np.all(pos[success] <= 5e-3 + 1e-6) and np.all(rot[success] <= 5e-2 + 1e-6)
    np.testing.assert_allclose(np.asarray(res.pos_err), pos, atol=1e-6)
    assert success.mean() >= 0.7  # measured 0.74; LM reaches 1e-5 m on all of these (see test above)
    sgd = ik.solve(chain, jnp.asarray(target[0]), method="optax", optimizer=optax.sgd(0.5), num_seeds=2, max_iters=5)
    assert sgd.q.shape == (7,) and np.isfinite(float(sgd.pos_err))
