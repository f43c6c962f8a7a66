"""Batched IK speed and success: diffkin (LM, optax) vs pytorch-kinematics PseudoInverseIK.

Same 1,000 iiwa14 targets (poses of uniform in-limit configurations, shipped URDF), float32, CPU.
pytorch-kinematics: 30 iterations x 10 retries, its default 1 mm / 0.01 rad, one timed run after a
warm-up. diffkin: jitted, warmed up, median of 5 runs. Success is re-checked with float64 FK.

Run: ``.venv/bin/python experiments/bench_ik.py``
"""

import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytorch_kinematics as pk
import torch
from _bench import median_seconds

import diffkin as dk
import diffkin.ik as ik

N = 1000
PK_TOL = (1e-3, 1e-2)
TIGHT_TOL = (1e-5, 1e-4)


def median_time(fn, *args, repeats=5):
    """Median warm time of ``fn(*args)`` and its result."""
    return median_seconds(fn, *args, repeats=repeats, warmup=1), fn(*args)


def main():
    path = dk.robots.urdf_path("iiwa14")
    chain = dk.load_urdf(path, "iiwa14_link_ee")
    with open(path, "rb") as f:
        xml = f.read()
    pk_chain = pk.build_serial_chain_from_urdf(xml, "iiwa14_link_ee")  # float32
    pk64 = pk.build_serial_chain_from_urdf(xml, "iiwa14_link_ee").to(dtype=torch.float64)  # .to() mutates
    q_true = np.random.default_rng(0).uniform(chain.lower, chain.upper, (N, 7))
    target64 = pk64.forward_kinematics(torch.as_tensor(q_true)).get_matrix().numpy()
    target = target64.astype(np.float32)

    def verified(q, tol):
        T = pk64.forward_kinematics(torch.as_tensor(np.asarray(q, np.float64))).get_matrix().numpy()
        pos = np.linalg.norm(T[:, :3, 3] - target64[:, :3, 3], axis=-1)
        M = target64[:, :3, :3] @ np.swapaxes(T[:, :3, :3], -1, -2)
        rot = np.arccos(np.clip((np.trace(M, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
        return (pos <= tol[0]) & (rot <= tol[1])

    print(f"# IK benchmark: iiwa14, {N} targets, float32, CPU ({platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores), jax {jax.__version__}, torch {torch.__version__}\n")

    torch.manual_seed(0)  # pk draws its retries from torch's RNG: make its run reproducible
    limits = torch.tensor(np.stack([chain.lower, chain.upper], -1), dtype=torch.float32)
    solver = pk.PseudoInverseIK(pk_chain, max_iterations=30, num_retries=10, joint_limits=limits,
                                early_stopping_any_converged=True, pos_tolerance=PK_TOL[0], rot_tolerance=PK_TOL[1])
    goal = pk.Transform3d(matrix=torch.as_tensor(target))
    solver.solve(goal)  # warm-up
    t = time.perf_counter()
    sol = solver.solve(goal)
    pk_time = time.perf_counter() - t
    pk_success = float(sol.converged_any.float().mean())

    rows = []
    key = jax.random.key(1)
    T32 = jnp.asarray(target)
    for label, kw in [("diffkin LM, defaults (32 seeds, 60 iters), 1e-5 m / 1e-4 rad", {}),
                      ("diffkin LM, defaults, pk's 1 mm / 0.01 rad", dict(pos_tol=PK_TOL[0], rot_tol=PK_TOL[1]))]:
        fn = jax.jit(lambda T, k, kw=kw: ik.solve(chain, T, key=k, **kw))
        dt, res = median_time(fn, T32, key)
        tol = (kw.get("pos_tol", TIGHT_TOL[0]), kw.get("rot_tol", TIGHT_TOL[1]))
        ok = np.asarray(res.success)
        assert np.all(verified(res.q, (tol[0] + 1e-6, tol[1] + 1e-5))[ok]), "a reported success fails float64 FK"
        rows.append((label, ok.mean(), dt))
    print("| solver | success | time (s) | solves/s | vs pk |\n| --- | --- | --- | --- | --- |")
    print(f"| pytorch-kinematics PseudoInverseIK 30 x 10, 1 mm / 0.01 rad | {pk_success:.1%} | {pk_time:.3f} | "
          f"{N / pk_time:.0f} | 1.0x |")
    for label, rate, dt in rows:
        print(f"| {label} | {rate:.1%} | {dt:.3f} | {N / dt:.0f} | {pk_time / dt:.2f}x |")

    print("\n## diffkin LM vs num_seeds and max_iters (1e-5 m / 1e-4 rad)\n")
    print("| num_seeds | max_iters | success | time (s) | solves/s |\n| --- | --- | --- | --- | --- |")
    for seeds in (4, 8, 16, 32):
        for iters in (30, 60):
            fn = jax.jit(lambda T, k, s=seeds, i=iters: ik.solve(chain, T, key=k, num_seeds=s, max_iters=i))
            dt, res = median_time(fn, T32, key, repeats=3)
            print(f"| {seeds} | {iters} | {float(res.success.mean()):.1%} | {dt:.3f} | {N / dt:.0f} |")

    print("\n## optax (Adam 1e-2, 4 seeds) vs LM\n")
    print("| method | iters | success 1e-5 m / 1e-4 rad | success 1 mm / 0.01 rad | median pos err (m) | time (s) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for method, iters in (("lm", 60), ("optax", 300), ("optax", 1000)):
        fn = jax.jit(lambda T, k, m=method, i=iters: ik.solve(chain, T, key=k, method=m, num_seeds=4, max_iters=i,
                                                              pos_tol=0.0, rot_tol=0.0))
        dt, res = median_time(fn, T32, key, repeats=1)
        pos, rot = np.asarray(res.pos_err), np.asarray(res.rot_err)
        tight = np.mean((pos <= TIGHT_TOL[0]) & (rot <= TIGHT_TOL[1]))
        loose = np.mean((pos <= PK_TOL[0]) & (rot <= PK_TOL[1]))
        print(f"| {method} | {iters} | {tight:.1%} | {loose:.1%} | {np.median(pos):.2e} | {dt:.3f} |")


if __name__ == "__main__":
    main()
