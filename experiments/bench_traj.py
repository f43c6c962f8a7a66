"""Collision-free trajectories (``dk.traj.optimize``) on MotionBenchMaker's Panda problems (issue 58).

Per problem (``../shared/data/mbm/panda_mbm_problems.json``, read as ``SOURCES.md`` there says):
``start -> goal_q`` (a joint goal) and ``start -> goal_pose`` (the ``panda_hand`` pose, solved by
collision-aware IK inside ``optimize``), the problem's own obstacles (exact boxes and cylinders:
:func:`bench_geometry.world_of`, a world per problem), example-robot-data's Panda and SRDF with the
fingers locked at MBM's 0.065 m, margin 5 mm. Velocity limits from the URDF's ``<limit velocity>``;
accelerations Franka's published ones (below); no jerk bound.

Each returned motion is judged independently, in float64, sampled densely along ``Trajectory.at``
(``--samples`` times per motion, evenly in time, plus the knots):

- **clearance on the real meshes**: coal's signed distances of the URDF's collision meshes and finger
  boxes to the exact obstacles and over the SRDF's enabled self pairs (``bench_mbm.Judge``), at every
  sample: a contact anywhere (coal < 0) is a failure;
- **limits**: joint limits at every sample, velocity and acceleration (``at(t, 1)``, ``at(t, 2)``)
  within the limits (relative slack 1e-5);
- **goal**: the joint goal within 1e-6 rad at the end, or the pose within 1e-5 m / 1e-4 rad (Pinocchio,
  or ``dk.fk`` where it is not installed).

**Solved** = ``success`` confirmed by all three. **Solvable**: MBM's ``goal_q`` clears its obstacles and
the self pairs by the margin on the real meshes, and the start and ``goal_q`` lie within the URDF's joint
limits (a witness that the goal is reachable; not that a motion exists). A few of MBM's ``goal_q`` exceed
a joint limit of example-robot-data's Panda (joint 4's upper): no motion within the limits reaches them.
Times: the first call (the first scene's batch, compile included) apart, then each scene once, warm (its
problems batched in one call, each with its own world).

    python experiments/bench_traj.py --quick           # 3 scenes x 3 problems, hulls
    python experiments/bench_traj.py --all --write     # all 700 (long on a CPU)
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from _bench import busy_note, machine_line, publish, table
from bench_geometry import FINGER, MARGIN, MBM, PAD, panda, revision, world_of
from bench_mbm import EE, Judge, subset, target_of

import diffkin as dk

C = dk.collision
QUICK_SCENES = ("bookshelf_small", "box", "table_pick")
# Franka's published joint limits (Franka Control Interface docs, "Limits for Panda": rad/s^2), arm only;
# the fingers are locked (any positive value)
ACCELERATION = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0, 1.0])
HEADER = [
    "scene",
    "goal",
    "problems",
    "solvable",
    "success",
    "solved",
    "success in contact (coal)",
    "success off limits",
    "success off goal",
    "motion time (s, mean solved)",
    "path length (rad, mean solved)",
    "warm (s / problem)",
]


def velocity_limits(urdf: str, robot: dk.Robot) -> np.ndarray:
    """Per joint of ``robot``, the URDF's ``<limit velocity>``."""
    import xml.etree.ElementTree as ET

    root = ET.parse(urdf).getroot()
    found = {
        j.get("name"): float(j.find("limit").get("velocity")) for j in root.iter("joint") if j.find("limit") is not None
    }
    return np.array([found[name] for name in robot.joint_names])


def plan(robot, geom, problems: list, kind: str, limits, args, dtype):
    """One call for a scene's problems: ``(Trajectory, seconds)``."""
    worlds = [world_of(p, PAD) for p in problems]
    world = jax.tree.map(lambda *x: jnp.stack(x).astype(dtype), *worlds)
    avoid = dk.ik.Avoid(geom, world, margin=MARGIN)
    start = jnp.asarray([np.r_[p["start"], FINGER] for p in problems], dtype)
    if kind == "goal_q":
        goal = jnp.asarray([np.r_[p["goal_q"], FINGER] for p in problems], dtype)
    else:
        goal = {EE: jnp.asarray(np.stack([target_of(p) for p in problems]), dtype)}
    t0 = time.perf_counter()
    traj = dk.traj.optimize(
        robot,
        start,
        goal,
        avoid=avoid,
        limits=limits,
        knots=args.knots,
        num_seeds=args.seeds,
        max_iters=args.iters,
        locked={"panda_finger_joint1": FINGER},
    )
    traj = jax.block_until_ready(traj)
    return traj, time.perf_counter() - t0


