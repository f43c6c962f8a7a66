"""Benchmark: a Panda's fitted collision capsules, its self pairs and 16 obstacles (issue 27).

diffkin's ``self_distances`` + ``world_distances`` (one jitted function, forward kinematics
included) against a Python loop of coal's ``distance`` on the same primitives (the shapes placed
by diffkin's poses beforehand: coal's time is the distances alone), and against PyRoki's
``compute_self_collision_distance`` + ``compute_world_collision_distance`` on its own geometry (one
capsule per link fitted to the meshes, the SRDF's pairs ignored as diffkin's: ``_pyroki_peer.py``;
PyRoki has no box, so each box is its six face half-spaces, as the IK benchmark does: the same
number of obstacles to check, a cheaper kind). Batch 1, 1,000 and 100,000, float32 and float64; the
coal loop is timed on 200 configurations and reported per configuration times the batch. Medians
of 5 warm calls (batches 1 and 1,000: as many as fill 1 s, diffkin's and PyRoki's calls in turns,
ten rounds, so that both meet the same spells of a shared machine); PyRoki's compile apart (first call).
``--compile``: instead, the seconds to trace, lower and compile (at batch 1,000) the value of
``self_distances`` + ``world_distances`` and the gradient of their sum with respect to ``q`` (what
IK and the tests differentiate).

    python experiments/bench_collision.py [--quick] [--compile] [--dtype float32|float64|both]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from _bench import example_robot_data, median_seconds, median_seconds_interleaved  # noqa: E402

import diffkin as dk  # noqa: E402


def panda():
    """The Panda of example-robot-data (:func:`_bench.example_robot_data`): its robot, URDF and SRDF paths."""
    root = os.path.join(example_robot_data(), "panda_description")
    urdf, srdf = os.path.join(root, "urdf", "panda.urdf"), os.path.join(root, "srdf", "panda.srdf")
    robot = dk.load_robot(urdf)
    return robot, urdf, srdf


def obstacles(rng):
    C = dk.collision
    spheres = C.Sphere(rng.uniform([-0.8, -0.8, 0], [0.8, 0.8, 1.2], (8, 3)), rng.uniform(0.03, 0.1, 8))
    T = np.tile(np.eye(4), (7, 1, 1))
    T[:, :3, 3] = rng.uniform([-0.8, -0.8, 0], [0.8, 0.8, 1.2], (7, 3))
    boxes = C.Box(T, rng.uniform(0.03, 0.15, (7, 3)))
    floor = C.Plane(np.array([0.0, 0, 1]), -0.01)
    return C.World(spheres, boxes, floor)


def coal_per_config(robot, geom, world, q):
    """Seconds per configuration of a Python loop of coal.distance over the self and world pairs."""
    import coal

    s, c, b = dk.collision._geometry.placed(robot, geom, q)  # noqa: SLF001  (host arrays, placed once)
    caps = [(np.asarray(c.a[k]), np.asarray(c.b[k]), np.asarray(c.radius)) for k in range(len(q))]
    boxes = [(np.asarray(b.pose[k]), np.asarray(b.half_extents)) for k in range(len(q))]

    def capsule(a, bb, r):
        L = float(np.linalg.norm(bb - a))
        z = (bb - a) / L
        x = np.cross([1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0], z)
        x /= np.linalg.norm(x)
        return coal.Capsule(float(r), L), coal.Transform3s(np.column_stack([x, np.cross(z, x), z]), 0.5 * (a + bb))

    obstacles_ = [
        (coal.Sphere(float(r)), coal.Transform3s(np.eye(3), p))
        for p, r in zip(np.asarray(world.spheres.center), np.asarray(world.spheres.radius), strict=True)
    ]
    obstacles_ += [
        (coal.Box(*(2 * h)), coal.Transform3s(T[:3, :3], T[:3, 3]))
        for T, h in zip(np.asarray(world.boxes.pose), np.asarray(world.boxes.half_extents), strict=True)
    ]
    obstacles_ += [
        (coal.Halfspace(n, float(o)), coal.Transform3s())
        for n, o in zip(np.asarray(world.planes.normal), np.asarray(world.planes.offset), strict=True)
    ]
    ns, nc, _ = geom.counts
    request = coal.DistanceRequest()
    start = time.perf_counter()
    for k in range(len(q)):
        shapes = [capsule(caps[k][0][i], caps[k][1][i], caps[k][2][i]) for i in range(nc)]
        shapes += [
            (coal.Box(*(2 * boxes[k][1][i])), coal.Transform3s(boxes[k][0][i][:3, :3], boxes[k][0][i][:3, 3]))
            for i in range(len(boxes[k][1]))
        ]
        for i, j in geom.pairs:
            coal.distance(*shapes[i - ns], *shapes[j - ns], request, coal.DistanceResult())
        for g, T in shapes:
            for o, To in obstacles_:
                coal.distance(g, T, o, To, request, coal.DistanceResult())
    return (time.perf_counter() - start) / len(q)


def distances(robot, geom, world, dtype):
    """``q -> (self_distances, world_distances)`` with every model number cast to ``dtype``."""
    r, g, w = (jax.tree.map(lambda x: x.astype(dtype), m) for m in (robot, geom, world))
    return lambda q: (dk.collision.self_distances(r, g, q), dk.collision.world_distances(r, g, q, w))


def pyroki_distances(urdf: str, srdf: str, world):
    """``q -> (self, world)`` distances of PyRoki's Panda (jitted), or ``None`` without PyRoki."""
    try:
        import jax.numpy as jnp
        from _pyroki_peer import _box_halfspaces, panda_robot
        from pyroki.collision import HalfSpace, Sphere
    except ImportError:
        return None
    robot, coll = panda_robot(urdf, srdf)
    spheres = Sphere.from_center_and_radius(jnp.asarray(world.spheres.center), jnp.asarray(world.spheres.radius))
    boxes = list(zip(np.asarray(world.boxes.pose), np.asarray(world.boxes.half_extents), strict=True))
    points, normals = _box_halfspaces(boxes)
    n, o = np.asarray(world.planes.normal), np.asarray(world.planes.offset)
    faces = HalfSpace.from_point_and_normal(
        jnp.asarray(np.concatenate([points.reshape(-1, 3), n * o[:, None]])),
        jnp.asarray(np.concatenate([normals.reshape(-1, 3), n])),
    )

    def one(q):  # one configuration: PyRoki's batched calls fail on a batch of configurations (jax_dataclasses)
        return (
            coll.compute_self_collision_distance(robot, q),
            coll.compute_world_collision_distance(robot, q, spheres),
            coll.compute_world_collision_distance(robot, q, faces),
        )

    return jax.jit(jax.vmap(one))


