"""The Panda's collision geometry, as tight as its meshes? Hulls and capsules against coal on the real
meshes, on the 700 MotionBenchMaker problems (issue 53's "Measure").

Three parts, one run, the two mesh models of ``dk.collision.load`` side by side (``meshes="hulls"``:
each collision mesh its convex hull; ``meshes="capsules"``: one capsule per mesh; the finger boxes
exact in both):

1. **Geometry**: shapes per kind, the worst and the median overshoot of the fitted (mesh) shapes
   (:attr:`Geometry.overshoot`), and the time of ``dk.collision.load`` in a fresh process, cold
   (``DIFFKIN_FIT_CACHE`` a new empty folder) and cached (a second process on the same folder),
   median of 3 processes each (JAX started before the clock, so that the time is the load's own).
2. **MBM goals**: at each problem's ``goal_q`` (``../shared/data/mbm/panda_mbm_problems.json``,
   fingers locked at MBM's 0.065 m, beyond the URDF's 0.04 m limit: SOURCES.md), the robot's
   smallest signed distance to its problem's obstacles (boxes exact, cylinders exact
   ``dk.collision.Cylinder``), float64, per model and per coal on the URDF's collision meshes (BVH
   models) and finger boxes against exact boxes and ``coal.Cylinder``. Per scene: goals clear by
   5 mm per each, and coal's distance minus the model's (a model that contains the meshes is never
   farther than coal: a model distance above coal's by more than 1e-6 m is a violation).
3. **Speed**: ``world_distances`` of the Panda against one problem's obstacles (``bookshelf_thin``
   #1: 11 boxes, 10 cylinders) at 1 and 1,000 random configurations, float32 and float64, jitted:
   compile apart, then the median of warm calls; against a Python loop of ``coal.distance`` over the
   same shape-obstacle pairs on the real meshes (shapes placed beforehand: coal's time is the
   distances alone), timed on some configurations and reported per configuration times the batch.

Every world is padded to 11 boxes and 10 cylinders (far-away small shapes) so that one compiled
function per (model, dtype, batch) serves every problem: compiling ``world_distances`` takes 20-110 s
per model on a 2-core machine, one per scene would not fit the run.

    python experiments/bench_geometry.py --quick               # 10 problems per scene, 1 load process each
    python experiments/bench_geometry.py --write               # all 700; results/<machine>-geometry.md
    python experiments/bench_geometry.py --batches 1 --write   # without batch 1,000 (hulls: ~1 min a call)
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import importlib.metadata
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _bench import busy_note, machine_line, median_seconds, publish, table  # noqa: E402
from bench_collision import panda  # noqa: E402

import diffkin as dk  # noqa: E402

C = dk.collision
MODELS = ("hulls", "capsules")
FINGER = 0.065  # MBM's finger opening (VAMP's README, "6.5cm"; its request files: 0.065 per finger joint)
MARGIN = 0.005
TOL = 1e-6  # a model distance above coal's by more than this is a violation
MBM = Path(__file__).resolve().parents[2] / "shared" / "data" / "mbm" / "panda_mbm_problems.json"
SPEED_PROBLEM = ("bookshelf_thin", 0)
PAD = (11, 10)  # the most boxes and cylinders of a problem (bookshelf_thin)
ROOT = Path(__file__).resolve().parents[1]


def rot(q) -> np.ndarray:
    """``[w, x, y, z]`` -> 3x3 rotation."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose(position, quaternion) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rot(quaternion), position
    return T


