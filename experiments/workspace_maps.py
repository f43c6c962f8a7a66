"""Reachability, manipulability and dexterity maps of the KUKA iiwa14 and the Franka Panda.

Writes, for each robot, slices through the base (``y = 0`` and ``z`` at the shoulder height) of
the sample count, the best manipulability and the dexterity (orientation bins reached) as PNGs,
saves each map as ``.npz``, and prints the throughput (samples/s of forward kinematics,
manipulability, orientation binning and voxel reduction).

    python experiments/workspace_maps.py --n 20000000 --voxel 0.02 --out experiments/out
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python experiments/workspace_maps.py   # both CPU cores
"""

from __future__ import annotations

import argparse
import os
import time

import jax

import diffkin as dk
from diffkin import workspace as ws


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20_000_000, help="samples per robot")
    parser.add_argument("--voxel", type=float, default=0.02, help="voxel edge, metres")
    parser.add_argument("--chunk", type=int, default=1 << 16, help="samples per device per step")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "out"))
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    devices = jax.devices()
    for name, shoulder in (("iiwa14", 0.36), ("panda", 0.333)):
        chain = getattr(dk.robots, name)()
        run = lambda n, chain=chain: ws.reachability(  # noqa: E731
            chain, n, key=jax.random.key(args.seed), voxel_size=args.voxel, chunk=args.chunk, dtype="float32"
        )
        run(args.chunk * len(devices))  # compile outside the timing
        start = time.perf_counter()
        m = run(args.n)
        seconds = time.perf_counter() - start
        print(
            f"{name}: {args.n / seconds / 1e6:.2f} M samples/s (n={args.n}, chunk={args.chunk}, float32, "
            f"{len(devices)} {devices[0].platform} device(s), grid {m.counts.shape}, voxel {args.voxel} m, "
            f"{m.orientation_bins} orientation bins, {seconds:.1f} s)"
        )
        m.save(os.path.join(args.out, f"workspace_{name}.npz"))
        for quantity in ("count", "manipulability", "dexterity"):
            for axis, value in (("y", 0.0), ("z", shoulder)):
                ws.plot_slice(
                    m,
                    axis=axis,
                    value=value,
                    quantity=quantity,
                    path=os.path.join(args.out, f"workspace_{name}_{quantity}_{axis}.png"),
                )
    print(f"maps and PNGs in {args.out}")


if __name__ == "__main__":
    main()
