"""Capability map and base placement of example-robot-data's Panda (issue 60).

A capability map of the ``panda_hand_tcp`` frame at 5 cm voxels x 5184 orientation bins (15 degree
cells; worst angular error 16.1 degrees, see ``dk.workspace.capability``), float32: its time, peak
memory and cells; then a base placement for 1,000 task poses on a table (tool z pointing down within
30 degrees, any yaw about the vertical) over a 2 m x 2 m region at 5 cm cells x 36 yaws, timed warm;
then the top 10 bases re-solved by IK (``Placement.verify``), and the map's precision and recall
against IK on 2,000 random (base, task) pairs of the grid (``--pairs-seed`` draws another set): of
``CapabilityMap.reaches`` (the pose judged by its cell and the cells beside it) and of its cell alone
(``count >= 1``).

The issue's size is 10^8 samples (``--samples 1e8``; 10^9 on a GPU); the default, 10^7, suits a shared
2-core machine. ``--map FILE`` reads a map that ``CapabilityMap.save`` wrote (built with these
arguments: the Panda's frame, key 0, 5 cm voxels) instead of building it. ``--write`` saves
``experiments/results/<machine>-capability.md``.
"""

from __future__ import annotations

import argparse
import datetime
import os
import resource
import sys
import time
from pathlib import Path

import jax
import numpy as np
from _bench import busy_note, example_robot_data, machine_line, machine_slug, table

import diffkin as dk
from diffkin.workspace._placement import planar_poses

HERE = Path(__file__).resolve().parent
FRAME = "panda_hand_tcp"
REGION = [[-1.0, -1.0], [1.0, 1.0]]