def world_of(problem: dict, pad: tuple[int, int] = PAD) -> C.World:
    """The problem's obstacles, exact: boxes and cylinders (float64), padded to ``pad`` (boxes, cylinders) with
    small shapes 100 m away, so that every problem's world has the same counts (one compiled function)."""
    o = problem["obstacles"]
    assert not o["sphere"], "no spheres in MBM's Panda set"
    far = pose([100.0, 100.0, 100.0], [1.0, 0.0, 0.0, 0.0])
    boxes = [(pose(b["position"], b["quaternion_wxyz"]), b["half_extents"]) for b in o["box"]]
    boxes += [(far, [0.01] * 3)] * (pad[0] - len(boxes))
    cylinders = [(pose(c["position"], c["quaternion_wxyz"]), c["radius"], c["length"] / 2) for c in o["cylinder"]]
    cylinders += [(far, 0.01, 0.01)] * (pad[1] - len(cylinders))
    return C.World(
        C.Box(jnp.asarray(np.stack([T for T, _ in boxes])), jnp.asarray([h for _, h in boxes], jnp.float64)),
        C.Cylinder(
            jnp.asarray(np.stack([T for T, _, _ in cylinders])),
            jnp.asarray([r for _, r, _ in cylinders], jnp.float64),
            jnp.asarray([h for _, _, h in cylinders], jnp.float64),
        ),
    )


class Distances:
    """``world_distances`` of each model, jitted with the world an argument, compiled once per (model, dtype,
    batch) and kept (the compile time with it): the goals and the speed part share the float64 batch-1 one."""

    def __init__(self, robot, geoms: dict):
        self.robot, self.geoms, self.compiled, self.compile_s = robot, geoms, {}, {}

    def __call__(self, model: str, q: np.ndarray, world: C.World, dtype=jnp.float64) -> np.ndarray:
        """``(N, S, W)`` float64 for ``q (N, dof)``."""
        q = jnp.asarray(q, dtype)
        world = jax.tree.map(lambda x: x.astype(dtype), world)
        key = (model, np.dtype(dtype).name, q.shape[0])
        if key not in self.compiled:
            r, g = (jax.tree.map(lambda x: x.astype(dtype), x) for x in (self.robot, self.geoms[model]))
            start = time.perf_counter()
            self.compiled[key] = jax.jit(lambda q, w: C.world_distances(r, g, q, w)).lower(q, world).compile()
            self.compile_s[key] = time.perf_counter() - start
            print(f"# compiled {key} in {self.compile_s[key]:.1f} s", flush=True)
        return self.compiled[key](q, world)


class Coal:
    """The real geometry (``RealGeometry`` of ``bench_ik_collision``: the URDF's meshes as BVH models, its
    finger boxes exact) and signed distances to exact obstacles by ``coal.distance``."""

    def __init__(self, urdf: str, robot: dk.Robot, geom: C.Geometry):
        import coal
        from bench_ik_collision import RealGeometry

        self.coal, self.robot = coal, robot
        self.shapes = list(RealGeometry(urdf, robot, geom, None).shapes.values())  # (shape, T_frame_shape, frame)
        self.request = coal.DistanceRequest()
        self._link_poses = jax.jit(lambda q: dk.link_poses(robot, q))

    def obstacles(self, problem: dict) -> list:
        coal, o = self.coal, problem["obstacles"]
        out = [
            (coal.Box(*(2 * np.asarray(b["half_extents"]))), pose(b["position"], b["quaternion_wxyz"]))
            for b in o["box"]
        ]
        out += [
            (coal.Cylinder(c["radius"], c["length"]), pose(c["position"], c["quaternion_wxyz"])) for c in o["cylinder"]
        ]
        return [(shape, self._tf(T)) for shape, T in out]

    def _tf(self, T):
        return self.coal.Transform3s(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]))

    def placed(self, q: np.ndarray) -> list[list]:
        """Per configuration, each robot shape with its placement (``Transform3s``)."""
        link = np.asarray(self._link_poses(jnp.asarray(q, jnp.float64)))
        return [[(shape, self._tf(link[k, f] @ T)) for shape, T, f in self.shapes] for k in range(len(q))]

    def distances(self, placed: list, obstacles: list) -> np.ndarray:
        """``(S, W)`` distances of placed robot shapes (one configuration) to the obstacles."""
        coal, request = self.coal, self.request
        out = np.empty((len(placed), len(obstacles)))
        for i, (a, Ta) in enumerate(placed):
            for j, (b, Tb) in enumerate(obstacles):
                out[i, j] = coal.distance(a, Ta, b, Tb, request, coal.DistanceResult())
        return out


