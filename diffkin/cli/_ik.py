"""``diffkin ik``: inverse kinematics of one pose or position (LM), among obstacles (``--avoid``), or every
exact iiwa solution (``--all``)."""

from __future__ import annotations

import sys

import numpy as np

from diffkin.cli._compiled import solve_ik, solve_ik_avoiding, srs_fns
from diffkin.cli._errors import CLIError
from diffkin.cli._robots import SRS_ROBOTS, frame_of, load_robot, robot_key, robot_with_geometry, single_end
from diffkin.cli._scene import read_scene
from diffkin.cli._text import collision_word, fmt


def target_pose(pose) -> np.ndarray:
    """``(4, 4)`` pose ``T_base_target`` of ``--pose x y z qw qx qy qz`` (the quaternion normalised).

    Raises:
        CLIError: a quaternion of (near) zero norm.
    """
    from diffkin import se3

    quat = np.asarray(pose[3:], dtype=np.float64)
    if np.linalg.norm(quat) < 1e-12:
        raise CLIError(f"--pose: the quaternion (qw qx qy qz) must not be zero, got {' '.join(f'{v:g}' for v in quat)}")
    T_base_target = np.eye(4)
    T_base_target[:3, :3] = np.asarray(se3.rotation_from_quaternion(quat))
    T_base_target[:3, 3] = pose[:3]
    return T_base_target


def _ik_all(args, T_base_target: np.ndarray) -> int:
    """The exact iiwa solutions of one pose along its self-motion (``dk.srs``)."""
    if args.robot not in SRS_ROBOTS:
        raise CLIError(
            f"--all: the closed-form arm-angle IK needs a built-in {' or '.join(SRS_ROBOTS)}, got {args.robot!r}"
        )
    if T_base_target.shape != (4, 4):
        raise CLIError("--all needs a full --pose (position and orientation)")
    from diffkin.srs import ALL_GC

    _, sampler, srs_ik, arm_angle = srs_fns(args.robot)
    gc = None if args.gc is None else np.asarray(args.gc)
    if args.psi is not None:
        gcs = ALL_GC if gc is None else gc[None]
        q, valid = (np.asarray(x) for x in srs_ik(T_base_target, np.full(len(gcs), args.psi), gcs))
        psi = np.full(len(gcs), args.psi)
        which = "all global configurations" if gc is None else "gc " + fmt(gc)
        title = f"arm angle psi = {args.psi:+.4f} rad, {which}"
    else:
        q, valid = (
            np.asarray(x)
            for x in (
                sampler(args.samples, False)(T_base_target)
                if gc is None
                else sampler(args.samples, True)(T_base_target, gc)
            )
        )
        psi, gcs = (np.asarray(x) for x in arm_angle(q))
        title = f"{args.samples} samples of the self-motion (dk.srs.sample_self_motion)"
    print(f"{args.robot}: {title}; {int(valid.sum())} of {len(valid)} valid (within limits)")
    print(f"{'psi (rad)':>10}  {'gc':>10}  valid  q (rad)")
    for p, g, v, qi in zip(psi, gcs, valid, q, strict=True):
        print(f"{p:>+10.4f}  {' '.join(f'{int(x):+d}' for x in g):>10}  {'yes' if v else 'no ':<5}  {fmt(qi)}")
    return 0 if valid.any() else 1


def _note_quaternion(pose) -> None:
    """Say on stderr that a ``--pose`` quaternion not of unit norm was normalised."""
    if pose and abs(np.linalg.norm(pose[3:]) - 1) > 1e-6:
        print(
            f"diffkin: note: the quaternion's norm is {np.linalg.norm(pose[3:]):.7g}, not 1: normalised",
            file=sys.stderr,
            flush=True,
        )