def table_tasks(n: int, seed: int = 0) -> np.ndarray:
    """``(n, 4, 4)`` tool poses over a 0.6 m x 0.4 m table centred on the world origin, 0.35-0.55 m above the
    floor the base stands on: tool z down within 30 degrees, any yaw."""
    rng = np.random.default_rng(seed)
    p = np.stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.2, 0.2, n), rng.uniform(0.35, 0.55, n)], axis=1)
    yaw, tilt, tilt_dir = (
        rng.uniform(-np.pi, np.pi, n),
        np.arccos(rng.uniform(np.cos(np.pi / 6), 1, n)),
        rng.uniform(-np.pi, np.pi, n),
    )
    down = np.diag([1.0, -1.0, -1.0])  # tool z along -world z
    T = planar_poses(p[:, 0], p[:, 1], yaw, 0.0)
    axis = np.stack([np.cos(tilt_dir), np.sin(tilt_dir), np.zeros(n)], axis=1)
    K = np.zeros((n, 3, 3))
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = axis[:, 1], -axis[:, 0], -axis[:, 1], axis[:, 0]
    tilt_R = np.eye(3) + np.sin(tilt)[:, None, None] * K + (1 - np.cos(tilt))[:, None, None] * K @ K
    T[:, :3, :3] = tilt_R @ T[:, :3, :3] @ down
    T[:, :3, 3] = p
    return T


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=float, default=1e7, help="map samples (default 1e7; the issue's: 1e8)")
    parser.add_argument("--bins", type=int, default=5184, help="orientation bins, 24 d^3 (default 5184: 15 deg)")
    parser.add_argument("--tasks", type=int, default=1000, help="task poses (default 1,000)")
    parser.add_argument("--pairs", type=int, default=2000, help="random (base, task) pairs for precision/recall")
    parser.add_argument("--pairs-seed", type=int, default=2, help="seed of the pairs' draw (default 2)")
    parser.add_argument("--map", metavar="NPZ", help="read the map from this file instead of building it")
    parser.add_argument("--figure", metavar="PNG", help="also plot the placement's score at the best yaw")
    parser.add_argument("--write", action="store_true", help="save experiments/results/<machine>-capability.md")
    args = parser.parse_args(argv)
    n, load, busy = int(args.samples), os.getloadavg()[0], busy_note()  # the load before the run
    path = os.path.join(example_robot_data(), "panda_description", "urdf", "panda.urdf")
    robot = dk.load_robot(path)
    model = (robot, FRAME)

    start = time.perf_counter()
    if args.map:
        cap = dk.workspace.CapabilityMap.load(args.map)
        if (cap.n_samples, cap.orientation_bins, cap.voxel_size) != (n, args.bins, 0.05):
            raise SystemExit(
                f"--map: {args.map} holds {cap.n_samples:g} samples, {cap.orientation_bins} bins, "
                f"{cap.voxel_size} m voxels; expected --samples {n:g}, --bins {args.bins}, 0.05 m"
            )
    else:
        cap = dk.workspace.capability(model, n, key=jax.random.key(0), voxel_size=0.05, orientation_bins=args.bins)
    map_s = time.perf_counter() - start
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    tasks = table_tasks(args.tasks)
    kwargs = dict(region=REGION, yaw_bins=36, base_height=0.0, cell=0.05)
    start = time.perf_counter()
    placement = dk.workspace.base_placement(cap, tasks, **kwargs)
    first_s = time.perf_counter() - start
    warm, cpu = [], []
    for _ in range(5):
        start, start_cpu = time.perf_counter(), time.process_time()
        dk.workspace.base_placement(cap, tasks, **kwargs)
        warm.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    warm_s, cpu_s = float(np.median(warm)), float(np.median(cpu))

    start = time.perf_counter()
    check = placement.verify(model, k=10, key=jax.random.key(1))
    verify_s = time.perf_counter() - start

    # Precision and recall of the map's look-ups against IK on random (base, task) pairs of the grid.
    rng = np.random.default_rng(args.pairs_seed)
    cells = [rng.integers(0, s, args.pairs) for s in placement.score.shape]
    bases = placement.base(*cells)
    pick = rng.integers(0, len(tasks), args.pairs)
    in_base = np.linalg.inv(bases) @ tasks[pick]
    start = time.perf_counter()
    truth = np.asarray(dk.ik.solve(robot, {FRAME: tasks[pick]}, base=bases, key=jax.random.key(3)).success)
    pairs_s = time.perf_counter() - start

    def measured(said: np.ndarray) -> str:
        hit = (said & truth).sum()
        return f"precision {hit / max(said.sum(), 1):.3f}, recall {hit / max(truth.sum(), 1):.3f}"

    said = cap.reaches(in_base)
    versus = (
        f"reaches: {measured(said)} ({int(truth.sum())} reachable by IK, {int(said.sum())} by the map); "
        f"reaches(min_count=2): {measured(cap.reaches(in_base, min_count=2))}; "
        f"the cell alone (count >= 1): {measured(cap.count(in_base) >= 1)}"
    )

    nx, ny, nyaw = placement.score.shape
    d = round((args.bins / 24) ** (1 / 3))
    rows = [
        [
            "capability map",
            f"{n:,} samples, 5 cm x {args.bins} bins ({90 / d:g} deg), grid {'x'.join(map(str, cap.shape))}",
            f"read from {args.map} in {map_s:.1f} s"
            if args.map
            else f"{map_s:.1f} s ({n / map_s / 1e6:.2f} M/s incl. compile)",
            f"{cap.cells.size:,} cells reached, {int((cap.counts > 0).sum()):,} voxels; peak RSS {peak_mb:,.0f} MB",
        ],
        [
            "base placement",
            f"{len(tasks):,} tasks x {nx} x {ny} x {nyaw} bases",
            f"{warm_s * 1e3:.0f} ms warm, {cpu_s * 1e3:.0f} ms of CPU (first {first_s:.1f} s)",
            f"best map score {placement.score.max():.1%}",
        ],
        [
            "verify top 10 by IK",
            f"{10 * len(tasks):,} IK problems (dk.ik.solve, base=)",
            f"{verify_s:.1f} s",
            "map score -> IK-verified: "
            + ", ".join(f"{s:.0%}->{v:.0%}" for s, v in zip(check.score, check.verified, strict=True)),
        ],
        [
            "map vs IK",
            f"{args.pairs:,} random (base cell, task) pairs (seed {args.pairs_seed})",
            f"{pairs_s:.1f} s of IK",
            versus,
        ],
    ]
    command = "python experiments/bench_capability.py" + (f" --samples {args.samples:g}" if n != 10**7 else "")
    command += f" --bins {args.bins}" if args.bins != 5184 else ""
    command += f" --pairs-seed {args.pairs_seed}" if args.pairs_seed != 2 else ""
    command += f" --map {args.map}" if args.map else ""
    about = (
        f"`{command}`, {datetime.date.today()}, 1-minute load average {load:.1f} before the run. "
        f"example-robot-data's Panda, frame `{FRAME}`, float32 map, "
        "default chunk; tasks: 0.6 m x 0.4 m table at the world origin, 0.35-0.55 m above the base's floor, tool "
        "z down within 30 deg, any yaw; region 2 m x 2 m at 5 cm cells, 36 yaws. IK: `dk.ik.solve` defaults "
        "(32 seeds, 1e-5 m / 1e-4 rad). Recall grows with the samples (most of the Panda's ~10^8 reachable "
        "cells hold a few samples at 10^7)."
    )
    text = "\n\n".join(
        p
        for p in [
            "# diffkin capability map and base placement (Panda)",
            machine_line(),
            busy,
            about,
            table(["work", "size", "time", "result"], rows),
        ]
        if p
    )
    print(text)
    if args.figure:
        dk.workspace.plot_placement(placement, path=args.figure)
        print(f"\nwrote {args.figure}")
    if args.write:
        out = HERE / "results" / f"{machine_slug()}-capability.md"
        with out.open("a") as file:  # one section per run (sizes and bins)
            file.write(text + "\n\n")
        print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