def configuration(goal_q) -> np.ndarray:
    return np.r_[np.asarray(goal_q, np.float64), FINGER]


# ------------------------------------------------------------------------------------------------- 1. geometry


def load_once(model: str) -> None:
    """(In a fresh process) print the seconds of one ``dk.collision.load`` of the Panda, JAX already started."""
    robot, urdf, srdf = panda()
    jax.block_until_ready(jnp.zeros(3) + 1.0)
    start = time.perf_counter()
    C.load(urdf, robot, meshes=model, srdf=srdf)
    print(json.dumps({"seconds": time.perf_counter() - start}))


def load_seconds(model: str, cache: str) -> float:
    env = dict(os.environ, DIFFKIN_FIT_CACHE=cache)
    out = subprocess.run(
        [sys.executable, __file__, "--load-once", model], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])["seconds"]


def geometry_rows(geoms: dict, runs: int) -> list[list[str]]:
    kinds = ("spheres", "capsules", "boxes", "cylinders", "convex")
    rows = []
    for model, geom in geoms.items():
        cold, cached = [], []
        for _ in range(runs):
            folder = tempfile.mkdtemp(prefix="diffkin-fit-cache-")
            try:
                cold.append(load_seconds(model, folder))
                cached.append(load_seconds(model, folder))
            finally:
                shutil.rmtree(folder, ignore_errors=True)
        names = [name for name, _, _, _ in geom.fits]
        over = geom.overshoot[[geom.shape_names.index(n) for n in names]]
        worst = names[int(np.argmax(over))]
        counts = ", ".join(f"{n} {k}" for n, k in zip(geom.counts, kinds, strict=True) if n)
        rows.append(
            [
                model,
                f"{len(geom.shape_names)} ({counts})",
                f"{1e3 * over.max():.2f} ({worst})",
                f"{1e3 * np.median(over):.2f}",
                f"{statistics.median(cold):.2f}",
                f"{statistics.median(cached):.2f}",
            ]
        )
        print(
            f"# {model}: loads cold {[round(t, 2) for t in cold]} s, cached {[round(t, 2) for t in cached]} s",
            flush=True,
        )
    return rows


# ------------------------------------------------------------------------------------------------- 2. MBM goals


def goal_rows(dist: Distances, real: Coal, doc: dict, per_scene: int | None):
    """Per scene (and all): clear by 5 mm per coal and per model, coal minus model, violations."""
    geoms = dist.geoms
    rows, bad, totals = [], [], {"n": 0, "coal>0": 0, "coal": 0, **{m: 0 for m in geoms}, **{m + "v": 0 for m in geoms}}
    gaps_all: dict[str, list[float]] = {m: [] for m in geoms}
    for scene, problems in doc["problems"].items():
        problems = problems[:per_scene] if per_scene else problems
        coal_d, model_d = [], {m: [] for m in geoms}
        qs = np.stack([configuration(p["goal_q"]) for p in problems])
        for p, q, placed in zip(problems, qs, real.placed(qs), strict=True):
            coal_d.append(real.distances(placed, real.obstacles(p)).min())
            world = world_of(p)
            for m in geoms:
                model_d[m].append(float(np.min(dist(m, q[None], world))))
        coal_d = np.asarray(coal_d)
        row = [scene, str(len(problems)), str(int((coal_d > 0).sum())), str(int((coal_d >= MARGIN).sum()))]
        totals["n"] += len(problems)
        totals["coal>0"] += int((coal_d > 0).sum())
        totals["coal"] += int((coal_d >= MARGIN).sum())
        gap_cells, clear_cells, viol_cells = [], [], []
        for m in geoms:
            d = np.asarray(model_d[m])
            gap = coal_d - d
            gaps_all[m] += gap.tolist()
            viol = np.flatnonzero(gap < -TOL)
            bad += [(m, scene, problems[k]["index"], d[k], coal_d[k]) for k in viol]
            totals[m] += int((d >= MARGIN).sum())
            totals[m + "v"] += len(viol)
            clear_cells.append(str(int((d >= MARGIN).sum())))
            gap_cells.append(f"{1e3 * gap.max():.3f} / {1e3 * np.median(gap):.3f}")
            viol_cells.append(f"{len(viol)} ({gap.min():.1e})")
            totals[m + "min"] = min(totals.get(m + "min", np.inf), float(gap.min()))
        rows.append(row + clear_cells + gap_cells + viol_cells)
        print(f"# {scene}: {' | '.join(rows[-1])}", flush=True)
    total = [
        "**all**",
        str(totals["n"]),
        str(totals["coal>0"]),
        str(totals["coal"]),
        *(str(totals[m]) for m in geoms),
        *(f"{1e3 * max(gaps_all[m]):.3f} / {1e3 * np.median(gaps_all[m]):.3f}" for m in geoms),
        *(f"{totals[m + 'v']} ({totals[m + 'min']:.1e})" for m in geoms),
    ]
    return rows + [total], bad


