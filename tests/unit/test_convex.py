"""Convex polytopes (``dk.collision.Convex``) and the tight robot model (``dk.collision.load(...,
meshes="hulls")``): a cube given by its corners measures exactly as the ``Box`` it is, against every kind;
hull fits of meshes and their overshoot against known values; robot distances through hulls."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import random_cylinders, random_fields, rotations, shape

import diffkin as dk
from diffkin.collision import Convex, _sources, distance

CORNERS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))


def _as_convex(box_fields: dict) -> Convex:
    """The boxes as polytopes of their 8 corners (pose and scaled corners)."""
    return Convex(jnp.asarray(box_fields["pose"]), jnp.asarray(box_fields["half_extents"][:, None, :] * CORNERS))


@pytest.mark.parametrize("other", ["sphere", "capsule", "box", "cylinder", "plane"])
def test_a_cube_of_corners_is_the_box(other):
    """1,000 random placements: the polytope of a box's corners has the box's distance (the closed forms and
    the box-box separating axes; the cylinder's general distance) to 1e-9 where apart, the same sign where
    overlapping (an overlap's depth may be reported deeper than the box's exact one: never shallower),
    both orders."""
    rng = np.random.default_rng(12)
    n = 1000
    fa = random_fields("box", rng, n)
    fb = random_cylinders(rng, n) if other == "cylinder" else random_fields(other, rng, n)
    b = shape(other, fb)
    d_box, d_convex, d_swapped = jax.jit(
        lambda box, convex, b: (distance(box, b), distance(convex, b), distance(b, convex) if other != "plane" else 0.0)
    )(shape("box", fa), _as_convex(fa), b)
    d_box, d_convex = np.asarray(d_box), np.asarray(d_convex)
    apart = d_box > 1e-9
    assert 0.2 < apart.mean() < 0.95 or other == "plane"
    np.testing.assert_allclose(d_convex[apart], d_box[apart], rtol=0, atol=1e-9)
    assert np.all(d_convex[d_box < -1e-9] < 0)
    if other != "cylinder":  # the box's overlaps are exact (a cylinder's are the general distance's, as the polytope's)
        assert np.all(d_convex[~apart] <= d_box[~apart] + 1e-9)
    if other == "plane":  # the lowest vertex: exact, overlapping too
        np.testing.assert_allclose(d_convex, d_box, rtol=0, atol=1e-12)
    else:
        np.testing.assert_allclose(np.asarray(d_swapped), d_convex, rtol=0, atol=1e-12)


def test_gradient_through_a_polytope():
    """A sphere above a cube's top face: the distance grows one for one with its height and with the sphere's
    radius it falls; the cube's vertices are leaves too (raising the top face's corners closes the gap)."""
    cube = Convex(jnp.eye(4), jnp.asarray(0.1 * CORNERS))

    def d(z, r, vertices):
        return distance(dk.collision.Sphere(jnp.array([0.01, 0.02, z]), r), cube.replace(vertices=vertices))

    value, grads = jax.value_and_grad(d, argnums=(0, 1, 2))(0.5, 0.05, cube.vertices)
    np.testing.assert_allclose(value, 0.35, atol=1e-12)
    np.testing.assert_allclose(grads[0], 1.0, atol=1e-12)
    np.testing.assert_allclose(grads[1], -1.0, atol=1e-12)
    assert np.all(np.isfinite(np.asarray(grads[2])))


def _prism(outline: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangle mesh: the polygon ``outline (k, 2)`` (counter-clockwise, fan-triangulable from its
    first corner's neighbours as below) extruded along z from 0 to ``height``."""
    k = len(outline)
    V = np.concatenate([np.column_stack([outline, np.zeros(k)]), np.column_stack([outline, np.full(k, height)])])
    faces = []
    for i in range(k):  # the sides
        j = (i + 1) % k
        faces += [[i, j, k + j], [i, k + j, k + i]]
    return V, np.array(faces)


