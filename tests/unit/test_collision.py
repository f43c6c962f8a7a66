"""Primitive shapes and their signed distances (``dk.collision``).

Closed forms and degenerate cases here; every pair kind against coal (Pinocchio's collision
library) on 10,000 random pairs, float64 and float32, and gradients against finite differences
(marked slow: cross-library).
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffkin as dk
from diffkin.collision import Box, Capsule, Plane, Sphere, distance
from diffkin.collision import _closest as cl

KINDS = ("sphere", "capsule", "box", "plane")
PAIRS = [(a, b) for a, b in itertools.combinations_with_replacement(KINDS, 2)]
N = 10_000


# ------------------------------------------------------------------------------------ random shapes


def rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """``(n, 3, 3)`` uniformly random rotations (from unit quaternions)."""
    w, x, y, z = (rng.normal(size=(n, 4)) / 1).T
    s = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / s, x / s, y / s, z / s
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def random_fields(kind: str, rng: np.random.Generator, n: int, points: float = 0.1) -> dict[str, np.ndarray]:
    """Fields of ``n`` random shapes of one kind in the cube ``[-0.5, 0.5]^3`` (sizes 0.02 to 0.4 m),
    so that about a third of the pairs overlap. A fraction ``points`` of the capsules have zero length."""
    if kind == "sphere":
        return {"center": rng.uniform(-0.5, 0.5, (n, 3)), "radius": rng.uniform(0.02, 0.4, n)}
    if kind == "capsule":
        a = rng.uniform(-0.5, 0.5, (n, 3))
        b = a + rng.normal(0, 0.3, (n, 3)) * (rng.uniform(size=(n, 1)) >= points)
        return {"a": a, "b": b, "radius": rng.uniform(0.01, 0.2, n)}
    if kind == "box":
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, :3, :3], T[:, :3, 3] = rotations(rng, n), rng.uniform(-0.5, 0.5, (n, 3))
        return {"pose": T, "half_extents": rng.uniform(0.02, 0.4, (n, 3))}
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return {"normal": normal, "offset": rng.uniform(-0.3, 0.3, n)}


CLASSES = {"sphere": Sphere, "capsule": Capsule, "box": Box, "plane": Plane}


def shape(kind: str, fields: dict, dtype=None):
    return CLASSES[kind](**{k: jnp.asarray(v, dtype) for k, v in fields.items()})


def _coal_shape(coal, kind: str, f: dict, i: int):
    """The coal geometry and placement of shape ``i``."""
    if kind == "sphere":
        return coal.Sphere(f["radius"][i]), coal.Transform3s(np.eye(3), f["center"][i])
    if kind == "capsule":
        a, b = f["a"][i], f["b"][i]
        axis = b - a
        length = float(np.linalg.norm(axis))
        R = np.eye(3)
        if length > 0:
            z = axis / length
            x = np.cross([1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0], z)
            x /= np.linalg.norm(x)
            R = np.column_stack([x, np.cross(z, x), z])
        return coal.Capsule(f["radius"][i], length), coal.Transform3s(R, 0.5 * (a + b))
    if kind == "box":
        T = f["pose"][i]
        return coal.Box(*(2 * f["half_extents"][i])), coal.Transform3s(T[:3, :3], T[:3, 3])
    return coal.Halfspace(f["normal"][i], f["offset"][i]), coal.Transform3s()


def coal_distances(kind_a: str, fa: dict, kind_b: str, fb: dict) -> np.ndarray:
    """coal's signed distances, one pair at a time. GJK/EPA (pairs with a box) at tolerance 1e-12:
    at coal's default (1e-6) one pair in 2,000 is off by 4.5e-7."""
    coal = pytest.importorskip("coal")
    request = coal.DistanceRequest()
    request.gjk_tolerance = request.epa_tolerance = 1e-12
    out = np.empty(len(next(iter(fa.values()))))
    for i in range(out.size):
        ga, Ta = _coal_shape(coal, kind_a, fa, i)
        gb, Tb = _coal_shape(coal, kind_b, fb, i)
        out[i] = coal.distance(ga, Ta, gb, Tb, request, coal.DistanceResult())
    return out


