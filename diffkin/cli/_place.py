"""``diffkin place``: base poses scored by the task poses a capability map reaches (among the obstacles of
``--avoid``), the best printed, verified by IK, plotted, saved and shown in the viewer (``--view``)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from diffkin.cli._errors import CLIError, need
from diffkin.cli._robots import ROBOTS, frame_of, jax_x64, load_robot, robot_with_geometry, single_end, tree
from diffkin.cli._scene import read_scene


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


def _rigid_targets(tasks: np.ndarray, path: str) -> None:
    """Task poses that ``--verify`` can hand to IK: rigid transforms in float64 (said before the map is built).

    Raises:
        CLIError: the first task that is not a rigid transform within 1e-9 (e.g. rounded or float32 poses).
    """
    from diffkin._checks import rigid_poses, rigid_tol

    bad = np.flatnonzero(~rigid_poses(tasks))
    if bad.size:
        raise CLIError(
            f"--tasks: task {bad[0]} of {path!r} is not a rigid transform within {rigid_tol(tasks.dtype):g} "
            "(R^T R = I, det R = +1, last row 0 0 0 1), which --verify needs to solve it by IK: write the poses "
            "at full float64 precision"
        )


def _obstacles(args):
    """``(model, avoid, scene)`` of ``--avoid``: the file's whole robot and the frame the tasks are poses of
    (``--end-link``, default the single leaf), its ``dk.ik.Avoid`` with the scene's obstacles, and the scene."""
    import diffkin as dk

    if args.base_link is not None:
        raise CLIError("--base-link does not apply to --avoid (the whole robot is placed: its root stands on the base)")
    robot, geom = robot_with_geometry(args.robot, args.srdf)
    end = frame_of(robot, args.end_link, "--end-link") if args.end_link else single_end(robot)
    scene = read_scene(args.avoid, args.margin)
    return (robot, end), dk.ik.Avoid(geom, scene.world, scene.margin, scene.self_collision), scene


def _check_flags(args) -> None:
    """The one-line errors of flags that go with others, of output paths and of numbers."""
    for flag, value in (("--margin", args.margin), ("--srdf", args.srdf)):
        if value is not None and args.avoid is None:
            raise CLIError(f"{flag} goes with --avoid")
    for flag, value in (("--host", args.host), ("--port", args.port)):
        if value is not None and not args.view:
            raise CLIError(f"{flag} goes with --view")
    for flag, path in (("--plot", args.plot), ("--out", args.out)):
        if path and not Path(path).parent.is_dir():
            raise CLIError(f"{flag}: no such directory {str(Path(path).parent)!r}")
    if args.plot:
        need("matplotlib", "--plot", "plot")
    if args.verify < 0:
        raise CLIError(f"--verify: expected a number of bases >= 0, got {args.verify}")
    xmin, ymin, xmax, ymax = args.region
    if not (xmin < xmax and ymin < ymax):  # before a map is built: that may take minutes
        raise CLIError(f"--region: expected XMIN < XMAX and YMIN < YMAX, got {xmin:g} {ymin:g} {xmax:g} {ymax:g}")
    if args.map and not Path(args.map).is_file():
        raise CLIError(f"--map: no such file {args.map!r}")


def _view(args, placement, model, avoid) -> None:
    """Serve the viewer on the placement's ``--best`` bases until Ctrl-C (``dk.viewer.show``): a file's whole
    robot with its meshes (the chain alone with ``--base-link``), the obstacles of ``--avoid`` drawn."""
    from diffkin import viewer

    if model is not None:  # --avoid: the robot with its geometry, drags solved clear of the obstacles
        shown, source, ends = model[0], args.robot, [model[1]]
    elif args.robot in ROBOTS:
        shown, source, ends = args.robot, None, None
    elif args.base_link is not None:  # the root of the file's robot is not the chain's base
        shown, source, ends = load_robot(args.robot, args.end_link, args.base_link), None, None
    else:
        shown, source = tree(args.robot), args.robot
        ends = [args.end_link or single_end(shown)]
    print(f"viewer: the {min(args.best, placement.score.size)} best bases and the tasks", flush=True)
    viewer.show(
        shown,
        source=source,
        ends=ends,
        avoid=avoid,
        placement=placement,
        best_bases=args.best,
        host=args.host or "127.0.0.1",
        port=args.port or 8080,
        block=True,
    )


