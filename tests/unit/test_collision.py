"""Primitive shapes and their signed distances (``dk.collision``): closed forms, degenerate cases, batches,
dtypes and bad input. Every pair kind against coal (Pinocchio's collision library) on 10,000 random
pairs, float64 and float32, against brute force and gradients against finite differences:
``tests/validation/test_collision_validation.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import SHAPE_PAIRS, random_fields, shape

import diffkin as dk
from diffkin.collision import Box, Capsule, Plane, Sphere, distance

# ------------------------------------------------------------------------------------ closed forms


def test_closed_forms():
    """Hand-computed distances, apart and overlapping, of every pair kind."""
    eye = jnp.eye(4)
    box = Box(eye, jnp.array([1.0, 2.0, 3.0]))
    shifted = eye.at[0, 3].set(3.5)
    cases = [
        (Sphere(jnp.zeros(3), 1.0), Sphere(jnp.array([3.0, 0, 0]), 0.5), 1.5),
        (Sphere(jnp.zeros(3), 1.0), Sphere(jnp.array([0.5, 0, 0]), 0.5), -1.0),
        (Sphere(jnp.array([0.0, 2, 0]), 0.5), Capsule(jnp.array([-1.0, 0, 0]), jnp.array([1.0, 0, 0]), 0.5), 1.0),
        (Sphere(jnp.array([3.0, 0, 0]), 0.5), Capsule(jnp.array([-1.0, 0, 0]), jnp.array([1.0, 0, 0]), 0.5), 1.0),
        (Sphere(jnp.array([2.0, 0, 0]), 0.5), box, 0.5),
        (Sphere(jnp.array([0.5, 0, 0]), 0.25), box, -0.75),  # centre 0.5 inside the x faces
        (Sphere(jnp.array([2.0, 3.0, 3.0]), 0.5), box, np.sqrt(2.0) - 0.5),  # nearest an edge
        (Sphere(jnp.array([0.0, 0, 2]), 0.5), Plane(jnp.array([0.0, 0, 1]), 1.0), 0.5),
        (Capsule(jnp.array([0.0, 0, 0]), jnp.array([0.0, 0, 1]), 0.1), Plane(jnp.array([0.0, 0, -1]), 0.5), -1.6),
        (Box(shifted, jnp.array([0.5, 0.5, 0.5])), box, 2.0),
        (Box(eye.at[0, 3].set(1.25), jnp.array([0.5, 0.5, 0.5])), box, -0.25),
        (Box(eye.at[2, 3].set(5.0), jnp.array([1.0, 1.0, 1.0])), Plane(jnp.array([0.0, 0, 1]), 1.0), 3.0),
        (Capsule(jnp.array([3.0, 0, -5]), jnp.array([3.0, 0, 5]), 0.5), box, 1.5),  # parallel to a face
        (Capsule(jnp.array([0.5, -9, 0]), jnp.array([0.5, 9, 0]), 0.25), box, -0.75),  # through the box
        (Plane(jnp.array([0.0, 0, 1]), 0.5), Plane(jnp.array([0.0, 0, -1]), -1.0), 0.5),
    ]
    for a, b, expected in cases:
        for x, y in ((a, b), (b, a)):
            np.testing.assert_allclose(distance(x, y), expected, atol=1e-12, err_msg=f"{type(x)} {type(y)}")


def test_crossing_capsules_and_rotated_boxes():
    """Crossing capsules overlap by the sum of radii; a box turned 45 degrees reaches sqrt(2) half widths."""
    a = Capsule(jnp.array([-1.0, 0, 0]), jnp.array([1.0, 0, 0]), 0.2)
    b = Capsule(jnp.array([0.0, -1, 0.1]), jnp.array([0.0, 1, 0.1]), 0.3)
    np.testing.assert_allclose(distance(a, b), 0.1 - 0.5, atol=1e-15)
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    T = jnp.array([[c, -s, 0, 3.0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    np.testing.assert_allclose(distance(Box(T, jnp.ones(3)), Box(jnp.eye(4), jnp.ones(3))), 2 - np.sqrt(2), atol=1e-12)
    edge = Capsule(jnp.array([1.0, -1, 0]), jnp.array([1.0, 1, 0]), 0.0)  # the box's edge against a face
    np.testing.assert_allclose(distance(edge, Box(T, jnp.ones(3))), 2 - np.sqrt(2), atol=1e-12)


# ------------------------------------------------------------------------------------ degenerate inputs

DEGENERATE = [
    ("coincident spheres", Sphere(jnp.zeros(3), 0.5), Sphere(jnp.zeros(3), 0.25), -0.75),
    ("sphere on a capsule's axis", Sphere(jnp.zeros(3), 0.1), Capsule(-jnp.ones(3), jnp.ones(3), 0.1), -0.2),
    ("zero-length capsules", Capsule(jnp.zeros(3), jnp.zeros(3), 0.1), Capsule(jnp.ones(3), jnp.ones(3), 0.1), None),
    (
        "coincident zero-length capsules",
        Capsule(jnp.zeros(3), jnp.zeros(3), 0.1),
        Capsule(jnp.zeros(3), jnp.zeros(3), 0.2),
        -0.3,
    ),
    (
        "parallel capsules",
        Capsule(jnp.zeros(3), jnp.array([1.0, 0, 0]), 0.1),
        Capsule(jnp.array([0.5, 1, 0]), jnp.array([1.5, 1, 0]), 0.1),
        0.8,
    ),
    (
        "collinear capsules",
        Capsule(jnp.zeros(3), jnp.array([1.0, 0, 0]), 0.1),
        Capsule(jnp.array([2.0, 0, 0]), jnp.array([3.0, 0, 0]), 0.1),
        0.8,
    ),
    (
        "identical capsules",
        Capsule(jnp.zeros(3), jnp.array([1.0, 0, 0]), 0.1),
        Capsule(jnp.zeros(3), jnp.array([1.0, 0, 0]), 0.1),
        -0.2,
    ),
    ("point on a box face", Sphere(jnp.array([1.0, 0, 0]), 0.0), Box(jnp.eye(4), jnp.ones(3)), 0.0),
    ("point at a box corner", Sphere(jnp.ones(3), 0.0), Box(jnp.eye(4), jnp.ones(3)), 0.0),
    ("centre of a box", Sphere(jnp.zeros(3), 0.5), Box(jnp.eye(4), jnp.ones(3)), -1.5),
    ("zero-length capsule in a box", Capsule(jnp.zeros(3), jnp.zeros(3), 0.5), Box(jnp.eye(4), jnp.ones(3)), -1.5),
    (
        "capsule on a box axis",
        Capsule(jnp.array([0.0, 0, -3]), jnp.array([0.0, 0, 3]), 0.5),
        Box(jnp.eye(4), jnp.ones(3)),
        -1.5,
    ),
    (
        "capsule along a box edge",
        Capsule(jnp.array([1.0, 1, -3]), jnp.array([1.0, 1, 3]), 0.0),
        Box(jnp.eye(4), jnp.ones(3)),
        0.0,
    ),
    ("identical boxes", Box(jnp.eye(4), jnp.ones(3)), Box(jnp.eye(4), jnp.ones(3)), -2.0),
    ("boxes face to face", Box(jnp.eye(4).at[0, 3].set(2.0), jnp.ones(3)), Box(jnp.eye(4), jnp.ones(3)), 0.0),
    ("flat box", Box(jnp.eye(4), jnp.array([1.0, 1, 0])), Sphere(jnp.array([0.0, 0, 0.5]), 0.1), 0.4),
    ("capsule on a plane", Capsule(jnp.zeros(3), jnp.array([1.0, 0, 0]), 0.0), Plane(jnp.array([0.0, 0, 1]), 0.0), 0.0),
    ("box on a plane", Box(jnp.eye(4), jnp.ones(3)), Plane(jnp.array([0.0, 0, 1]), -1.0), 0.0),
]


_VALUE_AND_GRAD = jax.jit(jax.value_and_grad(distance, argnums=(0, 1)))


@pytest.mark.parametrize("a, b, expected", [c[1:] for c in DEGENERATE], ids=[c[0] for c in DEGENERATE])
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_degenerate_inputs_are_finite(a, b, expected, dtype):
    """Finite distances (both orders) and finite gradients with respect to every field, f32 and f64."""
    a, b = (jax.tree.map(lambda x: x.astype(dtype), s) for s in (a, b))
    d, grads = _VALUE_AND_GRAD(a, b)
    assert d.dtype == dtype and np.isfinite(d)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))
    # distance compiles each pair of kinds once per shape and dtype: in float64, the closed forms' programs
    np.testing.assert_allclose(distance(b, a), d, rtol=0, atol=1e-6 if dtype == jnp.float32 else 1e-14)
    if expected is not None:
        np.testing.assert_allclose(d, expected, atol=1e-6 if dtype == jnp.float32 else 1e-12)


def test_plane_plane():
    """Opposite half-spaces: the gap (or minus the slab's thickness); others overlap without bound (coal's answer)."""
    up, down = Plane(jnp.array([0.0, 0, 1]), 0.2), Plane(jnp.array([0.0, 0, -1]), 0.1)
    np.testing.assert_allclose(distance(up, down), -0.3)
    tilted = Plane(jnp.array([0.0, 0.6, 0.8]), 0.0)
    assert distance(up, tilted) == np.finfo(np.float64).min
    assert jnp.isfinite(jax.grad(lambda o: distance(up.replace(offset=o), tilted))(0.2))


# ------------------------------------------------------------------------------------ batching, jit, errors


def test_batches_broadcast():
    """Leading axes of the two shapes (and of the fields of one shape) broadcast."""
    rng = np.random.default_rng(0)
    spheres = Sphere(jnp.asarray(rng.normal(size=(4, 1, 3))), jnp.asarray(rng.uniform(0.1, 0.2, (4, 1))))
    boxes = shape("box", random_fields("box", rng, 5))
    d = distance(spheres, boxes)
    assert d.shape == (4, 5)
    for i, j in [(0, 0), (3, 4), (2, 1)]:
        one = distance(Sphere(spheres.center[i, 0], spheres.radius[i, 0]), Box(boxes.pose[j], boxes.half_extents[j]))
        np.testing.assert_allclose(d[i, j], one, rtol=1e-14)
    shared_radius = Capsule(jnp.zeros((7, 3)), jnp.ones((7, 3)), 0.1)  # one radius for 7 capsules
    assert distance(shared_radius, Plane(jnp.array([0.0, 0, 1]), 0.0)).shape == (7,)
    vmapped = jax.vmap(distance, in_axes=(None, 0))(Sphere(spheres.center[0, 0], spheres.radius[0, 0]), boxes)
    np.testing.assert_allclose(vmapped, d[0], rtol=1e-14)


def test_dtypes():
    s32 = Sphere(jnp.zeros(3, jnp.float32), jnp.float32(1))
    assert distance(s32, s32).dtype == jnp.float32
    assert distance(s32, Sphere(jnp.zeros(3), 1.0)).dtype == jnp.float64  # promoted
    assert Sphere([0, 0, 0], 1).radius.dtype == jnp.result_type(float)  # ints become floats


def test_bad_input_names_the_field():
    with pytest.raises(ValueError, match=r"Sphere.radius.*>= 0"):
        Sphere(jnp.zeros(3), -1.0)
    with pytest.raises(ValueError, match=r"Capsule.a.*\(\.\.\., 3\)"):
        Capsule(jnp.zeros(2), jnp.zeros(3), 0.1)
    with pytest.raises(ValueError, match=r"Box.half_extents.*>= 0"):
        Box(jnp.eye(4), jnp.array([1.0, -1, 1]))
    with pytest.raises(ValueError, match=r"Box.pose\[1\].*rigid"):
        Box(jnp.stack([jnp.eye(4), 2 * jnp.eye(4)]), jnp.ones(3))
    with pytest.raises(ValueError, match=r"Box.pose.*\(\.\.\., 4, 4\)"):
        Box(jnp.eye(3), jnp.ones(3))
    with pytest.raises(ValueError, match=r"Plane.normal.*unit"):
        Plane(jnp.array([0.0, 0, 2]), 0.0)
    with pytest.raises(ValueError, match=r"Sphere.center.*finite"):
        Sphere(jnp.array([0.0, np.nan, 0]), 1.0)
    with pytest.raises(ValueError, match=r"Sphere: the batch axes"):
        Sphere(jnp.zeros((4, 3)), jnp.ones(5))
    with pytest.raises(TypeError, match=r"Sphere.radius.*real"):
        Sphere(jnp.zeros(3), "big")
    with pytest.raises(TypeError, match=r"shape_b: expected a Sphere"):
        distance(Sphere(jnp.zeros(3), 1.0), jnp.zeros(3))


def test_nothing_raises_under_jit():
    """Traced values are not checked: a negative radius inside jit gives a number, not an error."""
    f = jax.jit(lambda r, T: distance(Sphere(jnp.zeros(3), r), Box(T, jnp.ones(3))))
    assert np.isfinite(f(-1.0, 2 * jnp.eye(4)))


def test_public_name():
    assert dk.collision.distance is distance and dk.collision.Sphere is Sphere


def _moved(s, twist: jax.Array, eps: jax.Array):
    """The shapes moved to first order in ``eps`` by the space twists ``twist (n, 6)`` (a point ``p`` by
    ``eps (v + w x p)``); half-spaces stay (obstacles)."""

    def point(p):
        return p + eps[:, None] * (twist[:, :3] + jnp.cross(twist[:, 3:], p))

    if isinstance(s, Sphere):
        return Sphere(point(s.center), s.radius)
    if isinstance(s, Capsule):
        return Capsule(point(s.a), point(s.b), s.radius)
    if isinstance(s, Box):
        w = twist[:, 3:]
        zero = jnp.zeros_like(w[:, 0])
        W = jnp.stack([jnp.stack([zero, -w[:, 2], w[:, 1]], -1), jnp.stack([w[:, 2], zero, -w[:, 0]], -1),
                       jnp.stack([-w[:, 1], w[:, 0], zero], -1)], -2)  # fmt: skip
        R = s.pose[:, :3, :3] + eps[:, None, None] * W @ s.pose[:, :3, :3]
        T = s.pose.at[:, :3, :3].set(R).at[:, :3, 3].set(point(s.pose[:, :3, 3]))
        return dk.collision._shapes.unchecked(Box, pose=T, half_extents=s.half_extents)
    return s


@jax.jit
def _motion_checks(a, b, twists):
    """``motion(a, b)``, ``distance(a, b)`` and the derivatives of ``distance`` when ``a``, then ``b``,
    moves by ``twists[0]``, ``twists[1]`` (one compilation per pair of kinds: eager, the box-box
    derivatives took 10 s)."""
    from diffkin.collision._distance import motion

    def derivative(which):
        def moved_distance(eps):
            pair = [a, b]
            pair[which] = _moved(pair[which], twists[which], eps)
            return distance(*pair)

        n = twists.shape[1]
        return jax.jvp(moved_distance, (jnp.zeros(n),), (jnp.ones(n),))[1]

    return motion(a, b), distance(a, b), (derivative(0), derivative(1))


@pytest.mark.parametrize("kinds", SHAPE_PAIRS[:-1], ids=["-".join(p) for p in SHAPE_PAIRS[:-1]])
def test_motion_is_the_derivative_under_rigid_motions(kinds):
    """``motion``'s wrenches (from the contact normal and witness points) against forward-mode
    derivatives of ``distance`` when either shape moves by a random twist, 1,000 random pairs of each
    kind (about a third overlapping: every separating axis and closest feature), float64."""
    rng = np.random.default_rng(4)
    n = 1000
    a = shape(kinds[0], random_fields(kinds[0], rng, n, points=0.0))
    b = shape(kinds[1], random_fields(kinds[1], rng, n, points=0.0))
    twists = jnp.asarray(np.stack([rng.normal(size=(n, 6)) for _ in range(2)]))
    (d, Wa, Wb), d_ref, derivatives = _motion_checks(a, b, twists)
    np.testing.assert_allclose(np.asarray(d), np.asarray(d_ref), rtol=0, atol=1e-14)
    for which, W in ((0, Wa), (1, Wb)):
        if kinds[1] == "plane" and which == 1:
            assert np.all(np.asarray(W) == 0)  # a half-space is an obstacle: it does not move
            continue
        np.testing.assert_allclose(
            np.sum(np.asarray(W) * np.asarray(twists[which]), -1), derivatives[which], rtol=0, atol=1e-9
        )