# ------------------------------------------------------------------------------------------------- 3. speed


def speed_rows(dist: Distances, real: Coal, problem: dict, coal_configs: int, batches=(1, 1000)):
    robot, geoms = dist.robot, dist.geoms
    rng = np.random.default_rng(0)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)

    def configs(n):
        q = rng.uniform(lo, hi, (n, robot.dof))
        q[:, 7] = FINGER
        return q

    obstacles = real.obstacles(problem)
    q_coal = configs(coal_configs)
    placed = real.placed(q_coal)
    start = time.perf_counter()
    for shapes in placed:
        real.distances(shapes, obstacles)
    coal_s = (time.perf_counter() - start) / coal_configs
    pairs = len(real.shapes) * len(obstacles)
    world64 = world_of(problem)
    rows = []
    for batch in batches:
        q64 = configs(batch)
        d = {}
        for m in geoms:
            for dtype in (jnp.float32, jnp.float64):
                d[m, dtype] = np.asarray(dist(m, q64, world64, dtype), np.float64)
                key = (m, np.dtype(dtype).name, batch)
                compiled, compile_s = dist.compiled[key], dist.compile_s[key]
                q, w = jnp.asarray(q64, dtype), jax.tree.map(lambda x, dtype=dtype: x.astype(dtype), world64)
                if batch == 1:
                    s = median_seconds(compiled, q, w, repeats=5, warmup=2, min_time=1.0)
                else:  # seconds a call (hulls): the first call was made above, then 3 timed calls
                    s = median_seconds(compiled, q, w, repeats=3, warmup=0, min_time=0.0)
                rows.append(
                    [
                        m,
                        np.dtype(dtype).name,
                        f"{batch:,}",
                        f"{compile_s:.1f}",
                        f"{s:.3g}",
                        f"{coal_s * batch:.3g}",
                        f"{coal_s * batch / s:.1f}x",
                        "",
                    ]
                )
            rows[-2][-1] = f"{np.abs(d[m, jnp.float32] - d[m, jnp.float64]).max():.1e}"
            rows[-1][-1] = "-"
            print(f"# speed: {rows[-2]}, {rows[-1]}", flush=True)
    return rows, coal_s, pairs


# ------------------------------------------------------------------------------------------------- main


