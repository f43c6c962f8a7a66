"""Velocity IK (``dk.ik.step``) beside mink: one Panda step at batch 1 and 4,096, steps per second.

The Panda arm of example-robot-data (fingers removed: 7 joints), its hand's pose tracked (diffkin: the
pose target; mink: ``FrameTask``, daqp), position limits over the step and the URDF's velocity limits,
damping 1e-3. diffkin's step is one ``jax.jit`` of ``dk.ik.step`` (float32 and float64); its compile
time is the first call's. mink steps one configuration at a time (``Configuration.update`` and
``solve_ik``), so its batch of 4,096 is a loop. Medians of interleaved calls after a warmup
(``_bench.median_seconds_interleaved``); the table goes to ``experiments/results/<machine>-step.md``.

    python experiments/bench_step.py            # batch 1 and 4,096
    python experiments/bench_step.py --quick    # batch 1 and 256
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import re
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _bench import busy_note, example_robot_data, machine_line, median_seconds_interleaved, publish, rate  # noqa: E402

import diffkin as dk  # noqa: E402

DT, DAMPING = 0.001, 1e-3
VELOCITY = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])  # the URDF's (rad/s)


def arm_urdf() -> str:
    """The Panda without its fingers, meshes and static-body fusion (MuJoCo keeps the hand's body)."""
    with open(os.path.join(example_robot_data(), "panda_description/urdf/panda.urdf")) as f:
        text = f.read()
    for pattern in (
        r"<visual>.*?</visual>",
        r"<collision>.*?</collision>",
        r'<link name="panda_(left|right)finger">.*?</link>',
        r'<joint name="panda_finger_joint[12]".*?</joint>',
    ):
        text = re.sub(pattern, "", text, flags=re.S)
    return text.replace("</robot>", '<mujoco><compiler fusestatic="false"/></mujoco></robot>')


def problems(robot, n: int, seed: int = 0):
    """``n`` configurations within the limits and hand targets 1 cm to 5 cm from the hand (float64 NumPy)."""
    rng = np.random.default_rng(seed)
    lower, upper = np.asarray(robot.lower), np.asarray(robot.upper)
    q = rng.uniform(lower + 0.1, upper - 0.1, (n, robot.dof))
    T = np.array(dk.fk(robot, jnp.asarray(q), "panda_hand"))
    move = rng.normal(size=(n, 3))
    T[:, :3, 3] += move / np.linalg.norm(move, axis=1, keepdims=True) * rng.uniform(0.01, 0.05, (n, 1))
    return q, T


def diffkin_rows(robot, q, T, batches) -> tuple[list, list]:
    """Per dtype and batch: the timed call ``(fn, args)`` and the row's start (its compile time measured here)."""
    calls, rows = [], []
    for dtype in (jnp.float32, jnp.float64):
        step = jax.jit(
            lambda q, T, dtype=dtype: dk.ik.step(
                robot, q, {"panda_hand": T}, dt=DT, velocity=jnp.asarray(VELOCITY, dtype), damping=DAMPING
            )
        )
        for b in batches:
            args = (jnp.asarray(q[:b], dtype), jnp.asarray(T[:b], dtype))
            if b == 1:
                args = (args[0][0], args[1][0])
            start = time.perf_counter()
            out = jax.block_until_ready(step(*args))
            compile_s = time.perf_counter() - start
            assert bool(jnp.all(out.feasible)), "a step of the benchmark was infeasible"
            calls.append((step, args))
            rows.append([f"diffkin `dk.ik.step`, {jnp.dtype(dtype).name}", f"{b:,}", f"{compile_s:.1f}"])
    return calls, rows


def mink_call(q, T):
    """One mink step per configuration, in a loop: ``(fn, args)``, or ``None`` without mink."""
    try:
        import mink
        import mujoco
    except ImportError:
        return None
    model = mujoco.MjModel.from_xml_string(arm_urdf())
    configuration = mink.Configuration(model, q[0])
    task = mink.FrameTask("panda_hand", "body", position_cost=1.0, orientation_cost=1.0)
    limits = [
        mink.ConfigurationLimit(model, gain=1.0),
        mink.VelocityLimit(model, {f"panda_joint{i + 1}": VELOCITY[i] for i in range(7)}),
    ]
    targets = [mink.SE3.from_matrix(t) for t in T]

    def steps(n):
        out = []
        for k in range(n):
            configuration.update(q[k])
            task.set_target(targets[k])
            out.append(mink.solve_ik(configuration, [task], DT, "daqp", damping=DAMPING, limits=limits))
        return np.asarray(out)

    return steps, mink


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="batch 1 and 256 (a smoke run)")
    args = parser.parse_args()
    jax.config.update("jax_enable_x64", True)  # float64 available; each call's dtype is its arrays'
    batches = (1, 256) if args.quick else (1, 4096)
    head = [
        f"# Velocity IK: `dk.ik.step` beside mink ({time.strftime('%Y-%m-%d')})",
        f"`python experiments/bench_step.py{' --quick' if args.quick else ''}`. {machine_line()}.",
        busy_note(),
    ]
    robot = dk.load_robot(arm_urdf())
    q, T = problems(robot, max(batches))
    calls, rows = diffkin_rows(robot, q, T, batches)
    peer = mink_call(q, T)
    if peer is not None:
        steps, mink = peer
        for b in batches:
            n = min(b, 256)  # a loop: its rate does not depend on the batch (256 steps timed at the larger)
            calls.append((lambda n=n: steps(n), ()))
            label = "mink " + importlib.metadata.version("mink") + " (daqp), a loop" + (" (256 timed)" if b > n else "")
            rows.append([label, f"{b:,}", "-"])
    seconds = median_seconds_interleaved(calls, rounds=5, min_time=1.0)
    lines = ["| solver | batch | compile (s) | time per call | steps/s |", "| --- | --- | --- | --- | --- |"]
    for row, s in zip(rows, seconds, strict=True):
        b = int(row[1].replace(",", ""))
        n = min(b, 256) if row[0].startswith("mink") else b
        lines.append(f"| {row[0]} | {row[1]} | {row[2]} | {s / n * b * 1e6:,.0f} us | {rate(n, s)} |")
    publish(head + ["\n".join(lines)], None if args.quick else "step")


if __name__ == "__main__":
    main()
