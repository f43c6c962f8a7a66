"""``diffkin place``: base poses scored by the task poses a capability map reaches, the best printed,
verified by IK, plotted and saved."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from diffkin.cli._errors import CLIError, need
from diffkin.cli._robots import jax_x64, load_robot


def read_tasks(path: str) -> np.ndarray:
    """``(N, 4, 4)`` task poses from a ``.npy`` array, a ``.npz`` with ``tasks`` or a JSON list of 4x4 matrices."""
    from diffkin._npz import read_npz

    file = Path(path)
    if not file.is_file():
        raise CLIError(f"--tasks: no such file {path!r}")
    try:
        if file.suffix == ".json":
            tasks = np.asarray(json.loads(file.read_text()), dtype=np.float64)
        elif file.suffix == ".npz":
            arrays = read_npz(file, "with an array 'tasks' (N, 4, 4)")
            if "tasks" not in arrays:
                raise CLIError(f"--tasks: {path}: expected an array 'tasks', got {sorted(arrays)}")
            tasks = np.asarray(arrays["tasks"], np.float64)
        else:
            tasks = np.asarray(np.load(file, allow_pickle=False), np.float64)
    except (ValueError, TypeError, OSError) as e:
        raise CLIError(f"--tasks: could not read {path!r} ({e})") from None
    if tasks.ndim != 3 or tasks.shape[1:] != (4, 4) or len(tasks) == 0:
        raise CLIError(f"--tasks: expected task poses of shape (N, 4, 4), got {tasks.shape} in {path!r}")
    return tasks


def cmd_place(args) -> int:
    """Score base poses over ``--region`` by the tasks of ``--tasks`` that a capability map reaches."""
    jax = jax_x64()
    import diffkin as dk

    chain = load_robot(args.robot, args.end_link, args.base_link)
    tasks = read_tasks(args.tasks)
    for flag, path in (("--plot", args.plot), ("--out", args.out)):
        if path and not Path(path).parent.is_dir():
            raise CLIError(f"{flag}: no such directory {str(Path(path).parent)!r}")
    if args.plot:
        need("matplotlib", "--plot", "plot")
    if args.verify < 0:
        raise CLIError(f"--verify: expected a number of bases >= 0, got {args.verify}")
    if args.map:
        if not Path(args.map).is_file():
            raise CLIError(f"--map: no such file {args.map!r}")
        cap = dk.workspace.CapabilityMap.load(args.map)
        print(f"map: {args.map} ({cap.chain_name}, {cap.n_samples:,} samples, {cap.cells.size:,} cells)")
    else:
        start = time.perf_counter()
        cap = dk.workspace.capability(
            chain,
            args.samples,
            key=jax.random.key(args.seed),
            voxel_size=args.voxel,
            orientation_bins=args.orientation_bins,
            progress=not args.no_progress,
        )
        print(
            f"map: {args.samples:,} samples in {time.perf_counter() - start:.2f} s, {cap.voxel_size:g} m voxels x "
            f"{cap.orientation_bins} orientation bins, {cap.cells.size:,} cells reached"
        )
    (xmin, ymin, xmax, ymax) = args.region
    start = time.perf_counter()
    placement = dk.workspace.base_placement(
        cap,
        tasks,
        region=[[xmin, ymin], [xmax, ymax]],
        yaw_bins=args.yaw_bins,
        base_height=args.base_height,
        cell=args.cell,
    )
    nx, ny, nyaw = placement.score.shape
    print(
        f"placement: {len(tasks):,} tasks x {nx} x {ny} x {nyaw} bases in {time.perf_counter() - start:.2f} s "
        f"(incl. compile); score = fraction of the tasks the map reaches (a prior: --verify checks by IK)"
    )
    cells = placement.best_cells(args.best)
    for rank, (i, j, k) in enumerate(cells):
        print(
            f"  {rank + 1}. base x {placement.x[i]:+.3f} m, y {placement.y[j]:+.3f} m, "
            f"yaw {np.degrees(placement.yaw[k]):5.1f} deg: score {placement.score[i, j, k]:.1%}"
        )
    if args.verify:
        start = time.perf_counter()
        check = placement.verify(chain, args.verify, key=jax.random.key(args.seed))
        print(f"verified by IK ({time.perf_counter() - start:.2f} s): fraction of the tasks solved from each base")
        for rank, (score, verified) in enumerate(zip(check.score, check.verified, strict=True)):
            print(f"  {rank + 1}. map {score:.1%}, IK {verified:.1%}")
    if args.plot:
        dk.workspace.plot_placement(placement, path=args.plot)
        print(f"plot: the score over (x, y) at the best yaw, tasks drawn -> {args.plot}")
    if args.out:
        np.savez(
            args.out,
            score=placement.score,
            x=placement.x,
            y=placement.y,
            yaw=placement.yaw,
            best=placement.best(args.best),
        )
        print(f"saved {args.out} (score (nx, ny, nyaw), x, y, yaw, best ({len(cells)}, 4, 4) T_world_base)")
    return 0