@pytest.fixture(scope="module")
def random_pairs():
    """Per pair kind: ``N`` random pairs and coal's distances (computed once for the module)."""
    rng = np.random.default_rng(27)
    out = {}
    for kind_a, kind_b in PAIRS:
        fa, fb = random_fields(kind_a, rng, N), random_fields(kind_b, rng, N)
        if (kind_a, kind_b) == ("plane", "plane"):  # half of them opposite: the finite case
            fb["normal"][: N // 2] = -fa["normal"][: N // 2]
        out[kind_a, kind_b] = (fa, fb, coal_distances(kind_a, fa, kind_b, fb))
    return out


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


_DISTANCE = jax.jit(distance)
_VALUE_AND_GRAD = jax.jit(jax.value_and_grad(distance, argnums=(0, 1)))


@pytest.mark.parametrize("a, b, expected", [c[1:] for c in DEGENERATE], ids=[c[0] for c in DEGENERATE])
@pytest.mark.parametrize("dtype", [pytest.param(jnp.float32, marks=pytest.mark.slow), jnp.float64])
def test_degenerate_inputs_are_finite(a, b, expected, dtype):
    """Finite distances (both orders) and finite gradients with respect to every field, f32 and f64."""
    a, b = (jax.tree.map(lambda x: x.astype(dtype), s) for s in (a, b))
    d, grads = _VALUE_AND_GRAD(a, b)
    assert d.dtype == dtype and np.isfinite(d)
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(grads))
    np.testing.assert_allclose(_DISTANCE(b, a), d, rtol=0, atol=1e-6 if dtype == jnp.float32 else 1e-14)
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


# ------------------------------------------------------------------------------------ against coal


def _jitted(kind_a, kind_b, dtype):
    return jax.jit(lambda fa, fb: distance(shape(kind_a, fa, dtype), shape(kind_b, fb, dtype)))


