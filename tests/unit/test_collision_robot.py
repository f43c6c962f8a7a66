"""A robot's collision geometry (``dk.collision.load``), its pairs and distances.

Small files here; dm_control's humanoids against MuJoCo, example-robot-data against Pinocchio
and coal, the mesh fits of the Panda and UR5, and the toy's batches, jit, gradients and large batches
in steps (long compilations): ``tests/validation/test_collision_robot_validation.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _shapes import TOY_COLLISION_URDF as URDF
from _shapes import toy_robot

import diffkin as dk
from diffkin.collision import Plane, Sphere, World

SRDF = """<robot name="toy"><disable_collisions link1="base" link2="hand" reason="Never"/></robot>"""


@pytest.fixture(scope="module")
def toy():
    return toy_robot()


def test_urdf_shapes_and_pairs(toy):
    robot, geom = toy
    assert geom.counts == (2, 2, 1, 0, 0)  # spheres, capsules (the cylinder fitted), box, cylinders, polytopes
    assert geom.shape_names == ("upper_1", "hand_0", "upper_0", "lower_0", "base_0")
    assert geom.shape_links == ("upper", "hand", "upper", "lower", "base")
    assert geom.shape_bodies == ("upper", "lower", "upper", "lower", "base")  # hand merged onto lower
    # same body and body-parent pairs are left out: only base-lower remain (box-hand, box-capsule)
    assert set(geom.pair_bodies) == {("lower", "base")}
    assert geom.pairs.shape == (2, 2)
    srdf = dk.collision.load(URDF, robot, srdf=SRDF)
    assert [geom.shape_names[i] for i in srdf.pairs.ravel()] == ["lower_0", "base_0"]
    # the cylinder's capsule contains it, and the overhead is reported for its link
    ((name, source, volume, fitted),) = geom.fits
    assert (name, source) == ("upper_0", "cylinder") and fitted >= volume
    assert set(geom.volume_overhead()) == {"upper"}


def test_overshoot_of_the_capsule_around_a_cylinder(toy):
    """The toy's cylinder (radius 0.05, length 0.5) as a capsule: its overshoot is the largest distance from the
    capsule's surface to the cylinder, here measured at 20,000 random surface points with the sphere-cylinder
    distance; the exact shapes' overshoot is 0. With ``meshes="hulls"`` the cylinder is exact."""
    robot, geom = toy
    k = geom.shape_names.index("upper_0")
    assert np.count_nonzero(geom.overshoot) == 1
    a, b, r = (np.asarray(x[0]) for x in (geom.capsules.a, geom.capsules.b, geom.capsules.radius))
    assert geom.shape_names[2] == "upper_0"
    rng = np.random.default_rng(2)
    t = rng.uniform(-r / np.linalg.norm(b - a), 1 + r / np.linalg.norm(b - a), 20_000)
    direction = rng.normal(size=(20_000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    core = a + np.clip(t, 0, 1)[:, None] * (b - a)
    points = core + r * direction  # on the capsule's surface where the core point is the nearest: most of them
    cylinder = dk.collision.Cylinder(jnp.eye(4).at[2, 3].set(0.25), 0.05, 0.25)
    far = float(np.max(np.asarray(dk.collision.distance(dk.collision.Sphere(jnp.asarray(points), 0.0), cylinder))))
    assert far <= geom.overshoot[k] + 1e-6 and far >= geom.overshoot[k] - 2e-3
    tight = dk.collision.load(URDF, robot, meshes="hulls")
    assert tight.counts == (2, 1, 1, 1, 0) and not tight.fits and np.all(tight.overshoot == 0)
    np.testing.assert_allclose(tight.cylinders.radius, [0.05])
    np.testing.assert_allclose(tight.cylinders.half_length, [0.25])


@jax.jit
def _distances(robot, geom, q, world):
    """Self distances, world distances and clearance, compiled as one program."""
    return (
        dk.collision.self_distances(robot, geom, q),
        dk.collision.world_distances(robot, geom, q, world),
        dk.collision.clearance(robot, geom, q, world),
    )


def test_distances_closed_form(toy):
    """Arm folded down onto the base: the hand sphere against the box is computed by hand."""
    robot, geom = toy
    q = jnp.array([0.0, np.pi])  # lower points straight down from the elbow at z = 0.55
    world = World(
        Plane(jnp.array([0.0, 0, 1]), -1.0), Sphere(jnp.array([[0.0, 0, 2], [5, 5, 5]]), jnp.array([0.1, 0.1]))
    )
    d, w, c = (np.asarray(x) for x in _distances(robot, geom, q, world))
    hand = dict(zip(map(tuple, geom.pairs), d, strict=True))[(1, 4)]
    # hand centre: elbow (0.55) - 0.4 = 0.15; box top at 0.05; sphere radius 0.06
    np.testing.assert_allclose(hand, 0.15 - 0.05 - 0.06, atol=1e-12)
    assert w.shape == (5, 3) and world.size == 3
    # obstacles by kind: the two spheres, then the half-space
    np.testing.assert_allclose(w[4, 2], 1.0 - 0.05, atol=1e-12)  # the base box above the floor at -1
    np.testing.assert_allclose(w[0, 0], 2 - 0.55 - 0.07 - 0.1, atol=1e-12)  # upper's sphere below the ball
    np.testing.assert_allclose(c, min(d.min(), w.min()))


def test_per_problem_worlds_equal_a_loop_of_single_worlds(toy):
    """A world with problem axes: problem ``i`` sees only its own obstacles (here 2 spheres and a box
    each, beside one shared floor), and its distances are those of its world alone (to rounding: two
    programs, fused differently); configurations ``(3, 5, dof)`` broadcast against problems ``(5,)``."""
    robot, geom = toy
    rng = np.random.default_rng(4)
    n = 5
    spheres = Sphere(rng.uniform(-0.6, 0.6, (n, 2, 3)), rng.uniform(0.02, 0.1, (n, 2)))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = rng.uniform(-0.6, 0.6, (n, 3))
    boxes = dk.collision.Box(T[:, None], rng.uniform(0.02, 0.1, (n, 1, 3)))  # (n, 1): one box per problem
    floor = Plane(jnp.array([0.0, 0, 1]), -1.0)
    world = World(spheres, boxes, floor)
    assert world.batch == (n,) and world.size == 4
    q = jnp.asarray(rng.uniform(-2, 2, (3, n, 2)))
    d, w, c = (np.asarray(x) for x in _distances(robot, geom, q, world))
    assert w.shape == (3, n, 5, 4) and c.shape == (3, n)
    for i in range(n):
        alone = World(
            Sphere(spheres.center[i], spheres.radius[i]), dk.collision.Box(boxes.pose[i], boxes.half_extents[i]), floor
        )
        d_i, w_i, c_i = (np.asarray(x) for x in _distances(robot, geom, q[:, i], alone))
        for batched, alone in ((w[:, i], w_i), (c[:, i], c_i), (d[:, i], d_i)):
            np.testing.assert_allclose(batched, alone, rtol=0, atol=1e-15)
    with pytest.raises(ValueError):
        dk.collision.world_distances(robot, geom, q[:, :4], world)


def test_bad_input():
    robot = dk.load_robot(URDF)
    with pytest.raises(ValueError, match="meshes"):
        dk.collision.load(URDF, robot, meshes="spheres")
    with pytest.raises(TypeError, match="robot"):
        dk.collision.load(URDF, dk.load_urdf(URDF, "lower"))
    with pytest.raises(ValueError, match="unknown frame 'nowhere'"):
        dk.collision.load(URDF.replace('link name="hand"', 'link name="nowhere"'), robot)
    with pytest.raises(ValueError, match="radius.*expected 1 finite"):
        dk.collision.load(URDF.replace('radius="0.06"', 'radius="x"'), robot)
    with pytest.raises(TypeError, match="World: argument 0"):
        World(np.zeros(3))


MJCF = """<mujoco>
  <default><default class="limb"><geom type="capsule" size="0.03"/></default></default>
  <option><flag filterparent="enable"/></option>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 .1"/>
    <body name="a" childclass="limb"><joint name="ja" type="hinge" axis="0 1 0"/>
      <geom name="ga" fromto="0 0 0 0 0 0.4"/>
      <geom name="ghost" type="sphere" size="0.1" contype="0" conaffinity="0"/>
      <site name="tip" pos="0 0 0.4"/>
      <body name="b" pos="0 0 0.4"><joint name="jb" type="hinge" axis="0 1 0"/>
        <geom name="gb" fromto="0 0 0 0 0 0.4"/>
        <frame pos="0 0 0.4"><body name="c"><joint name="jc" type="hinge" axis="1 0 0"/>
          <geom name="gc" type="ellipsoid" size="0.05 0.02 0.1"/>
          <geom name="gd" type="box" size="0.05 0.05 0.05" contype="2" conaffinity="2"/>
        </body></frame>
      </body>
    </body>
  </worldbody>
  <contact><exclude body1="a" body2="c"/></contact>
</mujoco>"""


def test_mjcf_classes_filters_and_fits():
    robot = dk.load_robot(MJCF)
    geom = dk.collision.load(MJCF, robot)
    assert geom.shape_names == ("ga", "gb", "gc", "gd")  # no floor (the world's), no ghost (no contact bits)
    assert geom.counts == (0, 3, 1, 0, 0)
    # a-b and b-c are parent and child, a-c excluded by <exclude>: no pair is left; without the exclude, a-c
    assert geom.pairs.shape == (0, 2)
    assert jax.jit(dk.collision.self_distances)(robot, geom, jnp.zeros(3)).shape == (0,)  # one compile (op by op: 65)
    free = dk.collision.load(MJCF.replace('<contact><exclude body1="a" body2="c"/></contact>', ""), robot)
    assert [(free.shape_names[i], free.shape_names[j]) for i, j in free.pairs] == [("ga", "gc")]  # gd: bits 2 vs 1
    c = dict(zip(geom.shape_names, range(4), strict=True))
    a, b = geom.capsules.a[c["gc"]], geom.capsules.b[c["gc"]]
    np.testing.assert_allclose(np.abs(b - a), [0, 0, 2 * (0.1 - 0.05)], atol=1e-12)  # the ellipsoid's capsule
    np.testing.assert_allclose(geom.capsules.radius[c["gc"]], 0.05)


@pytest.mark.parametrize("radius, half", [(0.1, 1.0), (0.5, 0.05), (0.2, 0.2)])
def test_cylinder_and_ellipsoid_fits_contain_them(radius, half):
    """Points of the cylinder's rims and of the ellipsoid's surface are inside their capsules."""
    from diffkin.collision import _fit

    R, L = _fit.cylinder(radius, half)
    phi = np.linspace(0, 2 * np.pi, 97)
    rim = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full_like(phi, half)], 1)
    for points in (rim, rim * [1, 1, -1]):
        d = np.linalg.norm(points - np.clip(points * [0, 0, 1], -L, L), axis=1)
        assert np.all(d <= R + 1e-15)
    semi = np.array([radius, 0.7 * half + 0.01, half])
    k, R, L = _fit.ellipsoid(semi)
    u, v = np.meshgrid(np.linspace(0, np.pi, 61), phi)
    surface = np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1).reshape(-1, 3) * semi
    axial = surface[:, k]
    radial = np.linalg.norm(np.delete(surface, k, axis=1), axis=1)
    assert np.all(np.hypot(radial, np.maximum(np.abs(axial) - L, 0)) <= R + 1e-15)