def test_hull_overshoot_of_a_concave_mesh():
    """An L-shaped prism (two unit squares' worth of the 2 x 2 square): its hull bridges the missing corner,
    whose farthest point from the L (the middle of the bridging edge, (1.5, 1.5)) is 0.5 away."""
    outline = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], dtype=np.float64)
    V, side_faces = _prism(outline, 1.0)
    # caps: the L as four triangles, bottom (downwards) and top (upwards)
    cap = [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]
    faces = np.concatenate([side_faces, [[a, c, b] for a, b, c in cap], [[a + 6, b + 6, c + 6] for a, b, c in cap]])
    spec = _sources.fitted("l", "base", V, faces, "hulls")
    assert spec.kind == "convex" and len(spec.params) == 3 * 10  # the hull drops the inner corner (1, 1)
    np.testing.assert_allclose(spec.overshoot, 0.5, atol=1e-12)
    capsule = _sources.fitted("l", "base", V, faces, "capsules")
    assert capsule.kind == "capsule" and capsule.overshoot > 0.5


MJCF = """<mujoco><asset><mesh name="cube" vertex="{corners}"/></asset><worldbody>
  <body name="link"><joint name="j" type="slide" axis="0 0 1" range="-1 1"/>
    <geom name="{name}" {geom}/></body></worldbody></mujoco>"""


@pytest.fixture(scope="module")
def cube_robots():
    """A slider carrying a 0.2 m cube: as a box geom, and as a mesh of its corners (hulls / capsules)."""
    corners = " ".join(f"{v:g}" for v in (0.1 * CORNERS).reshape(-1))
    box = MJCF.format(corners=corners, name="box", geom='type="box" size=".1 .1 .1"')
    mesh = MJCF.format(corners=corners, name="mesh", geom='type="mesh" mesh="cube"')
    robot = dk.load_robot(box)
    return (
        robot,
        dk.collision.load(box, robot),
        {m: dk.collision.load(mesh, robot, meshes=m) for m in ("hulls", "capsules")},
    )


def test_robot_distances_through_hulls(cube_robots):
    """The mesh's hull is the cube: world distances and clearance equal the box geom's (apart), overshoot 0
    for the hull and the box, the capsule's reaching past the cube."""
    robot, box_geom, fits = cube_robots
    hull = fits["hulls"]
    assert hull.counts == (0, 0, 0, 0, 1) and box_geom.counts == (0, 0, 1, 0, 0)
    assert hull.overshoot.tolist() == [0.0] and box_geom.overshoot.tolist() == [0.0]
    assert fits["capsules"].overshoot[0] > 0.05
    world = dk.collision.World(
        dk.collision.Sphere(jnp.array([[0.3, 0.0, 0.0], [0.0, 0.0, 0.5]]), jnp.array([0.05, 0.1])),
        dk.collision.Cylinder(jnp.eye(4).at[0, 3].set(-0.4), 0.1, 0.2),
    )
    q = jnp.array([[0.0], [0.05], [-0.1]])
    d_box = np.asarray(dk.collision.world_distances(robot, box_geom, q, world))
    d_hull = np.asarray(dk.collision.world_distances(robot, hull, q, world))
    np.testing.assert_allclose(d_hull, d_box, rtol=0, atol=1e-9)
    np.testing.assert_allclose(d_box[:, 0, 0], 0.15, atol=1e-12)  # the small sphere, beside the cube
    np.testing.assert_allclose(d_box[:, 0, 2], 0.2, atol=1e-12)  # the cylinder, beside the other face


