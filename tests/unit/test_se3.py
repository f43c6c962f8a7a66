"""Rotations and rigid transforms (``diffkin.se3``) in jaxlie's style: random, near-identity and
near-half-turn rotations over several batch shapes, derivatives against finite differences, and the
entry-wise SO(3) log (``diffkin._rigid.so3_log``, the one the IK residual uses) in float32 and float64."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from diffkin import _rigid as rg
from diffkin import se3

SHAPES = [(), (1,), (5,), (2, 3)]


def _skew(w: np.ndarray) -> np.ndarray:
    """``[w]`` in numpy: row ``i`` of ``-cross(w, I)`` is ``-(w x e_i)``."""
    return -np.cross(w[..., None, :], np.eye(3))


def _expm_skew(w: np.ndarray) -> np.ndarray:
    """``exp([w])`` in numpy (the reference rotations, compiled nowhere)."""
    return scipy.linalg.expm(_skew(w))


@jax.jit
def _angle_and_log(R):
    """``se3.rotation_angle`` and ``se3.so3_log`` of ``R``: one compile per shape, shared by the kinds."""
    return se3.rotation_angle(R), se3.so3_log(R)


def _rotations(kind: str, shape, seed=0):
    """Rotations ``exp([w])`` with ``|w|`` random in (0, pi), about 1e-9..1e-3, or pi minus that."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=shape + (3,))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    if kind == "random":
        angle = rng.uniform(0.0, np.pi, shape)
    elif kind == "near_identity":
        angle = 10.0 ** rng.uniform(-9, -3, shape)
    else:
        angle = np.pi - 10.0 ** rng.uniform(-9, -3, shape)
    w = axis * angle[..., None]
    return _expm_skew(w), w, angle


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("kind", ["random", "near_identity", "near_pi"])
def test_log_and_angle_invert_exp(kind, shape):
    R, w, angle = _rotations(kind, shape)
    theta, w_log = (np.asarray(x) for x in _angle_and_log(R))
    np.testing.assert_allclose(theta, angle, atol=1e-12)
    assert w_log.shape == shape + (3,)
    # near pi the sign of the axis is ambiguous only at exactly pi: here it is not.
    np.testing.assert_allclose(w_log, w, atol=1e-7 if kind == "near_pi" else 1e-12)
    np.testing.assert_allclose(_expm_skew(w_log), R, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("kind", ["random", "near_identity", "near_pi"])
def test_entry_log_inverts_exp(kind, dtype):
    R, w_true, angle = _rotations(kind, (64,), seed=1)
    M = tuple(tuple(jnp.asarray(R[:, i, j], dtype) for j in range(3)) for i in range(3))
    w, theta = jax.jit(rg.so3_log)(M)
    assert theta.dtype == dtype and all(x.dtype == dtype for x in w)
    tol = {np.float64: (1e-12, 1e-7), np.float32: (1e-3, 1e-3)}[dtype][kind == "near_pi"]
    np.testing.assert_allclose(theta, angle, atol=tol)
    w = np.stack(w, -1)
    if kind == "near_pi" and dtype == np.float32:  # within float32 rounding of a half-turn: w and -w both right
        w = np.where(np.sum(w * w_true, -1, keepdims=True) < 0, -w, w)
    np.testing.assert_allclose(w, w_true, atol=tol)


def test_skew_vee_adjoint():
    rng = np.random.default_rng(2)
    w, v = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    np.testing.assert_allclose(se3.skew(w) @ v[..., None], np.cross(w, v)[..., None], atol=1e-15)
    np.testing.assert_allclose(se3.vee(se3.skew(w)), w, atol=1e-15)
    R, _, _ = _rotations("random", (4,), seed=3)
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, rng.normal(size=(4, 3))

    def hat(xi):
        X = np.zeros(xi.shape[:-1] + (4, 4))
        X[..., :3, :3], X[..., :3, 3] = se3.skew(xi[..., 3:]), xi[..., :3]
        return X

    xi = rng.normal(size=(4, 6))
    expected = T @ hat(xi) @ np.linalg.inv(T)  # Ad_T xi = (T [xi] T^-1)^vee
    np.testing.assert_allclose(hat(np.einsum("...ij,...j->...i", se3.adjoint(T), xi)), expected, atol=1e-13)
    # the rigid-transform entries' inverse, against numpy
    A = rg.from_matrix(jnp.asarray(T))
    inv = rg.to_matrix(rg.inverse(A), (4,), jnp.float64)
    np.testing.assert_allclose(inv, np.linalg.inv(T), atol=1e-13)


@functools.partial(jax.jit, static_argnums=0)
def _tangent_and_values(fn, R, dR, R_steps):
    """``fn``'s derivative at ``R`` along ``dR`` (``jax.jvp``), and ``fn`` at the rotations ``R_steps``."""
    return jax.jvp(fn, (R,), (dR,))[1], fn(R_steps)


@pytest.mark.parametrize("kind", ["random", "near_identity", "near_pi"])
def test_derivatives_match_finite_differences(kind):
    """d/dt of log(exp([a] t) R) and of its angle at t = 0 (a jvp along d/dt exp([a] t) R = [a] R), against
    central differences, at every kind of rotation."""
    R, _, angle = _rotations(kind, (), seed=4)
    a = np.random.default_rng(5).normal(size=3)
    eps = min(1e-6, (np.pi - angle) / 10)  # do not step across the half-turn, where log jumps
    steps = np.stack([_expm_skew(a * eps) @ R, _expm_skew(-a * eps) @ R])
    for fn in (se3.so3_log, se3.rotation_angle):
        tangent, (plus, minus) = (np.asarray(x) for x in _tangent_and_values(fn, R, _skew(a) @ R, steps))
        fd = (plus - minus) / (2 * eps)
        assert np.all(np.isfinite(tangent))
        if kind == "near_identity" and fn is se3.rotation_angle:
            continue  # |w| is not differentiable at the identity: finite, but no two-sided derivative
        np.testing.assert_allclose(tangent, fd, atol=1e-5, rtol=1e-6)


def test_derivatives_are_finite_at_the_identity_and_a_half_turn():
    for fn in (se3.so3_log, se3.rotation_angle):
        jacobian = jax.jit(jax.jacfwd(fn))  # one compile for both rotations
        for R in (np.eye(3), np.diag([1.0, -1.0, -1.0])):
            assert np.all(np.isfinite(jacobian(jnp.asarray(R))))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("kind", ["random", "near_identity", "near_pi"])
def test_quaternion_round_trip(kind, shape):
    """``quaternion_from_rotation`` inverts ``rotation_from_quaternion`` (``w >= 0``), under ``jit`` too."""
    R, w, angle = _rotations(kind, shape, seed=6)
    axis = w / angle[..., None]
    quat = np.concatenate([np.cos(angle / 2)[..., None], np.sin(angle / 2)[..., None] * axis], -1)
    np.testing.assert_allclose(se3.rotation_from_quaternion(3.0 * quat), R, atol=1e-12)  # normalised
    np.testing.assert_allclose(jax.jit(se3.quaternion_from_rotation)(R), quat, atol=1e-12)


def test_quaternions_of_half_turns_and_signs():
    for quat in ([0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0]):
        R = se3.rotation_from_quaternion(np.asarray(quat))
        np.testing.assert_allclose(se3.quaternion_from_rotation(R), quat, atol=1e-15)
    quat = np.array([-0.5, 0.5, -0.5, 0.5])  # w < 0: the same rotation as -quat
    np.testing.assert_allclose(se3.quaternion_from_rotation(se3.rotation_from_quaternion(quat)), -quat, atol=1e-15)