PAIRS_URDF = """<robot name="pairs">
  <link name="base"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <link name="l1"><collision><origin xyz="0 0 1.5"/><geometry><sphere radius="0.1"/></geometry></collision></link>
  <link name="l2"><collision><geometry><sphere radius="0.1"/></geometry></collision></link>
  <link name="far"><collision><geometry><sphere radius="0.1"/></geometry></collision></link>
  <link name="swing"><collision><origin xyz="0 0 0.5"/><geometry><sphere radius="0.1"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="far"/><origin xyz="0 0 5"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3"/></joint>
  <joint name="j4" type="revolute"><parent link="l1"/><child link="swing"/><origin xyz="0.5 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3"/></joint>
</robot>"""


def test_sampled_pairs_never_always_and_their_srdf():
    """Pairs chosen by sampling, as MoveIt's setup assistant: ``base``/``l2`` overlap at the origin in every
    configuration (always), ``far`` is 5 m above everything but ``l2``'s child, never near (never), ``swing``
    meets ``base`` only near ``j4 = -pi/2`` (sometimes: kept). The fractions are those of the sampled
    configurations' own self distances; the SRDF round trip through ``load(srdf=)`` drops exactly those pairs."""
    robot = dk.load_robot(PAIRS_URDF)
    geom = dk.collision.load(PAIRS_URDF, robot)
    sample = dk.collision.sample_pairs(robot, geom, 2000, key=jax.random.key(0))
    assert sample.always == (("base", "l2"),)
    assert set(sample.never) == {("base", "far"), ("far", "l1"), ("far", "swing")}
    swing = sample.colliding[sample.link_pairs.index(("base", "swing"))]
    # j4 uniform in [-3, 3]; the swing's centre is 2 sin(t/2) * 0.5 from the origin at t = j4 + pi/2: within
    # the radii (0.15) for |t| < 2 asin(0.15) = 0.3011 rad: a fraction of 0.6022 / 6 (+-0.02: 3 standard
    # deviations of a fraction of 2,000 samples).
    assert abs(swing - 4 * np.arcsin(0.15) / 6) < 0.02

    kept = sample.apply(geom)
    srdf = sample.to_srdf()
    assert 'reason="Always"' in srdf and 'reason="Never"' in srdf
    assert dk.collision.load(PAIRS_URDF, robot, srdf=srdf).pair_list == kept.pair_list
    assert {frozenset((geom.shape_links[i], geom.shape_links[j])) for i, j in kept.pair_list} == {
        frozenset(("base", "swing")),
        frozenset(("l2", "swing")),
    }
    extra = '<robot><disable_collisions link1="l2" link2="swing"/></robot>'
    both = dk.collision.load(PAIRS_URDF, robot, srdf=[srdf, extra])  # several SRDFs: the union of their pairs
    assert {frozenset((geom.shape_links[i], geom.shape_links[j])) for i, j in both.pair_list} == {
        frozenset(("base", "swing"))
    }
    with pytest.raises(TypeError, match="n: expected a positive int"):
        dk.collision.sample_pairs(robot, geom, 10.5, key=jax.random.key(0))
    with pytest.raises(ValueError, match="margin: expected a finite distance"):
        dk.collision.sample_pairs(robot, geom, 10, key=jax.random.key(0), margin=float("nan"))