def compile_times(robot, geom, world, q, dtypes) -> int:
    """Print the seconds to trace, lower and compile the value and the gradient (of the sum of every distance)."""
    print("| dtype | what | compile (s) |")
    print("| --- | --- | --- |")
    for dtype in dtypes:
        f = distances(robot, geom, world, dtype)
        total = lambda q, f=f: sum(jax.numpy.sum(d) for d in f(q))  # noqa: E731
        for what, fn in (("value", f), ("gradient", jax.grad(total))):
            start = time.perf_counter()
            jax.jit(fn).lower(q.astype(dtype)).compile()
            print(f"| {np.dtype(dtype).name} | {what} | {time.perf_counter() - start:.1f} |", flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="batches 1 and 1,000 only")
    parser.add_argument("--dtype", choices=("float32", "float64", "both"), default="both")
    parser.add_argument("--compile", action="store_true", help="compile times of the value and the gradient only")
    parser.add_argument("--no-coal", action="store_true", help="diffkin only (no coal loop: a GPU machine)")
    parser.add_argument("--no-pyroki", action="store_true", help="without PyRoki (not on PyPI: experiments/README.md)")
    args = parser.parse_args(argv)
    robot, urdf, srdf = panda()
    t = time.perf_counter()
    geom = dk.collision.load(urdf, robot, srdf=srdf)
    load_s = time.perf_counter() - t
    world = obstacles(np.random.default_rng(0))
    ns, nc, nb = geom.counts
    print(f"# Panda: {ns} spheres, {nc} capsules, {nb} boxes; {len(geom.pairs)} self pairs; {world.size} obstacles")
    cpu = platform.processor() or platform.machine()
    print(f"# load (mesh fits) {load_s:.1f} s; jax {jax.__version__}, {cpu}, {os.cpu_count()} CPUs")
    rng = np.random.default_rng(1)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    dtypes = {"float32": (np.float32,), "float64": (np.float64,), "both": (np.float32, np.float64)}[args.dtype]
    if args.compile:
        return compile_times(robot, geom, world, rng.uniform(lo, hi, (1000, robot.dof)), dtypes)
    coal_s = np.nan if args.no_coal else coal_per_config(robot, geom, world, rng.uniform(lo, hi, (200, robot.dof)))
    peer = None if args.no_pyroki else pyroki_distances(urdf, srdf, world)
    columns = "diffkin (s) | coal loop (s, per config x batch) | speed-up | PyRoki (s) | PyRoki / diffkin"
    print(f"| dtype | batch | {columns} |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for dtype in dtypes:
        f = jax.jit(distances(robot, geom, world, dtype))
        for batch in (1, 1000) if args.quick else (1, 1000, 100_000):
            q = jax.numpy.asarray(rng.uniform(lo, hi, (batch, robot.dof)).astype(dtype))  # on the device, as PyRoki's
            peer_cells = "n/a | n/a"
            if batch == 100_000:  # seconds a call: five each
                s = median_seconds(f, q, repeats=5, warmup=1, min_time=0.0)
            if peer is not None:
                qp = jax.numpy.asarray(q)  # the same joints in the same order (its mimic finger follows, as ours)
                start = time.perf_counter()
                jax.block_until_ready(peer(qp))
                first = time.perf_counter() - start
                if batch == 100_000:
                    p = median_seconds(peer, qp, repeats=5, warmup=0, min_time=0.0)
                else:  # thousands of samples of a fast call, the two in turns: stable medians, the same spells
                    s, p = median_seconds_interleaved([(f, (q,)), (peer, (qp,))], min_time=1.0)
                peer_cells = f"{p:.3g} (compile {first:.1f}) | {p / s:.1f}x"
            elif batch < 100_000:
                s = median_seconds(f, q, repeats=5, warmup=1, min_time=1.0)
            coal_cells = f"{coal_s * batch:.3g} | {coal_s * batch / s:.0f}x"
            print(f"| {np.dtype(dtype).name} | {batch:,} | {s:.3g} | {coal_cells} | {peer_cells} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