def test_float32_gjk_stops_where_it_cannot_get_nearer(monkeypatch):
    """4,000 random box-cylinder pairs: in float32 a pair can stall a few roundings short of GJK's tolerance
    (a cylinder's rim converges linearly); it stops there instead of holding the batch for every one of
    ``STEPS`` (which it did: 128 steps). The float32 distances of the pairs apart are never above float64's
    (a lower bound) and 98 % of them are within 1e-5 m; the rest, near a rim, are off by up to ~1.2e-4 m,
    with or without this stop (float32's GJK on a curved rim: a known limit, not this test's subject)."""
    from diffkin.collision import _gjk

    rng = np.random.default_rng(0)
    fa, fb = random_fields("box", rng, 4000), random_cylinders(rng, 4000)
    steps = []
    loop = jax.lax.while_loop

    def counted(cond, body, state):  # GJK's loop carries (step, Ya, Yb, mask, lam, done, nearest, idle)
        out = loop(cond, body, state)
        if len(state) == 8:
            steps.append(int(out[0]))
        return out

    monkeypatch.setattr(jax.lax, "while_loop", counted)
    _gjk.witnesses(shape("box", fa, jnp.float32), shape("cylinder", fb, jnp.float32))
    assert 0 < steps[0] <= _gjk.STEPS // 4
    monkeypatch.undo()
    d32, d64 = (
        np.asarray(jax.jit(distance)(shape("box", fa, dt), shape("cylinder", fb, dt))) for dt in ("float32", "float64")
    )
    apart = d64 > 1e-3
    assert apart.mean() > 0.3
    over = d32[apart] - d64[apart]
    assert over.max() < 2e-7 and np.mean(over > -1e-5) > 0.98 and over.min() > -1.5e-4


def test_bad_convex_input():
    with pytest.raises(ValueError, match=r"Convex\.vertices: expected shape \(\.\.\., 3\)"):
        Convex(jnp.eye(4), jnp.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"Convex\.vertices: expected shape \(\.\.\., V, 3\) with V >= 1"):
        Convex(jnp.eye(4), jnp.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"meshes: expected 'hulls' or 'capsules'"):
        dk.collision.load(MJCF.format(corners="0 0 0", name="m", geom='type="box" size=".1 .1 .1"'), None, meshes="x")


