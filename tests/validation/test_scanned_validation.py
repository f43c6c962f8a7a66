"""The scanned forward pass (``diffkin/models/_scanned.py``, taken by robots and chains with more than 32 joints
on one path) against the unrolled one, both forced on the same models: a tree with a mimic joint on a floating
root, DH and PoE chains; gradients; long chains against the robot path; IK of a long robot
(``tests/validation/test_robot_validation.py``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import PANDA, random_robot_q, snake_robot
from _reference import dh_fk

import diffkin as dk
from diffkin import se3
from diffkin.models import _scanned


@pytest.fixture(scope="module")
def scanned_and_unrolled():
    """The Panda (a tree, one mimic joint) on a floating root, taken once by each pass."""
    robot = dk.load_robot(PANDA, floating=True)
    return robot, lambda fn, *args: _with_long(0, fn, *args), lambda fn, *args: _with_long(10**9, fn, *args)


def _with_long(long: int, fn, *args):
    """``fn(*args)``, jitted and traced afresh, with every robot deeper than ``long`` joints scanned."""
    saved = _scanned.LONG
    _scanned.LONG = long
    try:
        return jax.jit(lambda *a: fn(*a))(*args)
    finally:
        _scanned.LONG = saved


def test_the_scanned_pass_equals_the_unrolled_pass_on_a_tree(scanned_and_unrolled):
    """Every frame, two frames' Jacobians in each reference frame (base columns included), the centre of
    mass and its Jacobian: the scanned pass equals the unrolled one (float64, 1e-12)."""
    dtype = np.float64
    robot, scanned, unrolled = scanned_and_unrolled
    rng = np.random.default_rng(1)
    q = random_robot_q(robot, 5, seed=1).astype(dtype)
    base = np.stack([np.eye(4)] * 5)
    base[:, :3, :3] = np.asarray(jax.vmap(lambda w: jax.scipy.linalg.expm(se3.skew(w)))(rng.normal(size=(5, 3))))
    base[:, :3, 3] = rng.normal(size=(5, 3))
    base = base.astype(dtype)
    tol = 1e-12
    frames = ("panda_rightfinger", "panda_link3")

    def everything(q, base):
        return {
            "link_poses": dk.link_poses(robot, q, base=base),
            "fk": dk.fk(robot, q, ["panda_hand_tcp", "panda_rightfinger"], base=base),
            "com": dk.com(robot, q),
            "com_jacobian": dk.com_jacobian(robot, q, include_base=True),
            **{
                f"jacobian {name} {ref}": dk.jacobian(robot, q, name, ref, base=base, include_base=True)
                for name in frames
                for ref in ("world", "space", "body")
            },
        }

    a, b = scanned(everything, q, base), unrolled(everything, q, base)
    for name in a:
        assert a[name].dtype == b[name].dtype == dtype
        np.testing.assert_allclose(a[name], b[name], atol=tol, err_msg=name)


def test_scanned_gradients_with_respect_to_q_and_the_model(scanned_and_unrolled):
    """Reverse mode through the scan (with respect to ``q`` and to the robot's own arrays, the robot traced
    as a ``jit`` argument) equals the unrolled pass's gradients."""
    robot, scanned, _ = scanned_and_unrolled
    q = jnp.asarray(random_robot_q(robot, 4, seed=2))

    def loss(robot, q):
        T = dk.fk(robot, q, ["panda_hand_tcp", "panda_leftfinger"])
        return jnp.sum(T[..., :3, :] ** 2 * jnp.arange(1.0, 13.0).reshape(3, 4)) + jnp.sum(dk.com(robot, q))

    grad = jax.grad(loss, argnums=(0, 1))
    # The unrolled reference op by op: jitted with the robot traced, XLA takes minutes to compile it.
    (g_robot, g_q), (h_robot, h_q) = scanned(grad, robot, q), grad(robot, q)
    np.testing.assert_allclose(g_q, h_q, atol=1e-11)
    for name in ("joint_poses", "screws", "multipliers", "offsets", "frame_poses", "masses", "body_coms"):
        np.testing.assert_allclose(getattr(g_robot, name), getattr(h_robot, name), atol=1e-11, err_msg=name)


def _dh_chain(n: int, seed: int):
    """A DH chain of ``n`` joints (every fifth prismatic), random parameters, a base and a tool off the identity."""
    rng = np.random.default_rng(seed)
    table = np.stack([rng.uniform(0, 0.1, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0, 0.1, n), np.zeros(n)], 1)
    kinds = "".join("P" if i % 5 == 2 else "R" for i in range(n))
    base, tool = np.eye(4), np.eye(4)
    base[:3, 3], tool[:3, 3] = [0.1, -0.2, 0.3], [0.0, 0.0, 0.05]
    base[:3, :3] = np.asarray(jax.scipy.linalg.expm(se3.skew(np.array([0.3, 0.2, -0.1]))))
    return dk.DHChain.from_table(
        table, joint_types=kinds, lower=-np.ones(n), upper=np.ones(n), base=base, tool=tool, modified=bool(seed % 2)
    )


@pytest.mark.parametrize("kind", ["standard DH", "modified DH", "PoE"])
def test_long_chains_scanned_equal_unrolled(kind):
    """Chains of more than 32 joints are scanned too: FK, link poses (DH frame 0 the chain's base) and the
    Jacobian in each reference frame equal the unrolled product's (float64, 1e-12; 12 joints, both passes
    forced: the unrolled one compiles in minutes at 40)."""
    chain = snake_robot(12).chain("l12") if kind == "PoE" else _dh_chain(12, seed=int(kind == "modified DH"))
    q = np.random.default_rng(4).uniform(-1, 1, (3, 12))

    def everything(q):
        out = {"fk": dk.fk(chain, q), "link_poses": dk.link_poses(chain, q)}
        return out | {ref: dk.jacobian(chain, q, frame=ref) for ref in ("world", "space", "body")}

    a, b = _with_long(0, everything, q), _with_long(10**9, everything, q)
    for name in a:
        np.testing.assert_allclose(a[name], b[name], atol=1e-12, err_msg=name)
    if kind != "PoE":
        np.testing.assert_allclose(a["link_poses"][:, 0], np.broadcast_to(chain.base, (3, 4, 4)), atol=1e-15)


def test_a_long_chain_is_the_robot_path():
    """The PoE chain of a 300-joint snake (``robot.chain``, scanned: it hung before) and a 300-joint DH chain
    (its own closed form is the unrolled product at a few configurations, eager): FK and the Jacobian."""
    n = 300
    robot = snake_robot(n)
    chain = robot.chain(f"l{n}")
    q = np.random.default_rng(5).uniform(-1, 1, (2, n))
    both = jax.jit(lambda q: (dk.fk(chain, q), dk.jacobian(chain, q), dk.link_poses(chain, q)))(q)
    np.testing.assert_allclose(both[0], dk.fk(robot, q, f"l{n}"), atol=1e-10)
    np.testing.assert_allclose(both[1], dk.jacobian(robot, q, f"l{n}"), atol=1e-10)
    np.testing.assert_allclose(both[2][:, 1:], dk.link_poses(robot, q)[:, 1:], atol=1e-10)
    dh = _dh_chain(n, seed=6)
    T = jax.jit(lambda q: dk.fk(dh, q))(q)
    for k in range(len(q)):
        np.testing.assert_allclose(T[k], dh_fk(dh, q[k]), atol=1e-10)
