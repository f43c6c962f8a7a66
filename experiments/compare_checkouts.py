"""Warm timings and first-call times of two checkouts of diffkin, in alternating fresh processes.

    python experiments/compare_checkouts.py BEFORE_DIR AFTER_DIR [--rounds 3]

Each round runs one subprocess per checkout (``PYTHONPATH`` set to it, so the same environment
imports that checkout's ``diffkin``), before then after, and each subprocess times, on the
iiwa14 in float32: ``dk.ik.solve`` (called as it is, defaults) of 1 and 1,000 reachable pose targets (the
first call, compile included, and the median of 25 warm calls, with the success rate), FK and the
world Jacobian of 100,000 configurations (medians of 25 warm calls). Alternating rounds spread a
drifting machine's speed over both checkouts; compare the rows of one round, and medians over rounds.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


def measure() -> dict:
    """The timings of the ``diffkin`` this process imports (the subprocess side)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import diffkin as dk

    chain = dk.robots.iiwa14()

    def median(f, *args, repeats=25):
        jax.block_until_ready(f(*args))
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            jax.block_until_ready(f(*args))
            times.append(time.perf_counter() - t)
        return float(np.median(times))

    out = {}
    rng = np.random.default_rng(1)
    for n in (1, 1000):
        q = jnp.asarray(rng.uniform(chain.lower, chain.upper, (n, chain.dof)))
        T = jnp.asarray(np.asarray(dk.fk(chain, q)), jnp.float32)
        solve = lambda T, key: dk.ik.solve(chain, T, key=key)  # noqa: E731 (as a script calls it: solve jits itself)
        t = time.perf_counter()
        res = jax.block_until_ready(solve(T, jax.random.key(1)))
        out[f"IK {n} first call s"] = time.perf_counter() - t
        out[f"IK {n} warm ms"] = 1e3 * median(solve, T, jax.random.key(1))
        out[f"IK {n} success"] = float(np.mean(res.success))
    q = jnp.asarray(rng.uniform(chain.lower, chain.upper, (100_000, chain.dof)), jnp.float32)
    out["FK 100,000 ms"] = 1e3 * median(jax.jit(lambda q: dk.fk(chain, q)), q)
    out["Jacobian 100,000 ms"] = 1e3 * median(jax.jit(lambda q: dk.jacobian(chain, q)), q)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", nargs="?", help="checkout directory (holding diffkin/)")
    parser.add_argument("after", nargs="?", help="checkout directory (holding diffkin/)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure()))
        return
    if not args.before or not args.after:
        parser.error("give the BEFORE and AFTER checkout directories")
    rows: dict[str, list[str]] = {}
    for r in range(args.rounds):
        for label, path in (("before", args.before), ("after", args.after)):
            env = dict(os.environ, PYTHONPATH=os.path.abspath(path))
            proc = subprocess.run(
                [sys.executable, os.path.abspath(__file__), "--measure"], env=env, capture_output=True, text=True
            )
            if proc.returncode != 0:
                sys.exit(f"{label} ({path}) failed:\n{proc.stderr[-2000:]}")
            for key, value in json.loads(proc.stdout.splitlines()[-1]).items():
                rows.setdefault(key, []).append(f"{label} {value:.3g}")
            print(f"round {r + 1}: {label} done", file=sys.stderr, flush=True)
    print("| measure | " + " | ".join(f"round {r + 1} before / after" for r in range(args.rounds)) + " |")
    print("| --- |" + " --- |" * args.rounds)
    for key, values in rows.items():
        pairs = [" / ".join(v.split()[1] for v in values[2 * r : 2 * r + 2]) for r in range(args.rounds)]
        print(f"| {key} | " + " | ".join(pairs) + " |")


if __name__ == "__main__":
    main()
