"""Collision-aware IK on a Panda among a table, a shelf and spheres: diffkin with ``avoid`` against
diffkin without it and PyRoki's collision IK, on the same targets (issue 28's benchmark).

Targets are ``panda_hand`` poses of random configurations whose fitted capsules clear every
obstacle and each other by 3 cm. Every returned configuration is judged the same way, in float64:
pose error (success at 1e-5 m / 1e-4 rad and at 5 mm / 0.05 rad), joint limits, and collision of
the **real meshes** (coal: the URDF's collision meshes as BVH models and its finger boxes, against
the obstacles and over the self pairs that diffkin checks; SRDF-disabled pairs left out).

PyRoki (``experiments/_pyroki_peer.py``: its collision-IK example, one start, vmapped) is run when
it is installed (``pyroki`` and ``jaxls`` from their sources; commits in that file). Warm times:
diffkin's two solvers timed in turns (medians over 2 s of calls each), PyRoki's calls on their own
(median of 3); a last table gives the ratios.

    python experiments/bench_ik_collision.py            # batches 1, 100, 1,000 (float32)
    python experiments/bench_ik_collision.py --quick    # batches 1 and 100
    python experiments/bench_ik_collision.py --baxter 100  # Baxter, two hands, self-collision
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
from _bench import example_robot_data, median_seconds, median_seconds_interleaved
from bench_collision import panda

import diffkin as dk
from diffkin._xla import solver_jit  # compiled as dk.ik.solve compiles itself (docs/performance.md)

C = dk.collision
MARGIN = 0.01
EE = "panda_hand"


def scene() -> dict:
    """The obstacles: a floor under the robot's plate, a table in front, a shelf (board and side wall), two spheres."""
    boxes = [  # (centre, half extents)
        ((0.65, 0.0, 0.0), (0.25, 0.5, 0.05)),
        ((0.6, 0.0, 0.8), (0.2, 0.45, 0.02)),
        ((0.6, 0.5, 0.42), (0.2, 0.02, 0.37)),
    ]
    spheres = np.array([[0.3, -0.45, 0.45, 0.1], [0.25, 0.35, 0.95, 0.08]])
    return {
        "boxes": [(_translation(c), np.array(h)) for c, h in boxes],
        "spheres": spheres,
        "plane": (np.array([0.0, 0.0, 1.0]), -0.15),
    }


