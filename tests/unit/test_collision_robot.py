"""A robot's collision geometry (``dk.collision.load``), its pairs and distances.

Small files here; dm_control's humanoids against MuJoCo, example-robot-data against Pinocchio
and coal, and the mesh fits of the Panda and UR5 (marked slow: cross-library).
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffkin as dk
from diffkin.collision import Box, Plane, Sphere, World

URDF = """<robot name="toy">
  <link name="base"><collision><geometry><box size="0.4 0.4 0.1"/></geometry></collision></link>
  <link name="upper">
    <collision><origin xyz="0 0 0.25"/><geometry><cylinder radius="0.05" length="0.5"/></geometry></collision>
    <collision><origin xyz="0 0 0.5"/><geometry><sphere radius="0.07"/></geometry></collision>
  </link>
  <link name="lower"><collision><origin xyz="0 0 0.2" rpy="0 1.5707963267948966 0"/>
    <geometry><capsule radius="0.04" length="0.4"/></geometry></collision></link>
  <link name="hand"><collision><geometry><sphere radius="0.06"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="upper"/><origin xyz="0 0 0.05"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="j2" type="revolute"><parent link="upper"/><child link="lower"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3"/></joint>
  <joint name="fixed" type="fixed"><parent link="lower"/><child link="hand"/><origin xyz="0 0 0.4"/></joint>
