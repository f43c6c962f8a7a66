"""Whole robots: a serial arm loaded as a tree against the same arm as a chain, and every link pose of a
humanoid against pytorch-kinematics and Pinocchio.

    python experiments/bench_robots.py [--quick] [--write]

1. iiwa14 (diffkin's shipped URDF, flange ``iiwa14_link_ee``) and Panda (``tests/data/panda.urdf``,
   ``panda_hand_tcp``) loaded by ``dk.load_robot`` (a tree) and by ``dk.load_urdf`` (a chain): FK
   and world Jacobians (analytic) of the flange, jitted, batch 1 and 100,000 float32. The tree must
   be as fast as the chain (chain / tree >= 0.9).
2. Talos (example-robot-data ``talos_full_v2.urdf``: 32 actuated joints, 12 mimic joints, 60 frames):
   every link pose (``dk.link_poses``), float32 and float64, against pytorch-kinematics'
   ``forward_kinematics`` of its tree (every link) and Pinocchio's ``framesForwardKinematics`` called
   once per configuration from Python (Pinocchio has no batch call).

Median of warm runs (compiled first). ``--write`` saves ``experiments/results/<machine>-robots.md``.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import os
import sys
from importlib import metadata
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _bench import busy_note, duration, machine_line, machine_slug, median_seconds, pk, rate, table, torch

import diffkin as dk

HERE = Path(__file__).resolve().parent
ARMS = {
    "iiwa14": (dk.robots.urdf_path("iiwa14"), "iiwa14_link_ee"),
    "Panda": (str(HERE.parent / "tests" / "data" / "panda.urdf"), "panda_hand_tcp"),
}


def _uniform(lower, upper, n: int, dtype: str, seed: int = 0) -> np.ndarray:
    lo = np.maximum(np.where(np.isfinite(lower), lower, -np.pi), -np.pi)
    hi = np.minimum(np.where(np.isfinite(upper), upper, np.pi), np.pi)
    return np.random.default_rng(seed).uniform(lo, hi, (n, len(lo))).astype(dtype)


def _talos_path() -> str | None:
    try:
        root = metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data")
    except metadata.PackageNotFoundError:
        return None
    path = os.path.join(str(root), "robots", "talos_data", "robots", "talos_full_v2.urdf")
    return path if os.path.isfile(path) else None


def arm_rows(batches) -> list[list[str]]:
    """Tree vs chain on the same file: FK and world Jacobian of the flange."""
    rows = []
    for name, (path, end) in ARMS.items():
        robot, chain = dk.load_robot(path), dk.load_urdf(path, end)
        cols = [robot.joint_names.index(n) for n in chain.joint_names]
        work = {
            "FK": (functools.partial(dk.fk, robot, frames=end), functools.partial(dk.fk, chain)),
            "Jacobian (world, analytic)": (
                functools.partial(dk.jacobian, robot, frame_name=end, method="analytic"),
                functools.partial(dk.jacobian, chain, method="analytic"),
            ),
        }
        for label, (tree_fn, chain_fn) in work.items():
            for n in batches:
                q = jnp.asarray(_uniform(robot.lower, robot.upper, n, "float32"))
                t_tree = median_seconds(jax.jit(tree_fn), q)
                t_chain = median_seconds(jax.jit(chain_fn), q[:, cols])  # the chain's joints, outside the timing
                rows.append(
                    [
                        f"{name} {label}",
                        f"{n:,}",
                        "float32",
                        f"{duration(t_tree)} ({rate(n, t_tree)})",
                        f"chain: {duration(t_chain)}",
                        f"**{t_chain / t_tree:.2f}x**",
                        "",
                    ]
                )
    return rows


def talos_rows(n: int) -> list[list[str]]:
    """Every link pose of Talos: diffkin vs pytorch-kinematics (batched) and Pinocchio (one call per config)."""
    path = _talos_path()
    if path is None:
        return [["Talos: example-robot-data is not installed", "", "", "", "", "", ""]]
    robot = dk.load_robot(path)
    rows = []
    with open(path, "rb") as fh:
        text = fh.read()
    pk_tree = pk.build_chain_from_urdf(text) if pk is not None else None
    for dtype in ("float32", "float64"):
        q = jnp.asarray(_uniform(robot.lower, robot.upper, n, dtype))
        fn = jax.jit(lambda q: dk.link_poses(robot, q))
        t_dk = median_seconds(fn, q)
        peers, ratios = [], []
        if pk_tree is not None:
            tree = pk_tree.to(dtype=getattr(torch, dtype))
            q_pk = torch.as_tensor(
                _uniform(
                    -np.full(len(tree.get_joint_parameter_names()), np.pi),
                    np.full(len(tree.get_joint_parameter_names()), np.pi),
                    n,
                    dtype,
                )
            )
            t_pk = median_seconds(tree.forward_kinematics, q_pk, repeats=3, warmup=1)
            peers.append(f"pytorch-kinematics: {duration(t_pk)} ({rate(n, t_pk)})")
            ratios.append(f"pk **{t_pk / t_dk:.0f}x**")
        if dtype == "float64":
            t_pin = _pinocchio_seconds(path, robot, np.asarray(q[: min(n, 2000)]))
            peers.append(f"Pinocchio: {duration(t_pin * n)} ({rate(n, t_pin * n)}, one call per configuration)")
            ratios.append(f"Pinocchio **{t_pin * n / t_dk:.1f}x**")
        rows.append(
            [
                f"Talos, all {len(robot.frame_names)} link poses ({robot.dof} joints + {len(robot.mimic)} mimic)",
                f"{n:,}",
                dtype,
                f"{duration(t_dk)} ({rate(n, t_dk)})",
                "; ".join(peers) or "n/a",
                "; ".join(ratios) or "n/a",
                "",
            ]
        )
    return rows


def _pinocchio_seconds(path: str, robot, q: np.ndarray) -> float:
    """Seconds per configuration of Pinocchio's ``framesForwardKinematics`` (a Python loop over ``q``)."""
    import time

    import pinocchio as pin

    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    qp = np.tile(pin.neutral(model), (len(q), 1))
    for i, name in enumerate(robot.joint_names):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 1:
            qp[:, joint.idx_q] = q[:, i]
    start = time.perf_counter()
    for row in qp:
        pin.framesForwardKinematics(model, data, row)
    return (time.perf_counter() - start) / len(q)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small batches (a smoke run)")
    parser.add_argument("--write", action="store_true", help="save experiments/results/<machine>-robots.md")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    batches = (1, 1000) if args.quick else (1, 100_000)
    rows = arm_rows(batches) + talos_rows(1000 if args.quick else 100_000)
    header = ["work", "batch", "dtype", "diffkin (tree)", "compared with", "ratio (> 1: tree faster)", "notes"]
    command = "python experiments/bench_robots.py" + " --quick" * args.quick
    about = (
        f"`{command}`, {datetime.date.today()}. Median of warm runs (jitted, compiled first). Tree rows: "
        "the same URDF loaded as a `dk.Robot` and as a chain (`dk.load_urdf`); ratio = chain / tree. Talos: "
        "pytorch-kinematics' `forward_kinematics` of its tree (all links), Pinocchio's `framesForwardKinematics` "
        "timed per configuration over 2,000 configurations and scaled to the batch."
    )
    text = "\n\n".join(
        p for p in ["# diffkin whole-robot benchmark", machine_line(), busy_note(), about, table(header, rows)] if p
    )
    print(text)
    if args.write:
        out = HERE / "results" / f"{machine_slug()}-robots.md"
        out.write_text(text + "\n")
        print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
