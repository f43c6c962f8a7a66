"""A robot's collision geometry (``dk.collision.load``) against other libraries: dm_control's humanoids
against MuJoCo, example-robot-data against Pinocchio and coal, and the mesh fits of the Panda and UR5;
a toy arm's batches, jit and gradients against finite differences, and large batches in steps."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _models import ERD
from _shapes import toy_robot

import diffkin as dk
from diffkin.collision import Box, Sphere, World


@pytest.fixture(scope="module")
def toy():
    return toy_robot()


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
    path = os.path.join(ERD, *parts) if ERD else ""
    if not os.path.isfile(path):
        pytest.skip(f"example-robot-data lacks {parts}")
    return path


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