def judge_motions(judge: Judge, traj, problems: list, kind: str, limits, samples: int) -> dict:
    """Per problem: coal's smallest clearance along the motion, limits along it, the goal reached."""
    n = len(problems)
    s = np.linspace(0.0, 1.0, samples)
    dur = np.asarray(traj.duration, np.float64)
    t = np.concatenate([s[:, None] * dur[None], np.asarray(traj.t, np.float64).T])  # (M, n)
    q = np.asarray(traj.at(jnp.asarray(t, traj.t.dtype)), np.float64)  # (M, n, dof)
    v = np.asarray(traj.at(jnp.asarray(t, traj.t.dtype), 1), np.float64)
    a = np.asarray(traj.at(jnp.asarray(t, traj.t.dtype), 2), np.float64)
    coal = np.empty(n)
    for k, p in enumerate(problems):
        obstacles = judge.coal.obstacles(p)
        world, own = judge.clearance(q[:, k], [obstacles] * len(q))
        coal[k] = min(world.min(), own.min())
    vel, acc = np.asarray(limits.velocity), np.asarray(limits.acceleration)
    within = np.array([judge.within_limits(q[:, k]).all() for k in range(n)])
    slow = np.all(np.abs(v) <= vel * (1 + 1e-5) + 1e-9, axis=(0, 2)) & np.all(
        np.abs(a) <= acc * (1 + 1e-5) + 1e-9, axis=(0, 2)
    )
    end = np.asarray(traj.at(traj.duration), np.float64)
    if kind == "goal_q":
        goal = np.array([np.r_[p["goal_q"], FINGER] for p in problems])
        on_goal = np.max(np.abs(end - goal)[:, judge.arm], axis=-1) <= 1e-6
    else:
        pos, rot = judge.pose_errors(end, np.stack([target_of(p) for p in problems]))
        on_goal = (pos <= 1e-5) & (rot <= 1e-4)
    return {"coal": coal, "limits": within & slow, "goal": on_goal}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=("capsules", "hulls"), default="hulls", help="robot model (hulls)")
    parser.add_argument("--quick", action="store_true", help=f"3 problems of each of {', '.join(QUICK_SCENES)}")
    parser.add_argument("--all", action="store_true", help="all 700 problems (7 scenes x 100)")
    parser.add_argument("--per-scene", type=int, metavar="N", help="N problems per scene, spread evenly")
    parser.add_argument("--scenes", help="comma-separated scenes")
    parser.add_argument("--goals", default="goal_q,goal_pose", help="goal_q, goal_pose or both (default)")
    parser.add_argument("--knots", type=int, default=12)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--iters", type=int, default=30)
    parser.add_argument("--samples", type=int, default=200, help="coal samples per motion (default 200)")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    parser.add_argument("--write", action="store_true", help="write experiments/results/<machine>-traj.md")
    args = parser.parse_args(argv)
    if not (args.quick or args.all or args.per_scene or args.scenes):
        parser.error("choose --quick, --all, --per-scene N or --scenes (all 700 take long on a CPU)")
    command = "python experiments/bench_traj.py " + " ".join(argv if argv is not None else sys.argv[1:])
    busy = busy_note()
    dtype = jnp.dtype(args.dtype)
    doc = json.loads(MBM.read_text())
    names = (
        list(QUICK_SCENES)
        if args.quick and not args.scenes
        else (list(doc["problems"]) if args.scenes is None else args.scenes.split(","))
    )
    per_scene = 3 if args.quick and args.per_scene is None else args.per_scene
    scenes = {s: subset(doc["problems"][s], per_scene) for s in names}
    kinds = args.goals.split(",")

    t0 = time.perf_counter()
    robot, urdf, srdf = panda()
    geom = C.load(urdf, robot, meshes=args.model, srdf=srdf, dtype=dtype)
    judge = Judge(urdf, robot, geom)
    limits = dk.traj.Limits(velocity=velocity_limits(urdf, robot), acceleration=ACCELERATION[: robot.dof])
    n = sum(len(p) for p in scenes.values())
    print(f"# {n} problems x {kinds}, model {args.model!r}, {args.dtype}; pose judged by {judge.fk_name}", flush=True)
    rows, firsts, totals = [], {}, {}
    for kind in kinds:
        first_scene = next(iter(scenes.values()))
        _, firsts[kind] = plan(robot, geom, first_scene, kind, limits, args, dtype)
        print(f"# {kind}: first call ({len(first_scene)} problems, compile included) {firsts[kind]:.1f} s", flush=True)
        total = {"problems": 0, "solvable": 0, "success": 0, "solved": 0, "contact": 0, "off limits": 0,
                 "off goal": 0, "time": [], "length": [], "warm": 0.0}  # fmt: skip
        for scene, problems in scenes.items():
            traj, warm = plan(robot, geom, problems, kind, limits, args, dtype)
            j = judge_motions(judge, traj, problems, kind, limits, args.samples)
            goal_q = np.stack([np.r_[p["goal_q"], FINGER] for p in problems])
            g_world, g_own = judge.clearance(goal_q, [judge.coal.obstacles(p) for p in problems])
            ends = np.stack([np.r_[p["start"], FINGER] for p in problems] + list(goal_q))
            within = judge.within_limits(ends).reshape(2, -1).all(axis=0)
            solvable = (np.minimum(g_world, g_own) >= MARGIN) & within
            success = np.asarray(traj.success)
            solved = success & (j["coal"] >= 0) & j["limits"] & j["goal"]
            c = {
                "problems": len(problems),
                "solvable": int(solvable.sum()),
                "success": int(success.sum()),
                "solved": int(solved.sum()),
                "contact": int((success & (j["coal"] < 0)).sum()),
                "off limits": int((success & ~j["limits"]).sum()),
                "off goal": int((success & ~j["goal"]).sum()),
                "time": list(np.asarray(traj.duration)[solved]),
                "length": list(np.asarray(traj.path_length)[solved]),
                "warm": warm,
            }
            for key, value in c.items():
                total[key] = total[key] + value
            rows.append(_row(scene, kind, c))
            why = [
                f"#{p['index']}: goal {bool(g)} limits {bool(lo)} clear {bool(cl)} ({1e3 * float(cv):.1f} mm certified)"
                for p, ok, g, lo, cl, cv in zip(
                    problems, success, np.asarray(traj.goal_ok), np.asarray(traj.limits_ok), np.asarray(traj.clear),
                    np.asarray(traj.clearance), strict=True,
                )
                if not ok
            ]  # fmt: skip
            print(f"# {scene} {kind}: {' | '.join(rows[-1][2:])}" + (f"; failed {', '.join(why)}" if why else ""))
        rows.append(_row("**all**", kind, total))
        totals[kind] = total
    parts = [
        f"# Collision-free trajectories on MotionBenchMaker's Panda problems (issue 58)\n\n`{command.strip()}`, "
        f"{datetime.date.today()}, {time.perf_counter() - t0:.0f} s. {machine_line()}. diffkin {revision()}. "
        f"Robot model **{args.model}**; {args.dtype}; knots {args.knots}, seeds {args.seeds}, iterations "
        f"{args.iters}; margin {1e3 * MARGIN:g} mm; velocity limits from the URDF, accelerations Franka's; judge: "
        f"coal on the URDF's meshes at {args.samples} samples per motion plus its knots, limits and derivatives "
        f"sampled there, the goal by {judge.fk_name}.",
        busy,
        "First call (the first scene's problems, compile included): "
        + ", ".join(f"{k} **{v:.1f} s**" for k, v in firsts.items())
        + ". warm: each scene's call once, per problem.\n",
        table(HEADER, rows),
    ]
    publish(parts, "traj" if args.write else None)
    return 0


def _row(scene: str, kind: str, c: dict) -> list[str]:
    mean = lambda x: f"{np.mean(x):.2f}" if len(x) else "-"  # noqa: E731
    return [
        scene,
        kind,
        str(c["problems"]),
        str(c["solvable"]),
        str(c["success"]),
        str(c["solved"]),
        str(c["contact"]),
        str(c["off limits"]),
        str(c["off goal"]),
        mean(c["time"]),
        mean(c["length"]),
        f"{c['warm'] / max(c['problems'], 1):.3f}",
    ]


if __name__ == "__main__":
    sys.exit(main())