@pytest.mark.slow
@pytest.mark.parametrize("kinds", PAIRS, ids=["-".join(p) for p in PAIRS])
def test_against_coal_float64(random_pairs, kinds):
    """Every pair kind, both orders, 10,000 random pairs (apart and overlapping) to 1e-9 of coal."""
    fa, fb, ref = random_pairs[kinds]
    overlapping = np.mean(ref < 0)
    assert 0.05 < overlapping < 0.95 or kinds == ("plane", "plane"), overlapping
    d_ab = np.asarray(_jitted(*kinds, jnp.float64)(fa, fb))
    d_ba = np.asarray(_jitted(*kinds[::-1], jnp.float64)(fb, fa))
    np.testing.assert_allclose(d_ab, ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(d_ab, d_ba, rtol=0, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("kinds", PAIRS, ids=["-".join(p) for p in PAIRS])
def test_against_coal_float32(random_pairs, kinds):
    """float32 inputs (shapes of size ~1 m) to 1e-5 m of coal's float64 answer; never the wrong sign beyond that."""
    fa, fb, ref = random_pairs[kinds]
    fa32, fb32 = ({k: v.astype(np.float32) for k, v in f.items()} for f in (fa, fb))
    d = np.asarray(_jitted(*kinds, jnp.float32)(fa32, fb32))
    assert d.dtype == np.float32
    finite = ref > np.finfo(np.float32).min  # plane-plane's unbounded overlap is the float32 minimum instead
    np.testing.assert_allclose(d[finite], ref[finite], rtol=0, atol=1e-5)
    assert np.all(d[~finite] == np.finfo(np.float32).min)


# ------------------------------------------------------------------------------------ against every feature pair


def _unit_box_edges() -> np.ndarray:
    """``(12, 2, 3)`` the end points of the edges of the box of half extents 1."""
    edges = []
    for i in range(3):
        for sj, sk in itertools.product((-1.0, 1.0), repeat=2):
            lo = np.zeros(3)
            lo[(i + 1) % 3], lo[(i + 2) % 3] = sj, sk
            hi = lo.copy()
            lo[i], hi[i] = -1.0, 1.0
            edges.append([lo, hi])
    return np.array(edges)


_CORNERS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
_EDGES = _unit_box_edges()


def _place(T: np.ndarray, p: np.ndarray) -> jax.Array:
    """Points ``p (n, ..., 3)`` of frames ``T (n, 4, 4)`` in the outer frame."""
    t = T[:, :3, 3].reshape(len(T), *([1] * (p.ndim - 2)), 3)
    return jnp.einsum("nij,n...j->n...i", T[:, :3, :3], p) + t


def _in_frame(T: np.ndarray, p: jax.Array) -> jax.Array:
    t = T[:, :3, 3].reshape(len(T), *([1] * (p.ndim - 2)), 3)
    return jnp.einsum("nji,n...j->n...i", T[:, :3, :3], p - t)


def brute_apart(kind_a: str, fa: dict, fb: dict) -> np.ndarray:
    """The signed distance of a capsule (or box) ``a`` to box ``b`` when apart, from every feature pair:
    the end points (corners) against the other box and the 12 (144) edge pairs: the brute force that
    the closest-feature candidates replaced."""
    Tb, hb = fb["pose"], fb["half_extents"]
    edges_b = _place(Tb, _EDGES * hb[:, None, None])
    if kind_a == "capsule":
        a, b = jnp.asarray(fa["a"])[:, None], jnp.asarray(fa["b"])[:, None]
        ends = jnp.min(cl.point_box(cl.vec(_in_frame(Tb, jnp.concatenate([a, b], 1))), cl.vec(hb[:, None])), axis=1)
        edges = jnp.min(cl.segment_segment(*(cl.vec(x) for x in (a, b, edges_b[:, :, 0], edges_b[:, :, 1]))), axis=1)
        return np.asarray(jnp.minimum(ends, edges)) - fa["radius"]
    Ta, ha = fa["pose"], fa["half_extents"]
    corners_a, corners_b = _place(Ta, _CORNERS * ha[:, None]), _place(Tb, _CORNERS * hb[:, None])
    corners = jnp.minimum(
        jnp.min(cl.point_box(cl.vec(_in_frame(Tb, corners_a)), cl.vec(hb[:, None])), axis=1),
        jnp.min(cl.point_box(cl.vec(_in_frame(Ta, corners_b)), cl.vec(ha[:, None])), axis=1),
    )
    edges_a = _place(Ta, _EDGES * ha[:, None, None])
    ends = (edges_a[:, :, None, 0], edges_a[:, :, None, 1], edges_b[:, None, :, 0], edges_b[:, None, :, 1])
    edges = cl.segment_segment(*(cl.vec(x) for x in ends))
    return np.asarray(jnp.minimum(corners, jnp.min(edges, axis=(1, 2))))


def tricky_fields(kind: str, mode: str, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """Shapes where closest features tie: ``quarter turns`` (boxes turned by multiples of 90 degrees,
    capsules along the axes, on a 5 cm grid: parallel faces and edges, touching), ``about z`` (boxes
    turned about z only: parallel top and bottom faces), or ``random``."""
    if mode == "random":
        return random_fields(kind, rng, n)
    grid = lambda shape: rng.integers(-6, 7, shape) * 0.05  # noqa: E731
    if kind == "capsule":
        a = grid((n, 3)) if mode == "quarter turns" else rng.uniform(-0.5, 0.5, (n, 3))
        axis = np.eye(3)[rng.integers(0, 3, n)] * rng.integers(-6, 7, (n, 1)) * 0.05
        return {"a": a, "b": a + axis, "radius": rng.integers(0, 3, n) * 0.05}
    T = np.tile(np.eye(4), (n, 1, 1))
    if mode == "quarter turns":
        for k in range(n):
            R = np.eye(3)[rng.permutation(3)] * rng.choice((-1.0, 1.0), 3)
            T[k, :3, :3] = R * np.linalg.det(R)
        T[:, :3, 3], h = grid((n, 3)), rng.integers(1, 6, (n, 3)) * 0.05
    else:
        angle = rng.uniform(0, 2 * np.pi, n)
        c, s = np.cos(angle), np.sin(angle)
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
        T[:, :3, 3], h = rng.uniform(-0.5, 0.5, (n, 3)), rng.uniform(0.02, 0.3, (n, 3))
    return {"pose": T, "half_extents": h}


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["random", "quarter turns", "about z"])
@pytest.mark.parametrize("kind_a", ["capsule", "box"])
def test_apart_against_every_feature_pair(kind_a, mode):
    """Apart, the closest-feature candidates give the distance of every feature pair to 1e-12 (10,000 pairs),
    ties of parallel faces and edges included."""
    rng = np.random.default_rng(5)
    fa, fb = tricky_fields(kind_a, mode, rng, 10_000), tricky_fields("box", mode, rng, 10_000)
    d = np.asarray(_jitted(kind_a, "box", jnp.float64)(fa, fb))
    apart = d + fa.get("radius", 0.0) > 0
    assert 0.2 < np.mean(apart) < 0.99, np.mean(apart)
    np.testing.assert_allclose(d[apart], brute_apart(kind_a, fa, fb)[apart], rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------ gradients


def _params(kind: str, rng: np.random.Generator, n: int) -> np.ndarray:
    """Unconstrained parameters of random shapes (box: quaternion, centre, half extents); capsules of
    non-zero length (the direction of a zero-length one jumps with any perturbation)."""
    f = random_fields(kind, rng, n, points=0.0)
    if kind == "box":
        return np.concatenate([rng.normal(size=(n, 4)), f["pose"][:, :3, 3], f["half_extents"]], axis=1)
    return np.concatenate([v.reshape(n, -1) for v in f.values()], axis=1)


def _from_params(kind: str, p: jax.Array):
    if kind == "sphere":
        return Sphere(p[..., :3], p[..., 3])
    if kind == "capsule":
        return Capsule(p[..., :3], p[..., 3:6], p[..., 6])
    if kind == "plane":
        return Plane(p[..., :3] / jnp.linalg.norm(p[..., :3], axis=-1, keepdims=True), p[..., 3])
    R = dk.se3.rotation_from_quaternion(p[..., :4] / jnp.linalg.norm(p[..., :4], axis=-1, keepdims=True))
    T = jnp.zeros((*p.shape[:-1], 4, 4), p.dtype).at[..., :3, :3].set(R).at[..., :3, 3].set(p[..., 4:7])
    return Box(T.at[..., 3, 3].set(1), p[..., 7:10])


@pytest.mark.slow
@pytest.mark.parametrize("kinds", PAIRS, ids=["-".join(p) for p in PAIRS])
def test_gradients_match_finite_differences(kinds):
    """Directional derivatives (forward and reverse mode) against central differences on 1,000 random pairs, float64.

    Pairs within a step of a tie (a switch of closest features: one-sided differences disagree)
    are left out; they must be rare (< 1 %).
    """
    rng = np.random.default_rng(1)
    n, h = 1000, 1e-6
    pa, pb = _params(kinds[0], rng, n), _params(kinds[1], rng, n)
    va, vb = rng.normal(size=pa.shape), rng.normal(size=pb.shape)

    @jax.jit
    def f(pa, pb):
        return distance(_from_params(kinds[0], pa), _from_params(kinds[1], pb))

    d0, dd = jax.jvp(f, (jnp.asarray(pa), jnp.asarray(pb)), (jnp.asarray(va), jnp.asarray(vb)))
    ga, gb = jax.jit(jax.grad(lambda pa, pb: jnp.sum(f(pa, pb)), argnums=(0, 1)))(pa, pb)
    reverse = np.sum(np.asarray(ga) * va, axis=1) + np.sum(np.asarray(gb) * vb, axis=1)
    up, down = np.asarray(f(pa + h * va, pb + h * vb)), np.asarray(f(pa - h * va, pb - h * vb))
    d0 = np.asarray(d0)
    smooth = np.abs((up - d0) - (d0 - down)) / h < 1e-3
    assert np.mean(smooth) > 0.99
    central = (up - down) / (2 * h)
    np.testing.assert_allclose(np.asarray(dd)[smooth], central[smooth], rtol=0, atol=2e-7)
    np.testing.assert_allclose(reverse[smooth], central[smooth], rtol=0, atol=2e-7)