</robot>"""

SRDF = """<robot name="toy"><disable_collisions link1="base" link2="hand" reason="Never"/></robot>"""


@pytest.fixture(scope="module")
def toy():
    robot = dk.load_robot(URDF)
    return robot, dk.collision.load(URDF, robot)


def test_urdf_shapes_and_pairs(toy):
    robot, geom = toy
    assert geom.counts == (2, 2, 1)  # spheres, capsules (the cylinder fitted), box
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


def test_distances_closed_form(toy):
    """Arm folded down onto the base: the hand sphere against the box is computed by hand."""
    robot, geom = toy
    q = jnp.array([0.0, np.pi])  # lower points straight down from the elbow at z = 0.55
    d = jax.jit(dk.collision.self_distances)(robot, geom, q)
    hand = dict(zip(map(tuple, geom.pairs), d, strict=True))[(1, 4)]
    # hand centre: elbow (0.55) - 0.4 = 0.15; box top at 0.05; sphere radius 0.06
    np.testing.assert_allclose(hand, 0.15 - 0.05 - 0.06, atol=1e-12)
    world = World(
        Plane(jnp.array([0.0, 0, 1]), -1.0), Sphere(jnp.array([[0.0, 0, 2], [5, 5, 5]]), jnp.array([0.1, 0.1]))
    )
    w = jax.jit(dk.collision.world_distances)(robot, geom, q, world)
    assert w.shape == (5, 3) and world.size == 3
    # obstacles by kind: the two spheres, then the half-space
    np.testing.assert_allclose(w[4, 2], 1.0 - 0.05, atol=1e-12)  # the base box above the floor at -1
    np.testing.assert_allclose(w[0, 0], 2 - 0.55 - 0.07 - 0.1, atol=1e-12)  # upper's sphere below the ball
    c = jax.jit(dk.collision.clearance)(robot, geom, q, world)
    np.testing.assert_allclose(c, min(d.min(), w.min()))


def test_batches_base_jit_and_gradients(toy):
    """Batched q and a floating base (a shift moves every shape), under jit, with finite gradients."""
    robot, geom = toy
    q = jnp.asarray(np.random.default_rng(0).uniform(-3, 3, (6, 2)))
    world = World(Box(jnp.eye(4).at[2, 3].set(-1.0), jnp.ones(3)))
    w = jax.jit(lambda q: dk.collision.world_distances(robot, geom, q, world))(q)
    assert w.shape == (6, 5, 1)
    up = jnp.eye(4).at[2, 3].set(0.3)
    np.testing.assert_allclose(dk.collision.world_distances(robot, geom, q, world, base=up), w + 0.3, atol=1e-12)
    assert dk.collision.self_distances(robot, geom, q[0], base=jnp.stack([up, up])).shape == (2, 2)
    g = jax.jit(jax.grad(lambda q: dk.collision.clearance(robot, geom, q, world)))(q[0])
    assert np.all(np.isfinite(g))
    g32 = jax.jit(jax.grad(lambda q: dk.collision.clearance(robot, geom, q, world).sum()))(q.astype(jnp.float32))
    assert np.all(np.isfinite(g32))


def test_large_batches_go_in_steps(toy, monkeypatch):
    """Above twice the step, the batch goes through in fixed-size steps (the last overlapping): same values,
    a floating base included, and gradients through the steps."""
    from diffkin.collision import _robot

    robot, geom = toy
    rng = np.random.default_rng(3)
    q = jnp.asarray(rng.uniform(-3, 3, (5, 7, 2)))
    base = jnp.tile(jnp.eye(4), (7, 1, 1)).at[:, :3, 3].set(jnp.asarray(rng.uniform(-0.2, 0.2, (7, 3))))
    world = World(Box(jnp.eye(4).at[2, 3].set(-1.0), jnp.ones(3)), Sphere(jnp.array([0.3, 0, 0.5]), 0.1))
    whole = (
        dk.collision.self_distances(robot, geom, q, base),
        dk.collision.world_distances(robot, geom, q, world, base),
    )
    monkeypatch.setattr(_robot, "STEP", 4)
    stepped = (
        dk.collision.self_distances(robot, geom, q, base),
        dk.collision.world_distances(robot, geom, q, world, base),
    )
    for a, b in zip(whole, stepped, strict=True):
        assert a.shape == b.shape
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-14)
    # jitted: op by op, the derivative of the steps' loop is compiled piece by piece, several times slower;
    # the ball only (the box's derivative, tested in test_collision.py, triples the compile time)
    ball = World(Sphere(jnp.array([0.3, 0, 0.5]), 0.1))
    g = jax.jit(jax.grad(lambda q: dk.collision.clearance(robot, geom, q, ball).sum()))(q)
    assert g.shape == q.shape and np.all(np.isfinite(g))


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
    assert geom.counts == (0, 3, 1)
    # a-b and b-c are parent and child, a-c excluded by <exclude>: no pair is left; without the exclude, a-c
    assert geom.pairs.shape == (0, 2)
    assert dk.collision.self_distances(robot, geom, jnp.zeros(3)).shape == (0,)
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


# -------------------------------------------------------------------------------- against MuJoCo

SUITE = None


def _suite(name: str) -> str:
    dm_control = pytest.importorskip("dm_control")
    return os.path.join(os.path.dirname(dm_control.__file__), "suite", name)


def _mujoco_pairs(m, mujoco) -> set[tuple[str, str]]:
    """Geom pairs MuJoCo's collision filter lets through (its rule, on the compiled model's arrays):
    not one weld body, not weld parent and child unless one is the world (filterparent on), contype
    and conaffinity bits meeting, no <exclude> of the two bodies. World geoms are left out."""
    weld, parent = m.body_weldid, m.body_parentid
    filterparent = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    excluded = {(int(s) >> 16, int(s) & 0xFFFF) for s in m.exclude_signature}
    out = set()
    geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0]
    for i, g1 in enumerate(geoms):
        for g2 in geoms[i + 1 :]:
            b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
            w1, w2 = weld[b1], weld[b2]
            if w1 == w2:
                continue
            if filterparent and w1 and w2 and (w1 == weld[parent[w2]] or w2 == weld[parent[w1]]):
                continue
            if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
                continue
            if (min(b1, b2) << 16) + max(b1, b2) in {(a << 16) + b for a, b in excluded}:
                continue
            out.add(tuple(sorted((m.geom(g1).name, m.geom(g2).name))))
    return out


def _mujoco_configs(robot, m, mujoco, n, seed):
    """``n`` random configurations as diffkin's ``(q, T_world_root)`` and MuJoCo's ``qpos``."""
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    q = rng.uniform(lo, hi, (n, robot.dof))
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    pos = rng.uniform(-1, 1, (n, 3))
    base = np.tile(np.eye(4), (n, 1, 1))
    base[:, :3, :3], base[:, :3, 3] = np.asarray(dk.se3.rotation_from_quaternion(quat)), pos
    qpos = np.zeros((n, m.nq))
    qpos[:, :3], qpos[:, 3:7] = pos, quat
    for k, name in enumerate(robot.joint_names):
        qpos[:, m.joint(name).qposadr[0]] = q[:, k]
    return q, base, qpos


@pytest.mark.slow
@pytest.mark.parametrize("model", ["humanoid.xml", "humanoid_CMU.xml"])
def test_humanoids_against_mujoco(model):
    """Active pairs equal MuJoCo's filter; every pair's distance equals mj_geomDistance to 1e-9 at 200
    configurations where both shapes are exact (capsules, spheres, boxes), and is never larger where a
    shape is a fitted ellipsoid (conservative)."""
    mujoco = pytest.importorskip("mujoco")
    path = _suite(model)
    m, robot = mujoco.MjModel.from_xml_path(path), dk.load_robot(path)
    data = mujoco.MjData(m)
    geom = dk.collision.load(path, robot)
    names = geom.shape_names
    ours = {tuple(sorted((names[i], names[j]))) for i, j in geom.pairs}
    assert ours == _mujoco_pairs(m, mujoco)
    q, base, qpos = _mujoco_configs(robot, m, mujoco, 200, seed=3)
    # robot and geometry closed over: their numbers fold into the program (a traced 56-joint robot's
    # forward pass compiles ~15x slower)
    d = np.asarray(jax.jit(lambda q, base: dk.collision.self_distances(robot, geom, q, base))(q, base))
    fitted = {name for name, *_ in geom.fits}
    ref = np.empty_like(d)
    ids = [(m.geom(names[i]).id, m.geom(names[j]).id) for i, j in geom.pairs]
    for k in range(len(q)):
        data.qpos[:] = qpos[k]
        mujoco.mj_kinematics(m, data)
        ref[k] = [mujoco.mj_geomDistance(m, data, g1, g2, 100.0, None) for g1, g2 in ids]
    exact = np.array([names[i] not in fitted and names[j] not in fitted for i, j in geom.pairs])
    assert exact.sum() > 50 and np.mean(ref[:, exact] < 0) > 0.001
    np.testing.assert_allclose(d[:, exact], ref[:, exact], rtol=0, atol=1e-9)
    assert np.all(d[:, ~exact] <= ref[:, ~exact] + 1e-9)


# -------------------------------------------------------------------------------- against Pinocchio, coal


def _erd(*parts: str) -> str:
    from _reference import ERD

    path = os.path.join(ERD, *parts) if ERD else ""
    if not os.path.isfile(path):
        pytest.skip(f"example-robot-data lacks {parts}")
    return path


@pytest.mark.slow
def test_primitive_urdf_against_pinocchio():
    """panda_collision.urdf (spheres, cylinders, meshes): every self pair of two exact shapes against
    pin.computeDistances to 1e-9 at 50 configurations; pairs with a fitted shape never farther."""
    pin = pytest.importorskip("pinocchio")
    path = _erd("panda_description", "urdf", "panda_collision.urdf")
    share = os.path.abspath(os.path.join(path, *[".."] * 5))  # the folder holding example-robot-data/
    model = pin.buildModelFromUrdf(path)
    cmodel = pin.buildGeomFromUrdf(model, path, pin.GeometryType.COLLISION, package_dirs=[share])
    robot = dk.load_robot(path)
    geom = dk.collision.load(path, robot)
    names = [g.name for g in cmodel.geometryObjects]
    ids = [names.index(n) for n in geom.shape_names]
    for i, j in geom.pairs:
        cmodel.addCollisionPair(pin.CollisionPair(ids[i], ids[j]))
    data, cdata = model.createData(), pin.GeometryData(cmodel)
    rng = np.random.default_rng(5)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    q = rng.uniform(lo, hi, (50, robot.dof))
    d = np.asarray(jax.jit(lambda q: dk.collision.self_distances(robot, geom, q))(q))
    ref = np.empty_like(d)
    for k in range(len(q)):
        qp = pin.neutral(model)
        for n, name in enumerate(robot.joint_names):
            qp[model.joints[model.getJointId(name)].idx_q] = q[k, n]
        for name, (source, multiplier, offset) in robot.mimic.items():  # pinocchio: an independent joint
            qp[model.joints[model.getJointId(name)].idx_q] = multiplier * q[k, robot.joint_names.index(source)] + offset
        pin.computeDistances(model, data, cmodel, cdata, qp)
        ref[k] = [r.min_distance for r in cdata.distanceResults]
    fitted = {name for name, *_ in geom.fits}
    exact = np.array([geom.shape_names[i] not in fitted and geom.shape_names[j] not in fitted for i, j in geom.pairs])
    assert exact.sum() >= 20
    np.testing.assert_allclose(d[:, exact], ref[:, exact], rtol=0, atol=1e-9)
    assert np.all(d[:, ~exact] <= ref[:, ~exact] + 1e-9)


@pytest.mark.slow
@pytest.mark.parametrize(
    "parts", [("panda_description", "urdf", "panda.urdf"), ("ur_description", "urdf", "ur5_robot.urdf")]
)
def test_mesh_fits_contain_every_vertex(parts):
    """Every vertex of every collision mesh is inside its capsule; where coal finds the real meshes
    of a self pair in collision, diffkin's distance is not positive (100 configurations)."""
    trimesh = pytest.importorskip("trimesh")
    coal = pytest.importorskip("coal")
    from diffkin._meshfiles import resolve_mesh
    from diffkin.models.urdf import rpy_matrix

    path = _erd(*parts)
    robot = dk.load_robot(path)
    geom = dk.collision.load(path, robot)
    import xml.etree.ElementTree as ET

    meshes = {}
    for link in ET.parse(path).getroot().findall("link"):
        for k, c in enumerate(link.findall("collision")):
            mesh = c.find("geometry/mesh")
            if mesh is not None:
                T = np.eye(4)
                origin = c.find("origin")
                if origin is not None:
                    T[:3, :3] = rpy_matrix(np.array([float(x) for x in origin.get("rpy", "0 0 0").split()]))
                    T[:3, 3] = [float(x) for x in origin.get("xyz", "0 0 0").split()]
                v = trimesh.load(resolve_mesh(mesh.get("filename"), os.path.dirname(path)), force="mesh")
                meshes[f"{link.get('name')}_{k}"] = (np.asarray(v.vertices) @ T[:3, :3].T + T[:3, 3], v)
    assert len(meshes) >= 6
    ns = geom.counts[0]
    for name, (vertices, _) in meshes.items():
        i = geom.shape_names.index(name) - ns
        a, b, r = (np.asarray(x[i]) for x in (geom.capsules.a, geom.capsules.b, geom.capsules.radius))
        t = np.clip((vertices - a) @ (b - a) / max((b - a) @ (b - a), 1e-300), 0, 1)
        outside = np.linalg.norm(vertices - a - t[:, None] * (b - a), axis=1) - r
        assert np.all(outside <= 0), (name, outside.max())
    overhead = geom.volume_overhead()
    assert all(v >= 0 for v in overhead.values())
    # coal on the real meshes: in collision means diffkin is not separated
    rng = np.random.default_rng(9)
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    q = rng.uniform(lo, hi, (100, robot.dof))
    d = np.asarray(jax.jit(lambda q: dk.collision.self_distances(robot, geom, q))(q))
    T = np.asarray(jax.jit(lambda q: dk.link_poses(robot, q))(q))
    bvh = {}
    for name, (vertices, mesh) in meshes.items():
        model = coal.BVHModelOBBRSS()
        model.beginModel(len(mesh.faces), len(vertices))
        model.addVertices(np.ascontiguousarray(vertices))
        model.addTriangles(np.asarray(mesh.faces, dtype=np.int64))
        model.endModel()
        bvh[name] = model
    colliding = 0
    for p, (i, j) in enumerate(geom.pairs):
        ni, nj = geom.shape_names[i], geom.shape_names[j]
        if ni not in bvh or nj not in bvh:
            continue
        for k in range(len(q)):
            Ti, Tj = T[k, geom.shape_frames[i]], T[k, geom.shape_frames[j]]
            result = coal.CollisionResult()
            coal.collide(
                bvh[ni],
                coal.Transform3s(Ti[:3, :3], Ti[:3, 3]),
                bvh[nj],
                coal.Transform3s(Tj[:3, :3], Tj[:3, 3]),
                coal.CollisionRequest(),
                result,
            )
            if result.isCollision():
                colliding += 1
                assert d[k, p] <= 0, (ni, nj, k, d[k, p])
    assert colliding > 0
