"""Benchmark (issue 29): the centre of mass of Talos, and Panda paths.

1. ``dk.com`` + ``dk.com_jacobian`` of Talos (``talos_full_v2.urdf``, floating base, base columns
   included), float64, one jitted call over a batch, against a Python loop of Pinocchio's
   ``centerOfMass`` + ``jacobianCenterOfMass`` (timed on 2,000 configurations, per configuration
   times the batch).
2. Panda paths (``dk.robots.panda()``, float32): 1,000 paths of 100 waypoints (lines and circles of
   5-10 cm from random in-limit configurations, the orientation held), ``dk.ik.solve_path`` with
   ``max_step=0.1`` rad, against solving the 100,000 waypoints independently with ``dk.ik.solve``:
   time (median of warm calls, compile separately), waypoint success, paths without a failed
   waypoint, and jumps (consecutive waypoints whose solutions differ by more than ``max_step``
   in some joint). With PyRoki installed (experiments/README.md), its trajectory optimisation's
   costs along the first 100 of the same paths (``_pyroki_peer.solve_paths``): one least-squares
   problem per path, every waypoint a pose target, consecutive configurations kept close.

    python experiments/bench_com_path.py [--quick]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from _bench import busy_note, example_robot_data, machine_line, median_seconds, random_configs  # noqa: E402

import diffkin as dk  # noqa: E402
from diffkin import se3  # noqa: E402

MAX_STEP = 0.1


def talos():
    import pinocchio as pin

    path = os.path.join(example_robot_data(), "talos_data/robots/talos_full_v2.urdf")
    return dk.load_robot(path, floating=True), pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())


def bench_com(batch: int) -> list[str]:
    import pinocchio as pin

    robot, model = talos()
    data = model.createData()
    rng = np.random.default_rng(0)
    q = random_configs(robot, batch, np.float64)
    base = np.tile(np.eye(4), (batch, 1, 1))
    base[:, :3, 3] = rng.normal(size=(batch, 3))

    @jax.jit
    def both(q, base):
        return dk.com(robot, q, base=base), dk.com_jacobian(robot, q, base=base, include_base=True)

    start = time.perf_counter()
    jax.block_until_ready(both(q, base))
    compile_s = time.perf_counter() - start
    ours = median_seconds(both, q, base, repeats=3, warmup=1)
    sample = min(batch, 2000)
    qp = [pin.neutral(model) for _ in range(sample)]
    for k in range(sample):  # joints in Pinocchio's order (no mimic joints in Talos); revolute only
        for i, name in enumerate(robot.joint_names):
            joint = model.joints[model.getJointId(name)]
            qp[k][joint.idx_q] = q[k, i]
        qp[k][:3] = base[k, :3, 3]
    start = time.perf_counter()
    for k in range(sample):
        pin.centerOfMass(model, data, qp[k])
        pin.jacobianCenterOfMass(model, data, qp[k])
    loop = (time.perf_counter() - start) / sample * batch
    return [
        "| Talos (" + f"{robot.dof} + 6 dof) | {batch:,} | {ours * 1e3:.1f} | {loop * 1e3:.1f} | "
        f"{loop / ours:.1f}x | {compile_s:.1f} |"
    ]


def panda_paths(n: int, T: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """``(n, T, 4, 4)`` waypoints and the ``(n, 7)`` start configurations (lines and circles)."""
    chain = dk.robots.panda()
    lo, hi = np.asarray(chain.lower), np.asarray(chain.upper)
    q_start = rng.uniform(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo), (n, 7))
    T0 = np.asarray(dk.fk(chain, q_start))
    s = np.linspace(0.0, 1.0, T)
    radius = rng.uniform(0.05, 0.10, n)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(u, rng.normal(size=(n, 3)))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    line = radius[:, None, None] * s[None, :, None] * u[:, None]
    angle = 2 * np.pi * s[None, :, None]
    circle = radius[:, None, None] * ((np.cos(angle) - 1.0) * u[:, None] + np.sin(angle) * v[:, None])
    offsets = np.where((np.arange(n) % 2 == 0)[:, None, None], line, circle)
    paths = np.repeat(T0[:, None], T, axis=1)
    paths[..., :3, 3] += offsets
    return paths, q_start


def jumps(q: np.ndarray) -> int:
    """Consecutive waypoints whose solutions differ by more than ``MAX_STEP`` in some joint (beyond float32
    rounding)."""
    return int(np.count_nonzero(np.abs(np.diff(q, axis=-2)).max(axis=-1) > MAX_STEP + 1e-6))


def bench_paths(n: int, T: int) -> list[str]:
    chain = dk.robots.panda()
    paths, q_start = panda_paths(n, T, np.random.default_rng(1))
    targets = jnp.asarray(paths, jnp.float32)
    q0 = jnp.asarray(q_start, jnp.float32)
    follow = jax.jit(lambda t, q: dk.ik.solve_path(chain, t, q0=q, max_step=MAX_STEP))
    start = time.perf_counter()
    res = jax.block_until_ready(follow(targets, q0))
    compile_path = time.perf_counter() - start
    path_s = median_seconds(follow, targets, q0, repeats=3, warmup=0)
    flat = targets.reshape(n * T, 4, 4)
    warm = jnp.repeat(q0, T, axis=0)
    each = jax.jit(lambda t, q: dk.ik.solve(chain, t, q0=q))
    start = time.perf_counter()
    ind = jax.block_until_ready(each(flat, warm))
    compile_each = time.perf_counter() - start
    each_s = median_seconds(each, flat, warm, repeats=3, warmup=0)
    q_ind = np.asarray(ind.q).reshape(n, T, 7)
    ok_ind = np.asarray(ind.success).reshape(n, T)
    return [
        f"| `solve_path` (max_step {MAX_STEP}) | {n:,} x {T} | {path_s:.3f} | {compile_path:.1f} | "
        f"{100 * float(np.mean(res.success)):.2f} % | {100 * float(np.mean(res.path_ok)):.1f} % | "
        f"{jumps(np.asarray(res.q))} | {float(jnp.max(res.max_step)):.3f} |",
        f"| `solve` per waypoint (q0 = the path's start) | {n * T:,} | {each_s:.3f} | {compile_each:.1f} | "
        f"{100 * float(np.mean(ok_ind)):.2f} % | {100 * float(np.mean(np.all(ok_ind, axis=1))):.1f} % | "
        f"{jumps(q_ind)} | {float(np.abs(np.diff(q_ind, axis=1)).max()):.3f} |",
    ]


#: Paths PyRoki solves (the first of the benchmark's): about 0.3 s a path on 2 CPU cores.
PYROKI_PATHS = 100


def waypoint_errors(q: np.ndarray, paths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and rotation (rad) errors ``(P, T)`` of the Panda's flange at ``q`` against ``paths`` (float64
    FK, the angle by ``se3.rotation_angle``, accurate near 0 where ``arccos`` of the trace is not)."""
    with jax.enable_x64(True):
        T = np.asarray(dk.fk(dk.robots.panda(), jnp.asarray(q, jnp.float64)))
        rot = np.asarray(se3.rotation_angle(np.swapaxes(T[..., :3, :3], -1, -2) @ paths[..., :3, :3]))
    return np.linalg.norm(T[..., :3, 3] - paths[..., :3, 3], axis=-1), rot