@pytest.mark.parametrize(
    "srdf, message",
    [
        ('<robot><disable_collisions link1="base" link2="hnad"/></robot>', "the robot has no link 'hnad'"),
        ('<robot><disable_collisions link1="base"/></robot>', "needs link1 and link2"),
        (URDF, "a URDF, not an SRDF"),
        ('<robot><disable_collisions link1="base" link2="hand"></robot>', "not well-formed XML"),
        ("<srdf/>", "expected a <robot> root element"),
    ],
    ids=["misspelt link", "missing link2", "the URDF", "malformed", "wrong root"],
)
def test_srdf_content_is_checked(toy, srdf, message):
    """An SRDF that would silently disable nothing, or is not one, is a ValueError naming what is wrong."""
    robot, _ = toy
    with pytest.raises(ValueError, match=message):
        dk.collision.load(URDF, robot, srdf=srdf)


def test_srdf_file_errors_name_the_file(toy, tmp_path):
    robot, _ = toy
    path = tmp_path / "bad.srdf"
    path.write_text("<robot><disable_collisions")
    with pytest.raises(ValueError, match=r"srdf '.*bad\.srdf': not well-formed XML"):
        dk.collision.load(URDF, robot, srdf=str(path))


INLINE_MESH = (
    '<mujoco><asset><mesh name="m" vertex="{v}"/></asset><worldbody><body name="b"><joint name="j" type="slide"/>'
    '<geom type="mesh" mesh="m"/></body></worldbody></mujoco>'
)


@pytest.mark.parametrize(
    "vertex, message",
    [
        ("0 0 0 1 0 0 0 1 0 0 0 nan", "expected finite numbers, got nan"),
        ("0 0 0 1 0 0 0 1 0 0 0", "expected at least 4 points of 3 numbers each, got 11 numbers"),
        ("0 0 0 1 0 x 0 1 0 0 0 1", "expected numbers, got 'x'"),
    ],
    ids=["nan", "not a multiple of 3", "a word"],
)
def test_bad_inline_mesh_names_the_mesh(vertex, message):
    """An MJCF inline mesh's bad ``vertex`` is a ValueError naming the mesh (NumPy's messages before)."""
    robot = dk.load_robot(INLINE_MESH.format(v="0 0 0 1 0 0 0 1 0 0 0 1"))
    with pytest.raises(ValueError, match=rf"MJCF <mesh name='m'> vertex: {message}"):
        dk.collision.load(INLINE_MESH.format(v=vertex), robot)
