"""Which ratios of the IK weights converge: the Panda's hand on 64 of its own poses, ``(w_pos, w_rot) = (1, r)``.

    python experiments/ik_weight_ratios.py

The Panda of ``tests/data`` (a tree with its fingers), 64 reachable hand poses (random configurations
within the limits, seed 0), ``dk.ik.solve`` with its defaults (float64), ``weights={"panda_hand_tcp": (1,
r)}`` for ratios ``r`` from 1e-8 to 1e8; prints the success rate per ratio (docs/ik.md, "weights"). Each
ratio compiles its own solver (the weights are constants of the program): about ten seconds each.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _models import PANDA, random_robot_q  # noqa: E402

import diffkin as dk  # noqa: E402

RATIOS = (1e-8, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1.0, 1e2, 1e3, 1e4, 1e5, 1e6, 1e8)


def main() -> None:
    robot = dk.load_robot(PANDA)
    T = np.asarray(dk.fk(robot, random_robot_q(robot, 64, seed=0), "panda_hand_tcp"))
    print("| w_rot / w_pos | success |")
    print("| ---: | ---: |")
    for r in RATIOS:
        res = dk.ik.solve(robot, {"panda_hand_tcp": T}, weights={"panda_hand_tcp": (1.0, r)}, key=jax.random.key(0))
        print(f"| {r:g} | {np.mean(res.success):.1%} |", flush=True)


if __name__ == "__main__":
    main()
