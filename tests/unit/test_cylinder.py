"""Cylinders (``dk.collision.Cylinder``): closed forms against a sphere and a half-space, the general convex
distance (capsule, box, cylinder) on placements whose answer is known, degenerate placements, motion
wrenches against derivatives, worlds and scene files with cylinders. Against coal on thousands of random
placements: ``tests/validation/test_cylinder_validation.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import random_cylinders, random_fields, shape

import diffkin as dk
from diffkin.collision import Box, Capsule, Cylinder, Plane, Sphere, distance
from diffkin.collision._distance import motion


def _posed(p=(0.0, 0.0, 0.0), R=None) -> jax.Array:
    T = np.eye(4)
    T[:3, 3] = p
    if R is not None:
        T[:3, :3] = R
    return jnp.asarray(T)


_X_TO_Z = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # a rotation whose z axis is the world x axis
UNIT = Cylinder(_posed(), 1.0, 0.5)  # radius 1, length 1, axis z

# (name, a, b, the signed distance)
KNOWN = [
    ("sphere beside", Sphere(jnp.array([3.0, 0, 0]), 0.5), UNIT, 1.5),
    ("sphere above the cap", Sphere(jnp.array([0.2, 0.3, 2.0]), 0.5), UNIT, 1.0),
    ("sphere off the rim", Sphere(jnp.array([4.0, 0, 4.5]), 1.0), UNIT, 4.0),
    ("sphere centre inside near the cap", Sphere(jnp.array([0.0, 0, 0.4]), 0.1), UNIT, -0.2),
    ("sphere centre inside near the side", Sphere(jnp.array([0.9, 0, 0.0]), 0.05), UNIT, -0.15),
    ("sphere at the centre (on the axis)", Sphere(jnp.zeros(3), 0.0), UNIT, -0.5),
    ("plane below", UNIT, Plane(jnp.array([0.0, 0, 1]), -2.0), 1.5),
    ("plane along the side", UNIT, Plane(jnp.array([1.0, 0, 0]), -3.0), 2.0),
    ("plane tilted 45 degrees", UNIT, Plane(jnp.array([1.0, 0, 1]) / np.sqrt(2), -3.0), 3.0 - 1.5 / np.sqrt(2)),
    ("capsule beside, parallel", Capsule(jnp.array([3.0, 0, -1]), jnp.array([3.0, 0, 1]), 0.5), UNIT, 1.5),
    ("capsule above, across", Capsule(jnp.array([-2.0, 0, 1.5]), jnp.array([2.0, 0, 1.5]), 0.25), UNIT, 0.75),
    ("capsule through the axis", Capsule(jnp.array([0.0, 0, -3]), jnp.array([0.0, 0, 3]), 0.0), UNIT, -1.0),
    ("box on the cap", Box(_posed((0.3, 0.1, 1.5)), jnp.array([0.2, 0.2, 0.5])), UNIT, 0.5),
    ("box beside", Box(_posed((2.5, 0, 0)), jnp.array([0.5, 2.0, 2.0])), UNIT, 1.0),
    ("coaxial cylinders stacked", Cylinder(_posed((0, 0, 2.0)), 0.5, 0.5), UNIT, 1.0),
    ("coaxial cylinders touching caps", Cylinder(_posed((0, 0, 1.0)), 2.0, 0.5), UNIT, 0.0),
    ("parallel cylinders side by side", Cylinder(_posed((3.0, 0, 0.2)), 0.5, 0.5), UNIT, 1.5),
    ("crossed cylinders", Cylinder(_posed((0, 0, 2.0), _X_TO_Z), 0.5, 3.0), UNIT, 1.0),
    ("cylinder inside a box", UNIT, Box(_posed(), jnp.array([2.0, 2.0, 2.0])), -2.5),
    ("identical cylinders", UNIT, UNIT, -1.0),
]


def _stacked(shapes):
    """One shape of the kind of ``shapes``, its fields stacked on a new leading axis."""
    return jax.tree.map(lambda *x: jnp.stack([jnp.asarray(v) for v in x]), *shapes)


def _groups():
    """The known placements grouped by their pair of kinds: ``(ids, a, b, expected)`` each, stacked."""
    groups: dict[tuple[type, type], list] = {}
    for name, a, b, expected in KNOWN:
        groups.setdefault((type(a), type(b)), []).append((name, a, b, expected))
    return [
        ([g[0] for g in group], _stacked([g[1] for g in group]), _stacked([g[2] for g in group]), [g[3] for g in group])
        for group in groups.values()
    ]


GROUPS = _groups()


@jax.jit
def _checks(a, b):
    """The distance both orders, its gradients with respect to every field, and ``motion``."""
    d, grads = jax.value_and_grad(lambda a, b: jnp.sum(distance(a, b)), argnums=(0, 1))(a, b)
    return distance(a, b), distance(b, a), grads, motion(a, b)


@pytest.mark.parametrize("group", GROUPS, ids=["; ".join(g[0]) for g in GROUPS])
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_known_placements(group, dtype):
    """The distance (both orders), finite gradients with respect to every field, and ``motion``'s distance
    and finite wrenches, on placements with a known answer: parallel, coaxial, touching, nested."""
    names, a, b, expected = group
    a, b = jax.tree.map(lambda x: x.astype(dtype), (a, b))
    tol = 2e-6 if dtype == jnp.float32 else 1e-12
    d, swapped, grads, (m_d, Wa, Wb) = _checks(a, b)
    assert d.dtype == dtype
    for got in (d, swapped, m_d):
        np.testing.assert_allclose(got, expected, rtol=0, atol=tol, err_msg=str(names))
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))
    assert np.all(np.isfinite(np.asarray(Wa))) and np.all(np.isfinite(np.asarray(Wb)))


def test_gradient_of_a_known_distance():
    """Moving a sphere beside the cylinder radially changes the distance one for one; along the axis, not at all."""
    grad = jax.grad(lambda c: distance(Sphere(c, 0.5), UNIT))(jnp.array([3.0, 0.0, 0.2]))
    np.testing.assert_allclose(grad, [1.0, 0.0, 0.0], atol=1e-12)
    # the general distance: a box above the cap rises with its centre
    grad = jax.grad(lambda p: distance(Box(_posed().at[:3, 3].set(p), jnp.full(3, 0.2)), UNIT))(
        jnp.array([0.1, 0, 1.5])
    )
    np.testing.assert_allclose(grad, [0.0, 0.0, 1.0], atol=1e-12)


@jax.jit
def _motion_checks(a, b, twists):
    """``motion(a, b)`` and the forward derivatives of ``distance`` when ``a``, then ``b``, moves by a twist."""

    def moved(s, twist, eps):
        def point(p):
            return p + eps[:, None] * (twist[:, :3] + jnp.cross(twist[:, 3:], p))

        if isinstance(s, Capsule):
            return Capsule(point(s.a), point(s.b), s.radius)
        if isinstance(s, Sphere):
            return Sphere(point(s.center), s.radius)
        R = s.pose[:, :3, :3]
        R = R + eps[:, None, None] * jnp.cross(twist[:, None, 3:], jnp.swapaxes(R, -1, -2)).swapaxes(-1, -2)
        T = s.pose.at[:, :3, :3].set(R).at[:, :3, 3].set(point(s.pose[:, :3, 3]))
        return dk.collision._shapes.unchecked(type(s), **{**vars(s), "pose": T})

    def derivative(which):
        def moved_distance(eps):
            pair = [a, b]
            pair[which] = moved(pair[which], twists[which], eps)
            return distance(*pair)

        n = twists.shape[1]
        return jax.jvp(moved_distance, (jnp.zeros(n),), (jnp.ones(n),))[1]

    return motion(a, b), distance(a, b), (derivative(0), derivative(1))


@pytest.mark.parametrize("kind", ["sphere", "capsule", "box", "cylinder"])
def test_motion_is_the_derivative_under_rigid_motions(kind):
    """``motion``'s wrenches against forward derivatives of ``distance`` when either shape moves by a random
    twist: 300 random pairs, float64; the distance of every pair, the derivatives of the pairs apart (an
    overlap's best direction may be a kink of the separation, where the derivative is not unique); finite
    wrenches everywhere."""
    rng = np.random.default_rng(8)
    n = 300
    a = shape(kind, random_cylinders(rng, n) if kind == "cylinder" else random_fields(kind, rng, n, points=0.0))
    b = shape("cylinder", random_cylinders(rng, n))
    twists = jnp.asarray(rng.normal(size=(2, n, 6)))
    (d, Wa, Wb), d_ref, derivatives = _motion_checks(a, b, twists)
    assert 0.1 < np.mean(np.asarray(d_ref) < 0) < 0.9
    np.testing.assert_allclose(np.asarray(d), np.asarray(d_ref), rtol=0, atol=1e-12)
    apart = np.asarray(d_ref) > 1e-9
    for W, twist, derivative in ((Wa, twists[0], derivatives[0]), (Wb, twists[1], derivatives[1])):
        assert np.all(np.isfinite(np.asarray(W)))
        change = np.sum(np.asarray(W) * np.asarray(twist), -1)
        np.testing.assert_allclose(change[apart], np.asarray(derivative)[apart], rtol=0, atol=1e-9)


def test_batches_broadcast_and_world_distances():
    """A cylinder batch against one box broadcasts; a World of cylinders gives the same distances as
    ``distance`` shape by shape, through ``world_distances`` and ``clearance``."""
    rng = np.random.default_rng(3)
    cylinders = shape("cylinder", random_cylinders(rng, 5))
    box = Box(_posed((0.0, 0.0, 2.0)), jnp.array([0.3, 0.3, 0.3]))
    assert distance(cylinders, box).shape == (5,)
    world = dk.collision.World(cylinders, box)
    assert world.size == 6 and world.cylinders.radius.shape == (5,)
    robot = dk.load_robot(
        '<robot name="r"><link name="base"/><link name="l"><collision><geometry><sphere radius="0.1"/></geometry>'
        '</collision></link><joint name="j" type="prismatic"><parent link="base"/><child link="l"/>'
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint></robot>'
    )
    geom = dk.collision.load(
        '<robot name="r"><link name="base"/><link name="l"><collision><geometry><sphere radius="0.1"/></geometry>'
        '</collision></link><joint name="j" type="prismatic"><parent link="base"/><child link="l"/>'
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint></robot>',
        robot,
    )
    q = jnp.array([[0.3], [-0.2]])
    got = np.asarray(dk.collision.world_distances(robot, geom, q, world))  # (2, 1, 6): boxes first, then cylinders
    for k, z in enumerate((0.3, -0.2)):
        ball = Sphere(jnp.array([0.0, 0.0, z]), 0.1)
        want = [float(distance(ball, box))] + [float(d) for d in distance(ball, cylinders)]
        np.testing.assert_allclose(got[k, 0], want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(dk.collision.clearance(robot, geom, q, world), got.min(axis=(1, 2)), atol=1e-12)


def test_scene_file_cylinders():
    """A scene's cylinders (axis along the quaternion's z), and errors naming the field."""
    scene = dk.collision.load_scene(
        {
            "cylinders": [
                {
                    "position": [1, 2, 3],
                    "quaternion": [0.7071067811865476, 0, 0.7071067811865476, 0],
                    "radius": 0.1,
                    "half_length": 0.4,
                }
            ]
        }  # fmt: skip
    )
    c = scene.world.cylinders
    np.testing.assert_allclose(c.pose[0, :3, 2], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(c.pose[0, :3, 3], [1.0, 2.0, 3.0])
    assert float(c.radius[0]) == 0.1 and float(c.half_length[0]) == 0.4
    with pytest.raises(ValueError, match=r"cylinders\[0\]\.half_length: expected values >= 0"):
        dk.collision.load_scene({"cylinders": [{"position": [0, 0, 0], "radius": 0.1, "half_length": -1}]})
    with pytest.raises(ValueError, match=r"cylinders\[0\]: missing key 'radius'"):
        dk.collision.load_scene({"cylinders": [{"position": [0, 0, 0], "half_length": 1}]})


def test_bad_input_names_the_field():
    with pytest.raises(ValueError, match=r"Cylinder\.radius: expected values >= 0"):
        Cylinder(jnp.eye(4), -1.0, 1.0)
    with pytest.raises(ValueError, match=r"Cylinder\.pose: expected a rigid transform"):
        Cylinder(2 * jnp.eye(4), 1.0, 1.0)
    with pytest.raises(ValueError, match=r"Cylinder\.pose: expected shape \(\.\.\., 4, 4\)"):
        Cylinder(jnp.eye(3), 1.0, 1.0)
    with pytest.raises(TypeError, match="Cylinder"):
        distance(UNIT, "box")
