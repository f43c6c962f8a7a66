"""Speed of the iiwa closed form: solutions per second in a batch, and time to sample one pose's self-motion.

    python experiments/bench_srs.py [--batch 100000] [--samples 2000] [--runs 7]

Everything is jitted and warmed up before timing; each figure is the median of ``--runs`` runs.
Prints a markdown table. float64 is enabled for the float64 row of ``srs.ik``; every other input
is cast to float32.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import diffkin as dk  # noqa: E402
import diffkin.srs as srs  # noqa: E402


def median_seconds(fn, runs: int) -> float:
    jax.block_until_ready(fn())  # compile and warm up
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=100_000)
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()

    arm = srs.iiwa14()
    rng = np.random.default_rng(0)
    q64 = rng.uniform(np.asarray(arm.lower), np.asarray(arm.upper), (args.batch, 7))
    fk = jax.jit(lambda q: dk.fk(arm.chain(), q))
    arm_angle = jax.jit(lambda q: srs.arm_angle(arm, q))
    solve = jax.jit(lambda T, psi, gc: srs.ik(arm, T, psi, gc))
    t_ik = {}
    for dtype in (np.float32, np.float64):
        target, psi, gc = (x.astype(dtype) for x in (fk(q64), *arm_angle(q64)))
        q_back, valid = solve(target, psi, gc)
        assert q_back.dtype == dtype and bool(valid.all()), "round trip left the joint limits"
        t_ik[dtype] = median_seconds(lambda: solve(target, psi, gc), args.runs)  # noqa: B023 (called right here)

    pose = target[0].astype(np.float32)
    key = jax.random.PRNGKey(0)
    draw = jax.jit(lambda T, key: srs.sample_self_motion(arm, T, args.samples, key=key))
    t_sample = median_seconds(lambda: draw(pose, key), args.runs)
    _, ok = draw(pose, key)

    print(f"device: {jax.devices()[0].device_kind}, jax {jax.__version__}, iiwa14, median of {args.runs} runs")
    print()
    print("| work | batch | dtype | time | rate |")
    print("| --- | --- | --- | --- | --- |")
    for dtype, t in t_ik.items():
        print(
            f"| `srs.ik` closed form | {args.batch:,} | {np.dtype(dtype).name} | {t * 1e3:.1f} ms | "
            f"{args.batch / t / 1e6:.2f} M solutions/s |"
        )
    print(
        f"| `srs.sample_self_motion` (8 global configurations) | {args.samples:,} | float32 | "
        f"{t_sample * 1e3:.2f} ms | {int(ok.sum())} valid samples |"
    )


if __name__ == "__main__":
    main()