def revision() -> str:
    """The commit, and a hash of the uncommitted changes under ``diffkin/`` where there are any."""
    git = lambda *a: subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout  # noqa: E731
    head = git("rev-parse", "--short", "HEAD").strip()
    dirty = git("status", "--porcelain", "--", "diffkin").strip()
    if not dirty:
        return head
    diff = git("diff", "HEAD", "--", "diffkin").encode()
    for path in sorted(line[3:] for line in dirty.splitlines() if line.startswith("??")):
        diff += (ROOT / path).read_bytes() if (ROOT / path).is_file() else b""
    return f"{head} + uncommitted changes under diffkin/ (sha256 {hashlib.sha256(diff).hexdigest()[:12]})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="10 problems per scene, 1 load process, 20 coal configs")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 1000], help="speed part's batches")
    parser.add_argument("--write", action="store_true", help="write experiments/results/<machine>-geometry.md")
    parser.add_argument("--load-once", choices=MODELS, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.load_once:
        load_once(args.load_once)
        return 0
    command = "python experiments/bench_geometry.py " + " ".join(argv if argv is not None else sys.argv[1:])
    busy = busy_note()
    robot, urdf, srdf = panda()
    geoms = {m: C.load(urdf, robot, meshes=m, srdf=srdf) for m in MODELS}
    real = Coal(urdf, robot, geoms["hulls"])
    doc = json.loads(MBM.read_text())
    t0 = time.perf_counter()

    geo = geometry_rows(geoms, 1 if args.quick else 3)
    dist = Distances(robot, geoms)
    goals, bad = goal_rows(dist, real, doc, 10 if args.quick else None)
    scene, k = SPEED_PROBLEM
    problem = doc["problems"][scene][k]
    speed, coal_s, pairs = speed_rows(dist, real, problem, 20 if args.quick else 100, args.batches)

    runs = "1 process" if args.quick else "median of 3 processes"
    parts = [
        f"# The Panda's collision geometry against its meshes (issue 53)\n\n`{command.strip()}`, "
        f"{datetime.date.today()}, {time.perf_counter() - t0:.0f} s. {machine_line()}, coal "
        f"{importlib.metadata.version('coal')}. diffkin {revision()}. Panda of "
        "example-robot-data (`panda.urdf` + `panda.srdf`); MBM problems `../shared/data/mbm/panda_mbm_problems.json`, "
        f"fingers locked at {FINGER} m (MBM's opening; the URDF's limit is 0.04 m).",
        busy,
        f"## 1. Geometry\n\nOvershoot: of the fitted (mesh) shapes, mm (the finger boxes are exact). Load: "
        f"`dk.collision.load` in a fresh process, s, {runs}; cold = empty `DIFFKIN_FIT_CACHE` folder, cached = "
        "the same folder in a second process.\n",
        table(
            ["model", "shapes", "worst overshoot (mm)", "median overshoot (mm)", "load cold (s)", "load cached (s)"],
            geo,
        ),
        "## 2. MBM goal configurations: smallest distance to the problem's obstacles\n\n"
        "float64; boxes and cylinders exact in both. coal: the URDF's collision meshes (BVH) and finger boxes. "
        f"clear = distance >= {1e3 * MARGIN:g} mm. coal - model: coal's smallest distance minus the model's, mm "
        "(largest / median; >= 0 for a model that contains the meshes). "
        f"Violations: model above coal by > {TOL:g} m (in brackets: the smallest coal - model, m).\n",
        table(
            ["scene", "goals", "coal > 0", "clear: coal", *(f"clear: {m}" for m in MODELS)]
            + [f"coal - {m} (max / median, mm)" for m in MODELS]
            + [f"violations {m}" for m in MODELS],
            goals,
        ),
    ]
    if bad:
        parts.append(
            "Violations (model, scene, problem index, model distance, coal distance):\n\n"
            + "\n".join(f"- {m} {s} #{i}: {d:.9f} m vs {c:.9f} m" for m, s, i, d, c in bad[:20])
        )
    parts.append(
        f"## 3. Speed: `world_distances` against {scene} #{problem['index']} ({len(real.obstacles(problem))} obstacles)"
        f"\n\nJitted; compile = lower + compile; warm = median of warm calls. coal: a Python loop of `coal.distance` "
        f"over the same {pairs} pairs on the real meshes, {1e3 * coal_s:.2f} ms per configuration (shapes placed "
        f"beforehand), times the batch. f32 - f64: largest difference of the float32 distances from float64's, m.\n\n"
        + table(
            [
                "model",
                "dtype",
                "batch",
                "compile (s)",
                "diffkin warm (s)",
                "coal loop (s)",
                "coal / diffkin",
                "f32 - f64 (m)",
            ],
            speed,
        )
    )
    publish(parts, "geometry" if args.write else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
