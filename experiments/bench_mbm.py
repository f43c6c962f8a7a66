"""Collision-aware IK on the 700 MotionBenchMaker Panda problems, judged on the real meshes (issue 54).

Per problem (``../shared/data/mbm/panda_mbm_problems.json``, read as ``SOURCES.md`` there says): the
``panda_hand`` goal pose, the problem's own obstacles (boxes and cylinders, exact:
:func:`bench_geometry.world_of`), example-robot-data's Panda and SRDF with the fingers locked at MBM's
0.065 m, ``dk.ik.solve(robot, {"panda_hand": T}, avoid=dk.ik.Avoid(geom, world, margin=0.005),
locked=...)`` with the robot model of ``dk.collision.load(..., meshes=--model)`` (``hulls``, the
tight model, by default; or ``capsules``), the solver's defaults otherwise.

Every returned configuration is judged independently, in float64:

- **pose**: Pinocchio's forward kinematics of the URDF (``dk.fk`` where Pinocchio is not installed,
  said in the output) against the goal pose, at 1e-5 m / 1e-4 rad and at cuRobo's 5 mm / 0.05 rad;
- **limits**: the arm's joints within the URDF's limits (1e-6 rad slack);
- **clearance on the real meshes**: coal's signed distances of the URDF's collision meshes (BVH) and
  finger boxes to the exact obstacles and over the self pairs the SRDF leaves enabled
  (:class:`bench_geometry.Coal`).

A problem is **solvable** when MBM's own ``goal_q`` clears its obstacles and the enabled self pairs
on the real meshes by the margin (coal): a witness that a solution exists for a model as tight as
the meshes. **Solved** = diffkin's ``success`` confirmed by the judge (pose within 1e-5 m / 1e-4 rad,
limits, coal clearance >= 0); the 5 mm / 0.05 rad column judges every returned configuration
(successful or not) the same way at cuRobo's tolerance. Successes in contact (coal < 0) must be 0;
successes below the margin by coal and successes off the pose are counted too.

Each problem has its own obstacles: a scene is solved in one call with a world per target (a
``World`` with problem axes; ``--loop``: problem by problem in a Python loop, to compare), every
world padded to the same counts (11 boxes, 10 cylinders, far-away dummies) so that one compilation
serves every scene. Times: the first call (compile included) apart, then each scene once, warm.

A second part reproduces cuRobo's collision-free IK benchmark (its ``benchmark/ik_benchmark.py`` at
NVlabs/curobo a35a708: the world ``collision_table.yml``, a 4 x 4 x 0.2 m slab under the robot;
targets the ``panda_hand`` poses of random in-limit configurations that are collision-free, batch
100, five draws, its fingers locked at 0.04 m): ``dk.ik.solve`` with ``avoid`` against that world and
without ``avoid``, first call and warm time per batch, judged as above (the sampled configurations
clear the slab and the self pairs by the margin on the real meshes, by coal).

    python experiments/bench_mbm.py                        # all 700, hulls, and cuRobo's setting
    python experiments/bench_mbm.py --quick                # 10 problems per scene (stratified)
    python experiments/bench_mbm.py --model capsules --scenes box,cage --per-scene 2 --no-curobo
    python experiments/bench_mbm.py --write                # results/<machine>-mbm.md
    python experiments/bench_mbm.py --scenes cage --per-scene 20 --no-curobo --loop --key 3   # a loop, other seeds
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
import yaml
from _bench import busy_note, machine_line, publish, table
from bench_geometry import FINGER, MARGIN, MBM, PAD, Coal, configuration, panda, pose, revision, world_of
from bench_ik_collision import RealGeometry

import diffkin as dk

try:
    from tqdm import tqdm
except ImportError:  # the "progress" extra: without it, a line per scene
    tqdm = None

C = dk.collision
EE = "panda_hand"
MODELS = ("hulls", "capsules")
TIGHT, LOOSE = (1e-5, 1e-4), (5e-3, 0.05)  # diffkin's default tolerances; cuRobo's
LIMIT_SLACK = 1e-6
CUROBO_WORLD = MBM.parent / "curobo_collision_table.yml"
CUROBO_FINGER = 0.04  # cuRobo's franka.yml: lock_joints panda_finger_joint1/2 at 0.04
CUROBO_BATCH = 100
# cuRobo V2's published Franka row (docs/reference/benchmarks.rst, "Latest Inverse Kinematics Results", GPU not
# named; the motion-generation table on the same page is on an RTX 6000 Ada): batch 100, 5 mm / 0.05 rad.
CUROBO_PUBLISHED = {"IK": (2.60138, 100.0), "collision-free IK": (2.72574, 100.0)}  # (ms per batch, success %)


# ------------------------------------------------------------------------------------------------- the solver


def solve_problems(
    robot,
    geom,
    targets: np.ndarray,
    worlds: list,
    locked: dict,
    dtype,
    desc: str = "solve",
    loop: bool = False,
    key: int = 0,
) -> dk.ik.IKResult:
    """``(N,)`` results of the targets ``(N, 4, 4)``, target ``k`` among ``worlds[k]`` (same counts): one call
    with a world per target (``World`` of problem axes ``(N,)``), or, with ``loop``, a Python loop of one
    problem per call (``dk.ik.solve`` compiles once for the padded counts); the solver's seeds from
    ``jax.random.key(key)`` in every call."""
    if not loop:
        world = jax.tree.map(lambda *x: jnp.stack(x), *worlds)  # (N, n_kind, ...): a world per target
        avoid = dk.ik.Avoid(geom, world, margin=MARGIN)
        T = jnp.asarray(targets, dtype)
        return jax.block_until_ready(dk.ik.solve(robot, {EE: T}, avoid=avoid, locked=locked, key=jax.random.key(key)))
    out = []
    for T, world in zip(progress(targets, desc), worlds, strict=True):
        avoid = dk.ik.Avoid(geom, world, margin=MARGIN)
        target = jnp.asarray(T[None], dtype)
        out.append(dk.ik.solve(robot, {EE: target}, avoid=avoid, locked=locked, key=jax.random.key(key)))
    return jax.block_until_ready(jax.tree.map(lambda *x: jnp.concatenate(x), *out))


def progress(items, desc: str):
    """``items`` with a tqdm bar (stderr) where tqdm is installed."""
    return items if tqdm is None else tqdm(items, desc=desc, leave=False, file=sys.stderr, mininterval=1.0)


# ------------------------------------------------------------------------------------------------- the judge


class Judge:
    """The independent judge: pose errors by Pinocchio (``dk.fk`` without it), joint limits, and coal's
    clearance of the real meshes to the obstacles and over the SRDF's enabled self pairs."""

    def __init__(self, urdf: str, robot: dk.Robot, geom: C.Geometry):
        self.robot = robot
        self.coal = Coal(urdf, robot, geom)
        real = RealGeometry(urdf, robot, geom, None)  # as Coal's: its shapes in Coal's order, the SRDF's pairs
        names = list(real.shapes)
        self.pairs = [(names.index(a), names.index(b)) for a, b in real.pairs]
        self.lower, self.upper = np.asarray(robot.lower), np.asarray(robot.upper)
        self.arm = np.array([name.startswith("panda_joint") for name in robot.joint_names])
        try:
            import pinocchio as pin
        except ImportError:
            self.pin, self.fk_name = None, "dk.fk (Pinocchio not installed)"
            return
        self.pin, self.fk_name = pin, f"Pinocchio {pin.__version__}"
        self.model = pin.buildModelFromUrdf(urdf)
        self.data = self.model.createData()
        self.frame = self.model.getFrameId(EE)
        self.idx_q = [self.model.joints[self.model.getJointId(name)].idx_q for name in robot.joint_names]

    def pose_errors(self, q: np.ndarray, T_targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(N,)`` position (m) and rotation (rad) errors of ``panda_hand`` at ``q (N, dof)``."""
        if self.pin is None:
            T = np.asarray(dk.fk(self.robot, jnp.asarray(q, jnp.float64), EE))
        else:
            pin, T = self.pin, np.empty((len(q), 4, 4))
            for k, qk in enumerate(q):
                q_pin = pin.neutral(self.model)
                q_pin[self.idx_q] = qk
                pin.framesForwardKinematics(self.model, self.data, q_pin)
                T[k] = self.data.oMf[self.frame].homogeneous
        pos = np.linalg.norm(T[:, :3, 3] - T_targets[:, :3, 3], axis=-1)
        rot = np.asarray(dk.se3.rotation_angle(np.swapaxes(T_targets[:, :3, :3], -1, -2) @ T[:, :3, :3]))
        return pos, rot

    def within_limits(self, q: np.ndarray) -> np.ndarray:
        """``(N,)`` the arm's joints within the limits (the locked fingers are held beyond theirs on purpose)."""
        ok = (q >= self.lower - LIMIT_SLACK) & (q <= self.upper + LIMIT_SLACK)
        return np.all(ok[:, self.arm], axis=-1)

    def clearance(self, q: np.ndarray, obstacles: list[list]) -> tuple[np.ndarray, np.ndarray]:
        """``(N,)`` smallest coal distances (m) of the real meshes at ``q (N, dof)``: to ``obstacles[k]`` (each
        :meth:`Coal.obstacles`; ``inf`` for none) and over the self pairs."""
        coal, real = self.coal.coal, self.coal
        world, own = np.full(len(q), np.inf), np.empty(len(q))
        for k, (placed, o) in enumerate(zip(real.placed(q), obstacles, strict=True)):
            if o:
                world[k] = real.distances(placed, o).min()
            own[k] = min(
                coal.distance(*placed[i], *placed[j], real.request, coal.DistanceResult()) for i, j in self.pairs
            )
        return world, own

    def judged(self, q, T_targets: np.ndarray, obstacles: list[list]) -> dict[str, np.ndarray]:
        """Per configuration ``q (N, dof)``: pose errors against ``T_targets (N, 4, 4)``, limits, and the coal
        clearance (m, the smaller of world and self) among ``obstacles[k]``."""
        q = np.asarray(q, np.float64)
        pos, rot = self.pose_errors(q, T_targets)
        world, own = self.clearance(q, obstacles)
        return {"pos": pos, "rot": rot, "limits": self.within_limits(q), "coal": np.minimum(world, own)}


def on_pose(j: dict, tol: tuple[float, float]) -> np.ndarray:
    return (j["pos"] <= tol[0]) & (j["rot"] <= tol[1])


def confirmed(j: dict, tol: tuple[float, float]) -> np.ndarray:
    """On the pose within ``tol``, within the limits and not in contact on the real meshes."""
    return on_pose(j, tol) & j["limits"] & (j["coal"] >= 0)


# ------------------------------------------------------------------------------------------------- MBM


def target_of(problem: dict) -> np.ndarray:
    g = problem["goal_pose"]
    assert g["frame"] == EE
    return pose(g["position"], g["quaternion_wxyz"])


def subset(problems: list, per_scene: int | None) -> list:
    """``per_scene`` problems spread evenly over the scene's list (all of them for ``None``)."""
    if per_scene is None or per_scene >= len(problems):
        return problems
    return [problems[k] for k in np.linspace(0, len(problems) - 1, per_scene).round().astype(int)]


def mbm(robot, geom, judge: Judge, scenes: dict, dtype, loop: bool, key: int = 0) -> tuple[list, list, float]:
    """Per scene: the solves and their judgement; returns the table's rows, the misses and the first call (s)."""
    locked = {"panda_finger_joint1": FINGER}
    goal_clearance = jax.jit(lambda q, w: C.clearance(robot, geom, q, w))  # diffkin's model at goal_q, float64
    # the first call, compile included: one problem (the loop's call), or the first scene's batch
    first_problems = next(iter(scenes.values()))[:1] if loop else next(iter(scenes.values()))
    start = time.perf_counter()
    solve_problems(
        robot,
        geom,
        np.stack([target_of(p) for p in first_problems]),
        [world_of(p, PAD) for p in first_problems],
        locked,
        dtype,
        "first call",
        loop,
        key,
    )
    first = time.perf_counter() - start
    print(f"# first call ({len(first_problems)} problem(s), compile included): {first:.1f} s", flush=True)
    rows, misses, totals = [], [], {}
    for scene, problems in scenes.items():
        T = np.stack([target_of(p) for p in problems])
        worlds = [world_of(p, PAD) for p in problems]
        start = time.perf_counter()
        res = solve_problems(robot, geom, T, worlds, locked, dtype, scene, loop, key)
        warm = time.perf_counter() - start
        obstacles = [judge.coal.obstacles(p) for p in problems]
        goal_q = np.stack([configuration(p["goal_q"]) for p in problems])
        goal_coal = np.minimum(*judge.clearance(goal_q, obstacles))
        goal_model = np.array(
            [float(goal_clearance(jnp.asarray(q[None]), w)[0]) for q, w in zip(goal_q, worlds, strict=True)]
        )
        j = judge.judged(res.q, T, obstacles)
        success = np.asarray(res.success)
        solvable = goal_coal >= MARGIN
        solved = success & confirmed(j, TIGHT)
        counts = {
            "problems": len(problems),
            "solvable": int(solvable.sum()),
            "goal clear (model)": int((goal_model >= MARGIN).sum()),
            "success": int(success.sum()),
            "solved": int(solved.sum()),
            "solved of solvable": int((solved & solvable).sum()),
            "loose": int(confirmed(j, LOOSE).sum()),
            "contact": int((success & (j["coal"] < 0)).sum()),
            "below margin": int((success & (j["coal"] >= 0) & (j["coal"] < MARGIN)).sum()),
            "off pose": int((success & ~(on_pose(j, TIGHT) & j["limits"])).sum()),
            "warm": warm,
        }
        for name, value in counts.items():  # (not `key`: the solver's PRNG key of every scene)
            totals[name] = totals.get(name, 0) + value
        rows.append(_row(scene, counts))
        print(f"# {scene}: {' | '.join(rows[-1])}", flush=True)
        res_clearance = np.asarray(res.clearance, np.float64)
        for k in np.flatnonzero(solvable & ~solved):
            misses.append(
                (scene, problems[k]["index"], bool(success[k]), j["pos"][k], j["rot"][k], bool(j["limits"][k]))
                + (res_clearance[k], j["coal"][k], goal_model[k], goal_coal[k])
            )
    rows.append(_row("**all**", totals))
    return rows, misses, first


def _row(scene: str, c: dict) -> list[str]:
    pct = f"{100 * c['solved of solvable'] / c['solvable']:.1f} %" if c["solvable"] else "-"
    return [
        scene,
        str(c["problems"]),
        str(c["solvable"]),
        str(c["goal clear (model)"]),
        str(c["success"]),
        f"{c['solved of solvable']} ({pct})",
        str(c["solved"]),
        str(c["loose"]),
        str(c["contact"]),
        str(c["below margin"]),
        str(c["off pose"]),
        f"{c['warm']:.2f}",
        f"{1e3 * c['warm'] / c['problems']:.0f}",
    ]


MBM_HEADER = [
    "scene",
    "problems",
    "solvable (coal at goal_q)",
    "goal_q clear (model)",
    "diffkin success",
    "solved of solvable",
    "solved (all)",
    "5 mm / 0.05 rad",
    "successes in contact (coal)",
    "successes below margin (coal)",
    "successes off pose / limits",
    "warm (s)",
    "ms / problem",
]


# ------------------------------------------------------------------------------------------------- cuRobo's setting


def curobo_world() -> tuple[C.World, list[dict]]:
    """cuRobo's ``collision_table.yml``: its cuboids as exact boxes (diffkin) and as MBM-style box records (coal)."""
    doc = yaml.safe_load(CUROBO_WORLD.read_text())
    assert set(doc) == {"cuboid"}, f"{CUROBO_WORLD}: only cuboids expected, got {sorted(doc)}"
    boxes = [  # cuRobo's pose: [x, y, z, qw, qx, qy, qz]
        {"half_extents": [d / 2 for d in c["dims"]], "position": c["pose"][:3], "quaternion_wxyz": c["pose"][3:]}
        for c in doc["cuboid"].values()
    ]
    poses = np.stack([pose(b["position"], b["quaternion_wxyz"]) for b in boxes])
    world = C.World(C.Box(jnp.asarray(poses), jnp.asarray([b["half_extents"] for b in boxes], jnp.float64)))
    return world, boxes


def curobo_targets(robot, judge: Judge, obstacles: list, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """``n`` in-limit configurations (fingers at cuRobo's 0.04 m) whose real meshes clear the slab and the self
    pairs by the margin (coal), and their ``panda_hand`` poses."""
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    found: list[np.ndarray] = []
    while sum(len(x) for x in found) < n:
        q = rng.uniform(lo, hi, (n, robot.dof))
        q[:, ~judge.arm] = CUROBO_FINGER
        world, own = judge.clearance(q, [obstacles] * n)
        found.append(q[np.minimum(world, own) >= MARGIN])
    q = np.concatenate(found)[:n]
    return q, np.asarray(dk.fk(robot, jnp.asarray(q), EE))


def curobo(robot, geom, judge: Judge, draws: int, dtype) -> list[list[str]]:
    world, boxes = curobo_world()
    obstacles = judge.coal.obstacles({"obstacles": {"box": boxes, "cylinder": []}})
    _, T = curobo_targets(robot, judge, obstacles, draws * CUROBO_BATCH, np.random.default_rng(0))
    batches = T.reshape(draws, CUROBO_BATCH, 4, 4)
    locked = {"panda_finger_joint1": CUROBO_FINGER}
    avoid = dk.ik.Avoid(geom, world, margin=MARGIN)
    solvers = {
        "collision-free IK": lambda T: dk.ik.solve(robot, {EE: T}, avoid=avoid, locked=locked),
        "IK": lambda T: dk.ik.solve(robot, {EE: T}, locked=locked),
    }
    rows = []
    for name, solve in solvers.items():
        start = time.perf_counter()
        jax.block_until_ready(solve(jnp.asarray(batches[0], dtype)))
        first = time.perf_counter() - start
        times, results = [], []
        for batch in batches:  # as cuRobo: each draw timed once, after the warm-up
            start = time.perf_counter()
            results.append(jax.block_until_ready(solve(jnp.asarray(batch, dtype))))
            times.append(time.perf_counter() - start)
        q = np.concatenate([np.asarray(r.q, np.float64) for r in results])
        success = np.concatenate([np.asarray(r.success) for r in results])
        j = judge.judged(q, T, [obstacles] * len(q))
        ms, pct = CUROBO_PUBLISHED[name]
        rows.append(
            [
                f"diffkin {name} ({'avoid' if 'free' in name else 'no avoid'})",
                f"{first:.1f}",
                f"{1e3 * np.median(times):.1f}",
                f"{100 * np.mean(success & confirmed(j, TIGHT)):.1f}",
                f"{100 * np.mean(confirmed(j, LOOSE)):.1f}",
                f"{int((j['coal'] < 0).sum())}",
                f"{int((success & (j['coal'] < 0)).sum())}",
                f"cuRobo V2: {ms:.2f} ms, {pct:g} %",
            ]
        )
        print(f"# cuRobo's setting: {' | '.join(rows[-1])}", flush=True)
    return rows


CUROBO_HEADER = [
    "solver",
    "first call (s)",
    "warm per batch (ms, median)",
    "solved 1e-5 m / 1e-4 rad (%)",
    "5 mm / 0.05 rad (%)",
    "in contact (coal)",
    "successes in contact",
    "published (GPU)",
]


# ------------------------------------------------------------------------------------------------- main


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=MODELS, default="hulls", help="the robot's collision model (default hulls)")
    parser.add_argument("--quick", action="store_true", help="10 problems per scene, spread evenly")
    parser.add_argument("--per-scene", type=int, metavar="N", help="N problems per scene, spread evenly")
    parser.add_argument("--scenes", help="comma-separated scenes (default: all 7)")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32", help="the solver's dtype")
    parser.add_argument("--curobo-draws", type=int, default=5, help="cuRobo's setting: batches of 100 (default 5)")
    parser.add_argument("--no-curobo", action="store_true", help="skip cuRobo's setting")
    parser.add_argument("--loop", action="store_true", help="one problem per call (default: a scene per call)")
    parser.add_argument(
        "--key", type=int, default=0, help="the solver's PRNG key, jax.random.key(KEY), in every call (default 0)"
    )
    parser.add_argument("--write", action="store_true", help="write experiments/results/<machine>-mbm.md")
    args = parser.parse_args(argv)
    command = "python experiments/bench_mbm.py " + " ".join(argv if argv is not None else sys.argv[1:])
    busy = busy_note()
    dtype = jnp.dtype(args.dtype)
    per_scene = 10 if args.quick and args.per_scene is None else args.per_scene
    doc = json.loads(MBM.read_text())
    names = list(doc["problems"]) if args.scenes is None else args.scenes.split(",")
    unknown = sorted(set(names) - set(doc["problems"]))
    if unknown:
        parser.error(f"--scenes: unknown {unknown}; the scenes are {list(doc['problems'])}")
    scenes = {s: subset(doc["problems"][s], per_scene) for s in names}

    t0 = time.perf_counter()
    robot, urdf, srdf = panda()
    geom = C.load(urdf, robot, meshes=args.model, srdf=srdf)
    judge = Judge(urdf, robot, geom)
    n = sum(len(p) for p in scenes.values())
    print(f"# {n} MBM problems, robot model {args.model!r}, {args.dtype}; pose judged by {judge.fk_name}", flush=True)
    rows, misses, first = mbm(robot, geom, judge, scenes, dtype, args.loop, args.key)
    curobo_rows = None if args.no_curobo else curobo(robot, geom, judge, args.curobo_draws, dtype)

    parts = [
        f"# Collision-aware IK on MotionBenchMaker's Panda problems (issue 54)\n\n`{command.strip()}`, "
        f"{datetime.date.today()}, {time.perf_counter() - t0:.0f} s. {machine_line()}. diffkin {revision()}. "
        f"Robot model: **{args.model}** (`dk.collision.load(..., meshes={args.model!r})`, example-robot-data's "
        f"`panda.urdf` + `panda.srdf`); solver dtype {args.dtype}; judge: pose by {judge.fk_name}, clearance by "
        "coal on the URDF's collision meshes.",
        busy,
        f"## MotionBenchMaker: {n} problems\n\n`dk.ik.solve(robot, {{'{EE}': T}}, avoid=dk.ik.Avoid(geom, world, "
        f"margin={MARGIN}), locked={{'panda_finger_joint1': {FINGER}}})`, the solver's defaults otherwise "
        f"(1e-5 m / 1e-4 rad); obstacles exact (boxes, cylinders), each problem its own (every world padded to "
        f"{PAD[0]} boxes and {PAD[1]} cylinders, so one compilation serves all). "
        + (
            "**Batch 1, one problem per call** in a Python loop. First call (one problem, compile included): "
            if args.loop
            else "**A scene per call**: its problems batched, each with its own world (`World` of problem axes). "
            "First call (the first scene, compile included): "
        )
        + f"**{first:.1f} s**.\n\n"
        f"solvable: MBM's `goal_q` clears its obstacles and the self pairs by {1e3 * MARGIN:g} mm on the real "
        f"meshes (coal); goal_q clear (model): by {1e3 * MARGIN:g} mm in diffkin's {args.model} model. solved: "
        "diffkin's success confirmed (pose within 1e-5 m / 1e-4 rad, arm within limits, coal clearance >= 0). "
        "5 mm / 0.05 rad: every returned configuration within cuRobo's tolerance, limits, coal >= 0. Successes in "
        f"contact: coal < 0; below margin: 0 <= coal < {1e3 * MARGIN:g} mm; off pose / limits: a success the "
        "judge puts beyond 1e-5 m / 1e-4 rad or the limits. warm: the scene's call(s), once.\n",
        table(MBM_HEADER, rows),
    ]
    if misses:
        parts.append(
            "Solvable but not solved (scene #index: diffkin's success, pose error, limits, clearance at the "
            "returned q by diffkin's model and by coal, goal_q's clearance by the model and by coal):\n\n"
            + "\n".join(
                f"- {s} #{i}: success {ok}, {1e3 * pe:.3g} mm / {re:.2g} rad, limits {lim}, clearance "
                f"{1e3 * rc:.2f} mm (model) / {1e3 * cc:.2f} mm (coal); goal_q {1e3 * gm:.2f} / {1e3 * gc:.2f} mm"
                for s, i, ok, pe, re, lim, rc, cc, gm, gc in misses
            )
        )
    if curobo_rows is not None:
        parts.append(
            f"## cuRobo's collision-free IK setting\n\nWorld `collision_table.yml` (a 4 x 4 x 0.2 m slab, top 0.1 m "
            f"below the base); {args.curobo_draws} draw(s) of {CUROBO_BATCH} targets, the `{EE}` poses of uniform "
            f"in-limit configurations clear of the slab and the self pairs by {1e3 * MARGIN:g} mm on the real meshes "
            f"(coal); batch {CUROBO_BATCH}, fingers locked at {CUROBO_FINGER} m (cuRobo's); margin {1e3 * MARGIN:g} "
            "mm. First call: the first batch, compile included (in this process, after the MBM part); warm: each "
            "draw timed once, median. Published: cuRobo V2 `docs/reference/benchmarks.rst` (Franka, batch 100, "
            "5 mm / 0.05 rad).\n\n" + table(CUROBO_HEADER, curobo_rows)
        )
    publish(parts, "mbm" if args.write else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