def test_bounding_boxes_contain_their_shapes_and_bound_distances():
    """Each solid's ``bounding_box`` (the broad phase of IK's clearance) holds the shape: its support
    points along 200 random directions lie in the box; and the cheap ``lower_bound`` of the general
    (GJK) pairs never exceeds their distance, on random placements of every such pair of kinds."""
    from diffkin.collision._distance import GENERAL, lower_bound

    rng = np.random.default_rng(11)
    n = 64
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = rotations(rng, n)
    T[:, :3, 3] = rng.uniform(-0.5, 0.5, (n, 3))
    shapes = {
        kind: shape(kind, random_cylinders(rng, n) if kind == "cylinder" else random_fields(kind, rng, n))
        for kind in ("sphere", "capsule", "box", "cylinder")
    }
    shapes["convex"] = Convex(
        jnp.asarray(T), jnp.asarray(rng.normal(0, 0.15, (n, 12, 3)) + rng.uniform(-0.1, 0.1, (n, 1, 3)))
    )
    directions = rng.normal(size=(200, 1, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    for kind, s in shapes.items():
        box = s.bounding_box()
        points = np.asarray(s.core_support(jnp.asarray(directions))) + np.asarray(s.rounding())[..., None] * directions
        R, c = np.asarray(box.pose)[:, :3, :3], np.asarray(box.pose)[:, :3, 3]
        local = np.einsum("nji,dnj->dni", R, points - c)
        assert np.all(np.abs(local) <= np.asarray(box.half_extents) + 1e-12), kind
    by_type = {type(s): s for s in shapes.values()}
    pairs = {(a, b) for a, b in GENERAL if a in by_type and b in by_type}
    assert len(pairs) >= 8  # every general pair of these kinds, both orders
    for a, b in sorted(pairs, key=lambda p: (p[0].__name__, p[1].__name__)):
        other = jax.tree.map(lambda x: jnp.roll(x, 1, axis=0), by_type[b])  # (another shape where a is b)
        bound, exact = (np.asarray(f(by_type[a], other)) for f in (lower_bound, distance))
        assert np.all(bound <= exact + 1e-9), (a.__name__, b.__name__, float(np.max(bound - exact)))
        assert np.mean(bound > 0) > 0.2, (a.__name__, b.__name__)  # not a vacuous bound


def _distance_to_hull(points: np.ndarray, p: np.ndarray) -> float:
    """The distance from ``p`` to the convex hull of ``points`` (``(V, 3)``), by non-negative least squares
    on the weights of a convex combination (their sum held at 1 by a heavily weighted row)."""
    from scipy.optimize import nnls

    A = np.vstack([points.T, 1e4 * np.ones(len(points))])
    weights, _ = nnls(A, np.r_[p, 1e4])
    return float(np.linalg.norm(points.T @ weights - p))


def test_inner_polytopes_lie_within_their_originals():
    """Five clouds of 150 points (ellipsoids, flattened or stretched), 24 of their vertices chosen: each an
    original point; the distances of 500 random balls to their hull never below the distance to the
    original's, and above it by at most the Hausdorff distance of the two hulls (the farthest original point
    from the inner hull, by least squares; less than half that of 24 points taken as they come) (GJK both)."""
    from diffkin.collision._inner import chosen

    rng = np.random.default_rng(5)
    for axes in ([0.05, 0.05, 0.25], [0.1, 0.08, 0.02], [0.1, 0.1, 0.1], [0.2, 0.03, 0.07], [0.06, 0.12, 0.09]):
        u = rng.normal(size=(150, 3))
        cloud = u / np.linalg.norm(u, axis=1, keepdims=True) * axes * rng.uniform(0.8, 1.0, (150, 1))
        points = chosen(cloud, 24)
        assert points.shape == (24, 3)
        assert all(np.any(np.all(cloud == p, axis=1)) for p in points)
        hausdorff = max(_distance_to_hull(points, p) for p in cloud)
        arbitrary = max(_distance_to_hull(cloud[:24], p) for p in cloud)  # 24 of the points, not chosen
        assert hausdorff < 0.5 * arbitrary
        centres = rng.normal(size=(500, 3)) * 0.3
        ball = dk.collision.Sphere(jnp.asarray(centres), jnp.asarray(rng.uniform(0.01, 0.05, 500)))
        d_full = np.asarray(distance(ball, Convex(jnp.eye(4), jnp.asarray(cloud))))
        d_inner = np.asarray(distance(ball, Convex(jnp.eye(4), jnp.asarray(points))))
        apart = d_full > 0
        assert apart.mean() > 0.5
        assert np.all(d_inner[apart] >= d_full[apart] - 1e-12)
        assert np.all(d_inner[apart] <= d_full[apart] + hausdorff + 1e-6)


def test_inner_geometry_keeps_small_polytopes_and_other_shapes(cube_robots):
    """A geometry whose polytopes have no more vertices than asked is returned as it is; a mesh of 100 points
    gets 16, the shape's frame, pose and name unchanged."""
    from diffkin.collision._inner import inner

    robot, _, fits = cube_robots
    assert inner(fits["hulls"], 16) is fits["hulls"]
    u = np.random.default_rng(2).normal(size=(100, 3))
    sphere_mesh = " ".join(f"{v:g}" for v in (0.1 * u / np.linalg.norm(u, axis=1, keepdims=True)).reshape(-1))
    mjcf = MJCF.format(corners=sphere_mesh, name="ball", geom='type="mesh" mesh="cube"')
    geom = dk.collision.load(mjcf, dk.load_robot(mjcf), meshes="hulls")
    fewer = inner(geom, 16)
    assert fewer.convexes.vertices.shape[-2] == 16 and geom.convexes.vertices.shape[-2] >= 90
    assert fewer.shape_names == geom.shape_names and fewer.shape_frames == geom.shape_frames
    np.testing.assert_array_equal(np.asarray(fewer.convexes.pose), np.asarray(geom.convexes.pose))