def _translation(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


def world_of(s: dict, dtype) -> C.World:
    return C.World(
        C.Sphere(jnp.asarray(s["spheres"][:, :3], dtype), jnp.asarray(s["spheres"][:, 3], dtype)),
        C.Box(jnp.asarray(np.stack([T for T, _ in s["boxes"]]), dtype), jnp.asarray([h for _, h in s["boxes"]], dtype)),
        C.Plane(jnp.asarray(s["plane"][0], dtype), jnp.asarray(s["plane"][1], dtype)),
    )


class RealGeometry:
    """The URDF's collision geometry in coal (meshes as BVH models, boxes exact) and the scene's obstacles."""

    def __init__(self, urdf: str, robot: dk.Robot, geom: C.Geometry, s: dict | None):
        import coal
        import trimesh

        from diffkin._meshfiles import resolve_mesh
        from diffkin.models.urdf import rpy_matrix

        self.coal, self.robot = coal, robot
        self.shapes: dict[str, tuple[object, np.ndarray, int]] = {}  # name -> (coal shape, T_frame_shape, frame)
        for link in ET.parse(urdf).getroot().findall("link"):
            for k, c in enumerate(link.findall("collision")):
                T = np.eye(4)
                origin = c.find("origin")
                if origin is not None:
                    T[:3, :3] = rpy_matrix(np.array([float(x) for x in origin.get("rpy", "0 0 0").split()]))
                    T[:3, 3] = [float(x) for x in origin.get("xyz", "0 0 0").split()]
                g = c.find("geometry")
                mesh, box, cylinder, sphere = (g.find(k) for k in ("mesh", "box", "cylinder", "sphere"))
                if mesh is not None:
                    m = trimesh.load(resolve_mesh(mesh.get("filename"), os.path.dirname(urdf)), force="mesh")
                    model = coal.BVHModelOBBRSS()
                    model.beginModel(len(m.faces), len(m.vertices))
                    model.addVertices(np.ascontiguousarray(m.vertices, dtype=np.float64))
                    model.addTriangles(np.asarray(m.faces, dtype=np.int64))
                    model.endModel()
                    shape: object = model
                elif box is not None:
                    shape = coal.Box(*[float(x) for x in box.get("size").split()])
                elif cylinder is not None:
                    shape = coal.Cylinder(float(cylinder.get("radius")), float(cylinder.get("length")))
                elif sphere is not None:
                    shape = coal.Sphere(float(sphere.get("radius")))
                else:
                    raise ValueError(f"{link.get('name')}: unexpected collision geometry")
                self.shapes[f"{link.get('name')}_{k}"] = (shape, T, robot.frame_index(link.get("name")))
        self.pairs = [(geom.shape_names[i], geom.shape_names[j]) for i, j in geom.pairs]
        self.obstacles: list = []
        if s is None:
            return
        self.obstacles = [(coal.Sphere(float(r)), np.r_[x, y, z]) for x, y, z, r in s["spheres"]]
        self.obstacles += [(coal.Box(*(2 * h)), T) for T, h in s["boxes"]]
        n, d = s["plane"]
        self.obstacles += [(coal.Halfspace(np.asarray(n, np.float64), float(d)), np.eye(4))]

    def _tf(self, T):
        if T.shape == (3,):
            return self.coal.Transform3s(np.eye(3), T)
        return self.coal.Transform3s(T[:3, :3], T[:3, 3])

    def colliding(self, q: np.ndarray) -> np.ndarray:
        """``(N,)`` whether the real geometry at ``q`` touches an obstacle or itself."""
        coal = self.coal
        link = np.asarray(dk.link_poses(self.robot, jnp.asarray(q, jnp.float64)))
        out = np.zeros(len(q), bool)
        for k in range(len(q)):
            placed = {name: (shape, link[k, f] @ T) for name, (shape, T, f) in self.shapes.items()}

            def hit(a, Ta, b, Tb):
                result = coal.CollisionResult()
                coal.collide(a, self._tf(Ta), b, self._tf(Tb), coal.CollisionRequest(), result)
                return result.isCollision()

            out[k] = any(hit(s, T, o, To) for s, T in placed.values() for o, To in self.obstacles) or any(
                hit(*placed[a], *placed[b]) for a, b in self.pairs
            )
        return out


def judge(robot, real: RealGeometry | None, q: np.ndarray, targets: np.ndarray) -> dict[str, float]:
    """Fractions over the batch: within 1e-5 m / 1e-4 rad, within 5 mm / 0.05 rad, within the limits, and
    in collision (real meshes); success = on target, within limits and collision-free."""
    T = np.asarray(dk.fk(robot, jnp.asarray(q, jnp.float64), EE))
    pos = np.linalg.norm(T[:, :3, 3] - targets[:, :3, 3], axis=-1)
    cos = (np.einsum("nij,nij->n", T[:, :3, :3], targets[:, :3, :3]) - 1) / 2
    rot = np.arccos(np.clip(cos, -1, 1))
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    limits = np.all((q >= lo - 1e-6) & (q <= hi + 1e-6), axis=-1)
    hits = real.colliding(q) if real is not None else np.full(len(q), np.nan)
    tight, loose = (pos <= 1e-5) & (rot <= 1e-4), (pos <= 5e-3) & (rot <= 0.05)
    ok = limits if real is None else ~hits.astype(bool) & limits
    return {
        "tight": float(np.mean(tight & ok)),
        "loose": float(np.mean(loose & ok)),
        "in collision": float(np.mean(hits)),
        "limits": float(np.mean(limits)),
    }


def targets_of(robot, geom, world64, n: int, rng) -> np.ndarray:
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    out = []
    while sum(len(x) for x in out) < n:
        q = rng.uniform(lo, hi, (4 * n + 64, robot.dof))
        clear = np.asarray(C.clearance(robot, geom, jnp.asarray(q), world64))
        out.append(q[clear >= 0.03])
    q = np.concatenate(out)[:n]
    return np.asarray(dk.fk(robot, jnp.asarray(q), EE))


def baxter(n: int) -> None:
    """Baxter's two grippers (self-collision only, SRDF pairs), float32: ``avoid`` against no avoid, the real
    geometry (coal) judging self-collision; targets from configurations whose shapes clear each other by 3 cm."""
    root = os.path.join(example_robot_data(), "baxter_description")
    urdf, srdf = os.path.join(root, "urdf", "baxter.urdf"), os.path.join(root, "srdf", "baxter_manipulation.srdf")
    robot = dk.load_robot(urdf)
    geom = C.load(urdf, robot, srdf=srdf)
    real = RealGeometry(urdf, robot, geom, None)
    hands = ["left_gripper", "right_gripper"]
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    q = rng.uniform(lo, hi, (8 * n, robot.dof))
    q = q[np.asarray(C.self_distances(robot, geom, jnp.asarray(q))).min(axis=-1) >= 0.03][:n]
    T = np.asarray(dk.fk(robot, jnp.asarray(q), hands))
    targets = {h: jnp.asarray(T[:, k], jnp.float32) for k, h in enumerate(hands)}
    avoid = dk.ik.Avoid(geom, None, margin=MARGIN)
    print(f"# Baxter: {len(geom.shape_names)} shapes, {len(geom.pairs)} self pairs; {n} two-hand targets")
    print("| solver | first call (s) | warm (s) | success 1e-5 m/1e-4 rad | self-collision (real geometry) |")
    print("| --- | --- | --- | --- | --- |")
    for name, kw in (("diffkin avoid (self)", dict(avoid=avoid)), ("diffkin (no avoid)", {})):
        fn = solver_jit(lambda t, kw=kw: dk.ik.solve(robot, t, **kw))
        start = time.perf_counter()
        res = jax.block_until_ready(fn(targets))
        first = time.perf_counter() - start
        warm = median_seconds(fn, targets, repeats=3, warmup=0, min_time=0.0)
        qs = np.asarray(res.q, np.float64)
        reached = np.asarray(dk.fk(robot, jnp.asarray(qs), hands))
        pos = np.linalg.norm(reached[..., :3, 3] - T[..., :3, 3], axis=-1).max(axis=-1)
        hits = real.colliding(qs)
        ok = (pos <= 1e-5) & ~hits & np.asarray(res.success)
        print(f"| {name} | {first:.1f} | {warm:.3g} | {ok.mean():.1%} | {hits.mean():.1%} |", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="batches 1 and 100 only")
    parser.add_argument("--no-pyroki", action="store_true", help="skip PyRoki even if installed")
    parser.add_argument("--no-coal", action="store_true", help="no check on the real meshes (coal)")
    parser.add_argument("--batches", type=int, nargs="+", help="batch sizes (default 1 100 1000; --quick: 1 100)")
    parser.add_argument("--baxter", type=int, metavar="N", help="Baxter's two hands with self-collision instead")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)  # float64 for judging; the solvers run in float32
    if args.baxter:
        baxter(args.baxter)
        return 0
    robot, urdf, srdf = panda()
    geom = C.load(urdf, robot, srdf=srdf)
    s = scene()
    world64, world32 = world_of(s, jnp.float64), world_of(s, jnp.float32)
    real = None if args.no_coal else RealGeometry(urdf, robot, geom, s)
    avoid = dk.ik.Avoid(geom, world32, margin=MARGIN)
    pyroki = None
    if not args.no_pyroki:
        try:
            import _pyroki_peer

            pyroki = _pyroki_peer.panda_robot(urdf, srdf)
        except ImportError as err:
            print(f"# PyRoki not installed ({err}): its rows are left out")
    solvers = {
        "diffkin avoid": solver_jit(lambda T: dk.ik.solve(robot, {EE: T}, avoid=avoid).q),
        "diffkin (no avoid)": solver_jit(lambda T: dk.ik.solve(robot, {EE: T}).q),
    }
    print(f"# Panda ({len(geom.shape_names)} shapes, {len(geom.pairs)} self pairs), {world32.size} obstacles;")
    print(f"# jax {jax.__version__}, {jax.devices()[0].device_kind}, {os.cpu_count()} CPUs; float32 solvers")
    print("| batch | solver | first call (s) | warm (s) | success 1e-5 m/1e-4 rad | success 5 mm/0.05 rad "
          "| in collision (real meshes) | within limits |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    rng = np.random.default_rng(0)
    ratios = []
    for batch in args.batches or ((1, 100) if args.quick else (1, 100, 1000)):
        T64 = targets_of(robot, geom, world64, batch, rng)
        T32 = jnp.asarray(T64, jnp.float32)
        runs = dict(solvers)
        if pyroki is not None:
            sph = s["spheres"]

            def peer(T, sph=sph):
                q, names = _pyroki_peer.solve_batch(*pyroki, EE, np.asarray(T), sph, s["boxes"], s["plane"])
                return q[:, [names.index(n) for n in robot.joint_names]]

            runs["PyRoki (collision example)"] = peer
        first, judged = {}, {}
        for name, fn in runs.items():
            t = time.perf_counter()
            q = np.asarray(jax.block_until_ready(fn(T32)), np.float64)
            first[name] = time.perf_counter() - t
            judged[name] = judge(robot, real, q, T64)
        # diffkin's two solvers in turns (their ratio is the target); PyRoki's slow calls on their own
        warm = dict(
            zip(solvers, median_seconds_interleaved([(fn, (T32,)) for fn in solvers.values()], 5, 2.0), strict=True)
        )
        for name in runs.keys() - solvers.keys():
            warm[name] = median_seconds(runs[name], T32, repeats=3, warmup=0, min_time=0.0)
        for name in runs:
            j = judged[name]
            print(
                f"| {batch:,} | {name} | {first[name]:.1f} | {warm[name]:.3g} | {j['tight']:.1%} | {j['loose']:.1%} "
                f"| {j['in collision']:.1%} | {j['limits']:.1%} |",
                flush=True,
            )
        avoid_s = warm["diffkin avoid"]
        peer_s = warm.get("PyRoki (collision example)")
        ratios.append((batch, avoid_s / warm["diffkin (no avoid)"], None if peer_s is None else peer_s / avoid_s))
    print("\n| batch | avoid / no avoid | PyRoki / avoid |\n| --- | --- | --- |")
    for batch, own, peer_ratio in ratios:
        print(f"| {batch:,} | {own:.2f}x | {'-' if peer_ratio is None else f'{peer_ratio:.0f}x'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
