"""Robots with long serial paths: the unrolled forward pass against the scanned one, compile and run.

    python experiments/bench_long_chains.py [--joints 8 16 32 64 128 1000 4000] [--batch 100]
        [--dtype float32] [--unrolled-up-to 128]

A URDF snake of ``n`` joints (``tests/_models.py::snake_robot``: revolute about z and y in turn,
every seventh prismatic), loaded as a whole robot. For each length, FK of the last frame, the poses
of every frame (``link_poses``) and the world Jacobian of the last frame (analytic), each jitted:
the first call's trace + compile time (``.lower().compile()``), then the median of 7 warm runs at
``--batch`` configurations. Both passes are forced (``diffkin.models._scanned.LONG`` set below or
above the length); the library picks the scanned one above ``LONG`` (32) joints on a path. The
unrolled pass is skipped beyond ``--unrolled-up-to`` joints (its compile time grows much faster than
the length: minutes at 200 joints).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
os.environ.setdefault("DIFFKIN_CACHE_DIR", "off")  # compiles timed cold: JAX's persistent cache off


def _case(robot, n: int, what: str, q) -> tuple[float, float]:
    import diffkin as dk

    end = f"l{n}"
    fn = {
        "fk": lambda q: dk.fk(robot, q, end),
        "link_poses": lambda q: dk.link_poses(robot, q),
        "jacobian": lambda q: dk.jacobian(robot, q, end),
    }[what]
    start = time.perf_counter()
    compiled = jax.jit(fn).lower(q).compile()
    first = time.perf_counter() - start
    jax.block_until_ready(compiled(q))
    runs = []
    for _ in range(7):
        start = time.perf_counter()
        jax.block_until_ready(compiled(q))
        runs.append(time.perf_counter() - start)
    return first, statistics.median(runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--joints", type=int, nargs="+", default=[8, 16, 32, 64, 128, 1000, 4000])
    parser.add_argument("--batch", type=int, default=100)
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    parser.add_argument("--unrolled-up-to", type=int, default=128)
    args = parser.parse_args()
    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    from _models import snake_robot

    from diffkin.models import _scanned

    print(f"# Long serial paths: {jax.devices()[0].device_kind}, batch {args.batch}, {args.dtype}")
    print("compile = trace + lower + compile of the first call (s); run = median of 7 warm calls (ms)\n")
    columns = ("FK compile", "FK run", "link poses compile", "link poses run", "Jacobian compile", "Jacobian run")
    print("| joints | pass | " + " | ".join(columns) + " |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|")
    for n in args.joints:
        robot = snake_robot(n)
        q = np.random.default_rng(0).uniform(-1, 1, (args.batch, n)).astype(args.dtype)
        for name, long in (("unrolled", 10**9), ("scanned", 0)):
            if name == "unrolled" and n > args.unrolled_up_to:
                continue
            _scanned.LONG = long
            cells = []
            for what in ("fk", "link_poses", "jacobian"):
                first, run = _case(robot, n, what, q)
                cells += [f"{first:.2f}", f"{run * 1e3:.2f}"]
            print(f"| {n} | {name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