def cmd_place(args) -> int:
    """Score base poses over ``--region`` by the tasks of ``--tasks`` that a capability map reaches, among
    the obstacles of ``--avoid``; ``--view`` serves the viewer on the best bases."""
    jax = jax_x64()
    import diffkin as dk

    _check_flags(args)
    if args.view:
        try:
            from diffkin import viewer  # noqa: F401  (before the map: a missing extra is said at once)
        except ImportError as e:
            raise CLIError(str(e)) from None
    chain = load_robot(args.robot, args.end_link, args.base_link)
    tasks = read_tasks(args.tasks)
    if args.verify:
        _rigid_targets(tasks, args.tasks)
    model = avoid = scene = None
    if args.avoid is not None:
        model, avoid, scene = _obstacles(args)
    if args.map:
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
        at_pose=not args.cell_only,
        model=model,
        avoid=avoid,
    )
    nx, ny, nyaw = placement.score.shape
    print(
        f"placement: {len(tasks):,} tasks x {nx} x {ny} x {nyaw} bases in {time.perf_counter() - start:.2f} s "
        f"(incl. compile); score = fraction of the tasks the map reaches (a prior: --verify checks by IK)"
    )
    if scene is not None:
        bases, out = np.asarray(placement.blocked_bases), np.asarray(placement.blocked_tasks)
        print(
            f"obstacles: {int(bases.sum()):,} of {bases.size:,} bases and {int(out.sum()):,} of {out.size:,} "
            f"tasks ruled out (within the margin {scene.margin:g} m of the {scene.world.size} obstacles of "
            f"{args.avoid} at every solution: the root body at the base, the tool body at the task)"
        )
    cells = placement.best_cells(args.best)
    for rank, (i, j, k) in enumerate(cells):
        print(
            f"  {rank + 1}. base x {placement.x[i]:+.3f} m, y {placement.y[j]:+.3f} m, "
            f"yaw {np.degrees(placement.yaw[k]):5.1f} deg: score {placement.score[i, j, k]:.1%}"
        )
    if args.verify:
        start = time.perf_counter()
        check = placement.verify(model or chain, args.verify, avoid=avoid, key=jax.random.key(args.seed))
        clear = " clear of the obstacles" if avoid is not None else ""
        print(
            f"verified by IK ({time.perf_counter() - start:.2f} s): fraction of the tasks solved{clear} from each base"
        )
        for rank, (score, verified) in enumerate(zip(check.score, check.verified, strict=True)):
            print(f"  {rank + 1}. map {score:.1%}, IK {verified:.1%}")
    if args.plot:
        dk.workspace.plot_placement(placement, path=args.plot)
        print(f"plot: the score over (x, y) at the best yaw, tasks drawn -> {args.plot}")
    if args.out:
        blocked: dict[str, Any] = {}  # (Any: np.savez's stub takes allow_pickle among the names)
        if placement.blocked_bases is not None and placement.blocked_tasks is not None:
            blocked = dict(blocked_bases=placement.blocked_bases, blocked_tasks=placement.blocked_tasks)
        np.savez(
            args.out,
            score=placement.score,
            x=placement.x,
            y=placement.y,
            yaw=placement.yaw,
            best=placement.best(args.best),
            **blocked,
        )
        also = ", blocked_bases (nx, ny, nyaw), blocked_tasks (N,)" if blocked else ""
        print(f"saved {args.out} (score (nx, ny, nyaw), x, y, yaw, best ({len(cells)}, 4, 4) T_world_base{also})")
    if args.view:
        _view(args, placement, model, avoid)
    return 0