def bench_paths_pyroki(n: int, T: int) -> list[str]:
    """PyRoki's trajectory optimisation along the first ``PYROKI_PATHS`` of the same paths (``_pyroki_peer``),
    or no row without PyRoki. Its flange (``panda_link8`` of example-robot-data's URDF) is diffkin's
    Panda's end effector to 1e-15; the finger joint starts at 0.02 m."""
    from _pyroki_peer import _example_robot_data_panda, panda_robot, solve_paths  # PyRoki imported inside

    try:
        robot, _ = panda_robot(_example_robot_data_panda()[0])
    except ImportError:  # PyRoki (or yourdfpy) not installed
        return []
    chain = dk.robots.panda()
    paths, q_start = panda_paths(n, T, np.random.default_rng(1))
    k = min(PYROKI_PATHS, n)
    paths, q0 = paths[:k], np.concatenate([q_start[:k], np.full((k, 1), 0.02)], axis=1)
    start = time.perf_counter()
    q = solve_paths(robot, "panda_link8", paths, q0)
    compile_s = time.perf_counter() - start
    warm = median_seconds(lambda: solve_paths(robot, "panda_link8", paths, q0), repeats=1, warmup=0, min_time=0.0)
    q = q[..., : chain.dof]
    pos, rot = waypoint_errors(q, paths)
    lo, hi = np.asarray(chain.lower), np.asarray(chain.upper)
    within = np.all((q >= lo) & (q <= hi), axis=-1)
    ok = (pos <= 1e-5) & (rot <= 1e-4) & within
    near = (pos <= 5e-3) & (rot <= 0.05) & within
    return [
        f"| PyRoki trajectory optimisation (5 mm / 0.05 rad: {100 * float(near.mean()):.2f} %) | {k:,} x {T} | "
        f"{warm:.3f} | {compile_s:.1f} | {100 * float(ok.mean()):.2f} % | {100 * float(ok.all(axis=1).mean()):.1f} % | "
        f"{jumps(q)} | {float(np.abs(np.diff(q, axis=1)).max()):.3f} |"
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small batches (a smoke run)")
    parser.add_argument("--only", choices=("com", "paths"), help="one of the two tables")
    parser.add_argument("--com-batches", type=int, nargs="+", help="the centre of mass's batches (1,000 and 100,000)")
    args = parser.parse_args()
    batch, (n, T) = (1_000, (50, 20)) if args.quick else (100_000, (1_000, 100))
    print(machine_line())
    print(busy_note())
    print(f"jax {jax.__version__}, {' '.join(sys.argv)}\n")
    if args.only != "paths":
        print("| robot | batch | diffkin com + com_jacobian (ms) | Pinocchio loop (ms) | speed-up | compile (s) |")
        print("| --- | --- | --- | --- | --- | --- |")
        for b in args.com_batches or sorted({1_000, batch}):
            for row in bench_com(b):
                print(row, flush=True)
        print()
    if args.only == "com":
        return
    print(
        "| Panda paths, float32 | waypoints | warm (s) | compile (s) | waypoint success | paths all solved | "
        "jumps | largest step (rad) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    jax.config.update("jax_enable_x64", False)  # float32 throughout, as a float32 user runs it (PyRoki's jaxls too)
    for row in bench_paths(n, T) + bench_paths_pyroki(n, T):
        print(row, flush=True)


if __name__ == "__main__":
    main()
