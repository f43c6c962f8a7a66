"""Primitive shapes' signed distances (``dk.collision``) against coal (Pinocchio's collision library) on
10,000 random pairs of every pair kind, float64 and float32; the distance between shapes apart against
a brute force over every feature pair; gradients against finite differences."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import SHAPE_PAIRS as PAIRS
from _shapes import coal_shape, random_fields, shape

import diffkin as dk
from diffkin.collision import Box, Capsule, Plane, Sphere, _boxes, distance
from diffkin.collision import _closest as cl

N = 10_000


def coal_distances(kind_a: str, fa: dict, kind_b: str, fb: dict) -> np.ndarray:
    """coal's signed distances, one pair at a time. GJK/EPA (pairs with a box) at tolerance 1e-12:
    at coal's default (1e-6) one pair in 2,000 is off by 4.5e-7."""
    coal = pytest.importorskip("coal")
    request = coal.DistanceRequest()
    request.gjk_tolerance = request.epa_tolerance = 1e-12
    out = np.empty(len(next(iter(fa.values()))))
    for i in range(out.size):
        ga, Ta = coal_shape(coal, kind_a, fa, i)
        gb, Tb = coal_shape(coal, kind_b, fb, i)
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


# ------------------------------------------------------------------------------------ against coal


def _jitted(kind_a, kind_b, dtype):
    return jax.jit(lambda fa, fb: distance(shape(kind_a, fa, dtype), shape(kind_b, fb, dtype)))


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
    if mode == "crossing faces":  # boxes turned about z, stacked: parallel faces crossing
        angle = rng.uniform(0, 2 * np.pi, n)
        if kind == "capsule":  # level segments above or below the boxes
            mid = np.column_stack([rng.uniform(-0.05, 0.05, (n, 2)), rng.uniform(0, 0.4, n)])
            half = rng.uniform(0.1, 0.3, (n, 1)) * np.column_stack([np.cos(angle), np.sin(angle), np.zeros(n)])
            return {"a": mid - half, "b": mid + half, "radius": rng.uniform(0, 0.05, n)}
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle)
        # squarish, centred near each other: octagons and hexagons of crossings, no corner inside the other
        h = np.column_stack([rng.uniform(0.1, 0.2, (n, 2)), rng.uniform(0.02, 0.1, n)])
        T[:, :2, 3] = rng.uniform(-0.05, 0.05, (n, 2))
        T[:, 2, 3] = rng.uniform(0, 0.4, n)
        return {"pose": T, "half_extents": h}
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


@pytest.mark.parametrize("mode", ["random", "quarter turns", "about z", "crossing faces"])
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


def test_crossing_faces_are_apart_along_their_normal():
    """Parallel faces crossing without a corner inside each other (the pairs no corner or edge candidate
    reaches): the distance is the gap between the faces, and the contact normal is theirs (its closest
    points are a crossing of the two borders)."""
    rng = np.random.default_rng(6)
    fa, fb = tricky_fields("box", "crossing faces", rng, 2_000), tricky_fields("box", "crossing faces", rng, 2_000)
    d, n, p = jax.jit(_boxes.box_box_contact)(shape("box", fa, jnp.float64), shape("box", fb, jnp.float64))
    gap = np.abs(fb["pose"][:, 2, 3] - fa["pose"][:, 2, 3]) - fa["half_extents"][:, 2] - fb["half_extents"][:, 2]
    brute = brute_apart("box", fa, fb)
    faces = np.abs(brute - gap) < 1e-12  # the faces overlap seen along z
    assert np.sum(faces & (gap > 0)) > 500
    np.testing.assert_allclose(np.asarray(d)[faces & (gap > 0)], gap[faces & (gap > 0)], rtol=0, atol=1e-12)
    normal_z = np.abs(np.asarray(n[2]))[faces & (gap > 0)]
    np.testing.assert_allclose(normal_z, 1.0, rtol=0, atol=1e-9)


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
