"""Jacobians in three frames, manipulability, and gradients with respect to model parameters (against
Pinocchio and pytorch-kinematics: ``tests/validation/test_jacobian_validation.py``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import BUILTIN, CHAIN_KINDS, URDF_ROBOTS, every_model_kind, jacobian_parameter_gradients, random_q

import diffkin as dk
from diffkin import se3

FRAMES = ("world", "space", "body")


def _models():
    prismatic = dk.DHChain.from_table(
        [[0.1, np.pi / 2, 0.3, 0.2], [0.2, -0.4, 0.1, 0], [0.3, 0.7, 0.2, 0.1]],
        "RPR",
        lower=[-2, -0.5, -2],
        upper=[2, 0.5, 2],
    )
    models = {name: getattr(dk.robots, name)() for name in BUILTIN}
    models["rpr"] = prismatic
    models["rpr_poe"] = dk.to_poe(prismatic)
    models["iiwa14_urdf"] = dk.load_urdf(*URDF_ROBOTS["iiwa14"])
    return models


MODELS = _models()


@pytest.mark.parametrize("name", list(MODELS))
def test_analytic_equals_autodiff_and_frames_are_consistent(name):
    chain = MODELS[name]
    q = random_q(chain, 50, seed=22)
    J = {f: np.asarray(dk.jacobian(chain, q, f, method="autodiff")) for f in FRAMES}
    for f in FRAMES:
        np.testing.assert_allclose(dk.jacobian(chain, q, f, method="analytic"), J[f], atol=1e-13)
        np.testing.assert_array_equal(dk.jacobian(chain, q, f), dk.jacobian(chain, q, f, method="analytic"))
    T = np.asarray(dk.fk(chain, q))
    np.testing.assert_allclose(se3.adjoint(T) @ J["body"], J["space"], atol=1e-13)  # J_s = Ad(T) J_b
    v, w = J["space"][:, :3], J["space"][:, 3:]
    p = np.broadcast_to(T[:, :3, 3, None], v.shape)
    np.testing.assert_allclose(J["world"][:, :3], v + np.cross(w, p, axis=1), atol=1e-13)
    np.testing.assert_allclose(J["world"][:, 3:], w, atol=0)


@pytest.mark.parametrize("name", ["iiwa14", "rpr_poe"])
def test_second_derivatives_of_fk_against_finite_differences(name):
    """Hessians through the forward pass (every joint's sine and cosine come from one stacked call
    with its own derivative rule) equal central differences of the gradient, float64."""
    chain = MODELS[name]

    def height(q):  # the end effector's z plus a rotation entry: both depend on every joint
        T = dk.fk(chain, q)
        return T[2, 3] + 0.3 * T[0, 2]

    hessian = jax.jit(jax.hessian(height))
    grads = jax.jit(jax.vmap(jax.grad(height)))  # the gradient at every perturbed q in one call
    h = 1e-6
    steps = h * np.eye(chain.dof)  # row i: the step in joint i
    for q in random_q(chain, 5, seed=31):
        H = np.asarray(hessian(jnp.asarray(q)))
        g = np.asarray(grads(jnp.asarray(np.concatenate([q + steps, q - steps]))))
        for i in range(chain.dof):
            fd = (g[i] - g[chain.dof + i]) / (2 * h)
            np.testing.assert_allclose(H[:, i], fd, atol=1e-8)
        np.testing.assert_allclose(H, H.T, atol=1e-12)


@pytest.mark.parametrize("name", ["iiwa14", "panda", "rpr_poe"])
def test_world_jacobian_columns_against_finite_differences(name):
    chain = MODELS[name]
    q = random_q(chain, 30, seed=23)
    J = np.asarray(dk.jacobian(chain, q, "world"))
    T = np.asarray(dk.fk(chain, q))
    h = 1e-6
    for i in range(chain.dof):
        dq = np.zeros(chain.dof)
        dq[i] = h
        Tp, Tm = np.asarray(dk.fk(chain, q + dq)), np.asarray(dk.fk(chain, q - dq))
        dT = (Tp - Tm) / (2 * h)
        w_fd = se3.vee(dT[:, :3, :3] @ np.swapaxes(T[:, :3, :3], 1, 2))
        np.testing.assert_allclose(J[:, :3, i], dT[:, :3, 3], atol=1e-8)
        np.testing.assert_allclose(J[:, 3:, i], w_fd, atol=1e-8)


def test_planar_2r_textbook_jacobian_and_singularity():
    a1, a2 = 0.7, 0.4
    chain = dk.robots.planar([a1, a2])
    q = random_q(chain, 50, seed=24)
    q[:2, 1] = [0.0, np.pi]  # the singular configurations
    J = np.asarray(dk.jacobian(chain, q))
    t1, t2 = q[:, 0], q[:, 1]
    s1, c1, s12, c12 = np.sin(t1), np.cos(t1), np.sin(t1 + t2), np.cos(t1 + t2)
    expected = np.stack(
        [np.stack([-a1 * s1 - a2 * s12, -a2 * s12], -1), np.stack([a1 * c1 + a2 * c12, a2 * c12], -1)], 1
    )
    np.testing.assert_allclose(J[:, :2], expected, atol=1e-14)
    np.testing.assert_allclose(J[:, 2:5], 0.0, atol=0)
    np.testing.assert_allclose(J[:, 5], 1.0, atol=0)
    np.testing.assert_allclose(np.linalg.det(J[:, :2]), a1 * a2 * np.sin(t2), atol=1e-14)
    assert np.abs(np.linalg.det(J[:2, :2])).max() < 1e-15
    # manipulability of a planar arm: sqrt(det(J^T J)) = |a1 a2 sin t2| (with the unit w rows included: see below)
    m = np.asarray(dk.manipulability(chain, q))
    np.testing.assert_allclose(m, np.sqrt(np.linalg.det(np.swapaxes(J, 1, 2) @ J)), atol=1e-13)


@pytest.mark.parametrize("name", ["iiwa14", "panda", "ur5"])
def test_manipulability_against_numpy(name):
    chain = MODELS[name]
    q = random_q(chain, 50, seed=25)
    J = np.asarray(dk.jacobian(chain, q))
    expected = np.sqrt(np.linalg.det(J @ np.swapaxes(J, 1, 2)))
    np.testing.assert_allclose(dk.manipulability(chain, q), expected, rtol=1e-10)
    np.testing.assert_allclose(dk.manipulability(chain, q), np.prod(np.linalg.svd(J, compute_uv=False), -1), rtol=1e-9)


def test_manipulability_finite_at_the_stretched_iiwa():
    chain = dk.robots.iiwa14()
    q0 = jnp.zeros(7)
    m = dk.manipulability(chain, q0)
    assert m == 0.0
    g = jax.grad(lambda q: dk.manipulability(chain, q))(q0)
    assert np.all(np.isfinite(g))
    # near the elbow singularity (theta4 -> 0, shoulder and wrist bent) it shrinks linearly, gradient finite
    near = jnp.array([0.0, 0.5, 0.0, 1e-4, 0.0, 0.5, 0.0])
    m_near, m_ten = dk.manipulability(chain, near), dk.manipulability(chain, near.at[3].set(1e-3))
    assert 0 < m_near and abs(m_ten / m_near - 10) < 1e-2
    assert np.all(np.isfinite(jax.grad(lambda q: dk.manipulability(chain, q))(near)))


@pytest.mark.parametrize("shape", [(), (4,), (2, 3)])
def test_jacobian_batch_shapes(shape):
    chain = MODELS["panda"]
    q = random_q(chain, int(np.prod(shape)), seed=26).reshape(shape + (7,))
    flat = np.stack([np.asarray(dk.jacobian(chain, qi, "body")) for qi in q.reshape(-1, 7)])
    for method in ("autodiff", "analytic"):
        J = dk.jacobian(chain, q, "body", method=method)
        assert J.shape == shape + (6, 7)
        np.testing.assert_allclose(np.asarray(J).reshape(-1, 6, 7), flat, atol=1e-14)
    assert dk.manipulability(chain, q).shape == shape


@every_model_kind(*CHAIN_KINDS)
@pytest.mark.parametrize("method", ["autodiff", "analytic"])
def test_jacobian_jit_vmap_and_float32(model, method):
    chain = model
    q = random_q(chain, 6, seed=26)
    ref = dk.jacobian(chain, q, "body", method=method)
    fn = jax.jit(lambda x: dk.jacobian(chain, x, "body", method=method))
    np.testing.assert_allclose(fn(q), ref, atol=1e-14)
    np.testing.assert_allclose(jax.vmap(dk.jacobian, (None, 0, None))(chain, q, "body"), ref, atol=1e-14)
    J32 = fn(jnp.asarray(q, jnp.float32))
    assert J32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(J32, np.float64), ref, atol=1e-5)


# --- gradients with respect to model parameters ----------------------------------------------


def _fd_check(chain, field, q, seed, h=1e-6, atol=1e-7):
    """``jax.grad`` of a random linear function of ``fk(chain.replace(field=x), q)`` vs central differences."""
    W = np.random.default_rng(seed).normal(size=q.shape[:-1] + (4, 4))

    def loss(x):
        return jnp.sum(W * dk.fk(chain.replace(**{field: x}), q))

    x0 = np.asarray(getattr(chain, field), dtype=np.float64)
    g = np.asarray(jax.jit(jax.grad(loss))(jnp.asarray(x0)))
    assert np.all(np.isfinite(g))
    steps = h * np.eye(x0.size).reshape((x0.size,) + x0.shape)  # one perturbation per entry
    values = np.asarray(jax.jit(jax.vmap(loss))(np.concatenate([x0 + steps, x0 - steps])))
    fd = (values[: x0.size] - values[x0.size :]).reshape(x0.shape) / (2 * h)
    np.testing.assert_allclose(g, fd, atol=atol)


@pytest.mark.parametrize("field", ["a", "alpha", "d", "theta_offset", "base", "tool"])
@pytest.mark.parametrize("name", ["iiwa14", "panda"])
def test_dh_parameter_gradients(name, field):
    chain = MODELS[name]
    _fd_check(chain, field, random_q(chain, 5, seed=27), seed=28)


@pytest.mark.parametrize("name, field", [("rpr_poe", "screws"), ("rpr_poe", "home"), ("iiwa14_urdf", "home")])
def test_poe_and_urdf_parameter_gradients(name, field):
    chain = MODELS[name]
    _fd_check(chain, field, random_q(chain, 5, seed=29), seed=30)


@pytest.mark.parametrize("name, field", [("iiwa14", "a"), ("rpr", "base")])
def test_jacobian_parameter_gradients_agree_between_methods(name, field):
    """Calibrating through a Jacobian: the default (analytic) and autodiff give the same parameter gradient.

    The base is moved rigidly (:func:`_models.jacobian_parameter_gradients`). The traced base of
    the 7-joint iiwa14 compiles its autodiff second derivatives for ~15 s: it is checked in
    ``tests/validation/test_jacobian_validation.py``; the 3-joint chain here takes the same path. (Traced
    PoE screws agree too, measured, but compiling their second derivatives took 88 s: not in the suite.)
    """
    g = jacobian_parameter_gradients(MODELS[name], field, seed=32)
    assert np.all(np.isfinite(g["analytic"])) and np.abs(g["analytic"]).max() > 1e-3
    np.testing.assert_allclose(g["analytic"], g["autodiff"], atol=1e-12)


def test_to_poe_is_differentiable():
    chain = MODELS["iiwa14"]
    q = random_q(chain, 5, seed=31)

    def via_poe(d):
        return jnp.sum(dk.fk(dk.to_poe(chain.replace(d=d)), q)[..., :3, 3])

    def direct(d):
        return jnp.sum(dk.fk(chain.replace(d=d), q)[..., :3, 3])

    np.testing.assert_allclose(jax.grad(via_poe)(chain.d), jax.grad(direct)(chain.d), atol=1e-12)


@pytest.mark.parametrize("name", ["iiwa14", "panda"])
def test_link_frame_columns_of_the_forward_pass(name):
    """A chain's ``forward(q).columns(i)`` (link frame ``i``: joints before it move it, the others give zero
    columns) against forward-mode autodiff of that link's pose, every link, DH and its PoE conversion."""
    from diffkin import _rigid as rg

    for chain in (getattr(dk.robots, name)(), dk.to_poe(getattr(dk.robots, name)())):
        q = jnp.asarray(random_q(chain, 1, seed=5)[0])
        for i in range(chain.dof + 1):
            kin = chain.forward(list(q))
            T = kin.pose(i)
            columns = rg.world_from_space(kin.columns(i), T.p)
            J = np.asarray([[float(c[part][k]) for c in columns] for part in (0, 1) for k in range(3)])

            def pose(q, i=i, chain=chain):
                return dk.link_poses(chain, q)[i]

            dT = np.moveaxis(np.asarray(jax.jacfwd(pose)(q)), -1, 0)  # (dof, 4, 4)
            R = np.asarray(pose(q))[:3, :3]
            v = dT[:, :3, 3].T
            w = np.stack([se3.vee(jnp.asarray(d[:3, :3] @ R.T)) for d in dT], axis=1)
            np.testing.assert_allclose(J, np.concatenate([v, w]), atol=1e-10)