def _ik_avoid(args, target: np.ndarray) -> int:
    """IK of the whole robot of a file among the obstacles of ``--avoid`` (``dk.ik.solve(..., avoid=)``)."""
    if args.all:
        raise CLIError("--avoid does not apply to --all (the iiwa closed form ignores obstacles)")
    if args.psi is not None or args.gc is not None or args.samples is not None:
        raise CLIError("--psi, --gc and --samples go with --all")
    if args.base_link is not None:
        raise CLIError("--base-link does not apply to --avoid (the whole robot is solved, targets in its root frame)")
    robot, geom = robot_with_geometry(args.robot, args.srdf)
    end = frame_of(robot, args.end_link, "--end-link") if args.end_link else single_end(robot)
    scene = read_scene(args.avoid, args.margin)
    if args.q0 is not None and len(args.q0) != robot.dof:
        raise CLIError(f"--q0: {robot.name or args.robot} has {robot.dof} joints, got {len(args.q0)} values")
    res = solve_ik_avoiding(
        args.robot,
        end,
        target,
        scene,
        num_seeds=args.seeds,
        q0=args.q0,
        seed=args.seed,
        pos_tol=args.pos_tol,
        rot_tol=args.rot_tol,
        srdf=args.srdf,
    )
    ok = bool(res["success"])
    what = "pose" if target.shape == (4, 4) else "position (orientation free)"
    clearance = float(res["clearance"])
    print(
        f"{robot.name or args.robot}: IK of a {what} of {end}, LM, {args.seeds} seeds{' + q0' if args.q0 else ''}, "
        f"tolerances {args.pos_tol:g} m / {args.rot_tol:g} rad"
    )
    print(
        f"avoiding {scene.world.size} obstacles of {args.avoid}, margin {scene.margin:g} m, "
        f"self-collision {'on' if scene.self_collision else 'off'} ({len(geom.shape_names)} shapes on the robot, "
        f"{len(geom.pair_list)} self pairs)"
    )
    print(f"q          {fmt(res['q'], 10)} rad")
    print(f"success    {ok}")
    print(f"pos_err    {float(res['pos_err']):.3e} m")
    print(f"rot_err    {float(res['rot_err']):.3e} rad{' (not constrained)' if target.shape == (3,) else ''}")
    print(f"iters      {int(res['iters'])}")
    print(f"clearance  {clearance:.3e} m: {collision_word(clearance, scene.margin)}")
    return 0 if ok else 1


def cmd_ik(args) -> int:
    """IK of one pose or position: LM from random seeds, among obstacles with ``--avoid``, or every
    exact iiwa solution with ``--all``."""
    for flag, value in (("--margin", args.margin), ("--srdf", args.srdf)):
        if value is not None and args.avoid is None:
            raise CLIError(f"{flag} goes with --avoid")
    if args.avoid is not None:
        target = target_pose(args.pose) if args.pose else np.asarray(args.position)
        _note_quaternion(args.pose)
        return _ik_avoid(args, target)
    key = robot_key(args.robot, args.end_link, args.base_link)
    chain = load_robot(args.robot, args.end_link, args.base_link)
    target = target_pose(args.pose) if args.pose else np.asarray(args.position)
    _note_quaternion(args.pose)
    if not args.all and (args.psi is not None or args.gc is not None or args.samples is not None):
        raise CLIError("--psi, --gc and --samples go with --all")
    if args.all:
        if args.q0 is not None:
            raise CLIError("--q0 does not apply to --all")
        if args.pos_tol != 1e-5 or args.rot_tol != 1e-4:
            raise CLIError("--pos-tol and --rot-tol do not apply to --all (exact solutions)")
        args.samples = 16 if args.samples is None else args.samples
        return _ik_all(args, target)
    if args.q0 is not None and len(args.q0) != chain.dof:
        raise CLIError(f"--q0: {chain.name or args.robot} has {chain.dof} joints, got {len(args.q0)} values")
    res = solve_ik(
        key, target[None], num_seeds=args.seeds, q0=args.q0, seed=args.seed, pos_tol=args.pos_tol, rot_tol=args.rot_tol
    )
    ok = bool(res["success"][0])
    what = "pose" if target.shape == (4, 4) else "position (orientation free)"
    print(
        f"{chain.name or args.robot}: IK of a {what}, LM, {args.seeds} seeds{' + q0' if args.q0 else ''}, "
        f"tolerances {args.pos_tol:g} m / {args.rot_tol:g} rad"
    )
    print(f"q        {fmt(res['q'][0], 10)} rad")
    print(f"success  {ok}")
    print(f"pos_err  {res['pos_err'][0]:.3e} m")
    print(f"rot_err  {res['rot_err'][0]:.3e} rad{' (not constrained)' if target.shape == (3,) else ''}")
    print(f"iters    {int(res['iters'][0])}")
    return 0 if ok else 1
