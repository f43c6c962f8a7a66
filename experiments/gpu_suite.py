"""Every GPU row in one run (issue 57): FK and Jacobian throughput, IK of the arms, whole robots, collision,
collision-aware IK, a slice of MotionBenchMaker, the centre of mass and paths, with the issue's GPU targets.

    python experiments/gpu_suite.py [--only fk,jacobian,...] [--out PATH] [--budget SECONDS]
    python experiments/gpu_suite.py --cpu-check [--out PATH]     # a tiny run of every row, here

Each row reuses the benchmark that owns it (``_bench``, ``bench_collision``, ``bench_ik_collision``,
``bench_com_path``, ``bench_mbm``, ``_pyroki_peer``) at the sizes of :data:`GPU` and puts its table in one
markdown file, ``experiments/results/<device>.md`` (``nvidia-h200.md``: JAX's device kind, slugified), between
``<!-- gpu_suite.py -->`` markers so that the file's other sections stay; ``--out`` writes elsewhere. The
file is rewritten after every row, so a run cut short keeps what it measured.

Times are medians of warm calls (compiled first; ``_bench.median_seconds``); the first call, compile
included, is its own column. pytorch-kinematics runs beside diffkin where it has the feature (FK, Jacobian,
single-end-effector IK: eager ``PseudoInverseIK``) when torch sees CUDA; PyRoki beside the collision rows and
the paths when ``_pyroki_peer`` can import it. Rows that need example-robot-data (Baxter, Talos, the
collision Panda), MotionBenchMaker's problems (``--mbm``) or a peer are skipped with the reason when it is
missing: nothing is downloaded. Large batches are split into equal chunks when they do not fit the device
(the note says so). ``--budget`` (seconds, default 450): past it, the remaining sizes are skipped (noted),
so that one run ends within the issue's 8 minutes on one device.

``--cpu-check``: every row at its smallest size (about 10-100 items, one timed call), compiled for compile
time (LLVM -O0, XLA's classic CPU emitter), written to a temporary file unless ``--out``:
``tests/integration/test_gpu_suite.py`` runs it so that the script never breaks unseen. Its figures mean
nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import json
import os
import re
import sys
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # JAX and torch share the GPU

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
try:
    import diffkin as dk
except ImportError:  # a checkout without an install: the repository root
    sys.path.insert(0, str(ROOT))
    import diffkin as dk

import _bench  # noqa: E402
from _bench import duration, first_call_seconds, machine_line, median_seconds, table  # noqa: E402

from diffkin._xla import solver_jit  # noqa: E402  (compiled as dk.ik.solve compiles itself)

PARTS = ("fk", "jacobian", "ik", "robots", "com", "paths", "collision", "collision_ik", "mbm")
TOL = (1e-5, 1e-4)  # dk.ik.solve's defaults: the targets' success
SLACK = (2e-6, 2e-5)  # float32 rounding allowed when a float32 solution is checked in float64


@dataclass(frozen=True)
class Sizes:
    """What each row runs."""

    fk: tuple[tuple[int, str], ...]  # (batch, dtype)
    jacobian: tuple[tuple[int, str], ...]
    pk_max: int  # largest batch pytorch-kinematics is timed at (FK, Jacobian)
    ik: tuple[int, ...]  # targets, iiwa14 and Panda
    robots: tuple[int, ...]  # Baxter and Talos problems
    com: tuple[int, ...]  # Talos configurations
    paths: tuple[int, int]  # paths x waypoints
    collision: tuple[tuple[int, str], ...]
    collision_ik: tuple[int, ...]
    mbm_per_scene: int
    quick: bool = False  # one timed call, no warm-up


GPU = Sizes(
    fk=tuple((n, d) for d in ("float32", "float64") for n in (1_000_000, 10_000_000, 100_000_000)),
    jacobian=((1_000_000, "float32"), (10_000_000, "float32"), (100_000_000, "float32"))
    + ((1_000_000, "float64"), (10_000_000, "float64")),
    pk_max=10_000_000,
    ik=(1, 1000, 100_000),
    robots=(1000,),  # Talos compiles for ~35 s per batch size
    com=(100_000, 1_000_000),
    paths=(1000, 100),
    collision=((1, "float32"), (1000, "float32"), (100_000, "float32"), (100_000, "float64")),
    collision_ik=(1000,),  # the avoid solver compiles for ~2 min per batch size on an H200 (nvidia-h200.md)
    mbm_per_scene=10,
)
CPU_CHECK = Sizes(
    fk=((100, "float32"), (100, "float64")),
    jacobian=((100, "float32"), (100, "float64")),
    pk_max=100,
    ik=(10,),
    robots=(4,),
    com=(10,),
    paths=(2, 5),
    collision=((10, "float32"),),
    collision_ik=(2,),
    mbm_per_scene=1,
    quick=True,
)

#: The issue's GPU targets: (label, row key, limit, unit); keys are filled by the rows.
TARGETS = [
    ("FK float32 at 1e8 (iiwa14) >= 10 G/s", ("fk", 100_000_000, "float32"), 10e9, ">="),
    ("default Jacobian float32 at 1e7 (iiwa14) >= 2 G/s", ("jacobian", 10_000_000, "float32"), 2e9, ">="),
] + [
    (f"IK {n:,} {name} target{'s' * (n > 1)} <= {ms:g} ms at >= 99.5 % (1e-5 m)", ("ik", name, n), ms * 1e-3, "<=")
    for name in ("iiwa14", "Panda")
    for n, ms in ((1, 0.3), (1000, 3), (100_000, 12))
]


# --------------------------------------------------------------------------------------------- the report


@dataclass
class Section:
    """One row of the issue: a table, its notes, and the figures the targets read."""

    key: str
    title: str
    about: str
    header: list[str]
    rows: list[list[str]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def markdown(self) -> str:
        parts = [f"### {self.title}", self.about]
        parts.append(table(self.header, self.rows) if self.rows else "_no row ran_")
        parts += [f"- {n}" for n in self.notes]
        parts.append(f"_{self.seconds:.0f} s in all._")
        return "\n\n".join(p for p in parts if p)


class Run:
    """The run's state: sizes, time budget, measured figures for the targets, and the output file."""

    def __init__(self, sizes: Sizes, out: Path, budget: float | None, command: str):
        self.sizes, self.out, self.budget, self.command = sizes, out, budget, command
        self.start = time.perf_counter()
        self.sections: list[Section] = []
        self.figures: dict[tuple, tuple[float, str, float | None]] = {}  # key -> (value, shown, success)
        self.failed: list[str] = []

    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def log(self, message: str) -> None:
        print(f"[{self.elapsed():6.1f} s] {message}", flush=True)

    def over_budget(self) -> bool:
        return self.budget is not None and self.elapsed() > self.budget

    def skipped(self, what: str) -> str:
        return f"{what}: skipped, past the time budget ({self.budget:.0f} s)"

    def time(self, fn, *args) -> tuple[float, float]:
        """``(first call, median warm call)`` seconds of ``fn(*args)``."""
        first = first_call_seconds(fn, *args)
        if self.sizes.quick:
            return first, median_seconds(fn, *args, repeats=1, warmup=0, min_time=0.0)
        return first, median_seconds(fn, *args, repeats=3, warmup=1, min_time=0.3)

    def target_rows(self) -> list[list[str]]:
        rows = []
        for label, key, limit, op in TARGETS:
            if key not in self.figures:
                rows.append([label, "not measured", "-"])
                continue
            value, shown, success = self.figures[key]
            ok = value >= limit if op == ">=" else value <= limit
            if success is not None:
                ok = ok and success >= 0.995
            rows.append([label, shown, "**pass**" if ok else "**FAIL**"])
        return rows

    def markdown(self) -> str:
        devices = jax.devices()
        head = [
            f"## One script for every GPU row (issue 57), {datetime.date.today()}",
            f"`{self.command}`, {self.elapsed():.0f} s. {machine_line()}. diffkin {_revision()}.",
            f"Device: {devices[0].device_kind} x{len(devices)} ({jax.default_backend()}); JAX's persistent cache: "
            f"{jax.config.jax_compilation_cache_dir or 'off'}. Medians of warm calls (at least 3 calls and 0.3 s; "
            "`--cpu-check`: one call); first call (compile included) apart; rates are items per second.",
        ]
        if self.sizes.quick:
            head.append("**`--cpu-check`: tiny sizes, compiled for compile time; the figures mean nothing.**")
        if self.failed:
            head.append("**Rows that raised:** " + "; ".join(self.failed))
        head += ["### The issue's GPU targets", table(["target", "measured", "result"], self.target_rows())]
        return "\n\n".join(head + [s.markdown() for s in self.sections])

    def write(self) -> None:
        """The report between the markers in :attr:`out` (the file's other text kept), written now."""
        begin, end = "<!-- gpu_suite.py: begin -->", "<!-- gpu_suite.py: end -->"
        block = f"{begin}\n\n{self.markdown()}\n\n{end}"
        old = self.out.read_text() if self.out.exists() else ""
        if begin in old and end in old:
            text = old[: old.index(begin)] + block + old[old.index(end) + len(end) :]
        elif old.startswith("# "):  # after the file's title
            title, _, rest = old.partition("\n")
            text = f"{title}\n\n{block}\n\n{rest.lstrip()}"
        else:
            text = f"# diffkin on {jax.devices()[0].device_kind}\n\n{block}\n\n{old}"
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.out.write_text(text.rstrip() + "\n")


def _revision() -> str:
    import subprocess

    try:
        git = ["git", "-C", str(ROOT)]
        head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run([*git, "status", "--porcelain", "--", "diffkin"], capture_output=True, text=True)
        return (head or "unknown") + (" plus uncommitted changes under diffkin/" if dirty.stdout.strip() else "")
    except OSError:
        return "unknown (no git)"


def gigas(n: int, seconds: float) -> str:
    per_s = n / seconds
    return f"{per_s / 1e9:.3g} G/s" if per_s >= 1e8 else _bench.rate(n, seconds)


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"


# --------------------------------------------------------------------------------------------- helpers


def erd(*parts: str) -> str:
    """A file of example-robot-data (``_bench.example_robot_data``), or ``FileNotFoundError`` saying how to get it."""
    try:
        path = os.path.join(_bench.example_robot_data(), *parts)
    except Exception as err:  # noqa: BLE001  (importlib.metadata's PackageNotFoundError, a bad path)
        raise FileNotFoundError(f"example-robot-data not installed and $EXAMPLE_ROBOT_DATA not set ({err})") from None
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path} not found (example-robot-data)")
    return path


@contextlib.contextmanager
def quiet():
    """Nothing printed (pytorch-kinematics' URDF parser prints a line per attribute it does not know)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        yield


def pk_reason() -> str | None:
    """Why pytorch-kinematics is not timed (``None``: it is)."""
    if _bench.pk is None:
        return "pytorch-kinematics not installed"
    if _bench.torch_device() != "cuda":
        return "torch has no CUDA (pytorch-kinematics runs on the CPU here: timed only by --cpu-check)"
    return None


def pk_runs(run: Run) -> bool:
    """Whether to time pytorch-kinematics: on CUDA, or on the CPU in ``--cpu-check`` (its code path checked)."""
    return _bench.pk is not None and (pk_reason() is None or run.sizes.quick)


def in_limits(chain, key, n: int, dtype):
    """``(n, dof)`` uniform configurations within the limits, drawn on the device (no host copy of 1e8 rows)."""
    lo, hi = (jnp.asarray(np.asarray(x), dtype) for x in (chain.lower, chain.upper))
    return jax.jit(lambda k: lo + (hi - lo) * jax.random.uniform(k, (n, lo.shape[0]), dtype), static_argnums=())(key)


def chunk_for(n: int, bytes_per_item: int) -> int:
    """The largest power-of-ten divisor chunk of ``n`` whose inputs and outputs take at most a third of the device's
    memory (``n`` where the device does not say)."""
    stats = jax.devices()[0].memory_stats() or {}
    limit = stats.get("bytes_limit")
    chunk = n
    while limit and chunk > 1000 and chunk * bytes_per_item > limit / 3 and n % (chunk // 10) == 0:
        chunk //= 10
    return chunk


def throughput(run: Run, fn, chain, n: int, dtype: str, out_items: int) -> tuple[float, float, str]:
    """``(first call, warm seconds for n, note)`` of ``fn`` on ``n`` configurations, in equal chunks where they
    do not fit (the warm time is then the chunks' calls back to back)."""
    size = np.dtype(dtype).itemsize
    chunk = chunk_for(n, size * (chain.dof + out_items))
    while True:
        try:
            q = in_limits(chain, jax.random.key(0), chunk, dtype)
            calls = n // chunk

            def all_chunks(q, calls=calls):
                out = None
                for _ in range(calls):
                    out = fn(q)
                return out

            first, warm = run.time(all_chunks, q)
            return first, warm, "" if calls == 1 else f"{calls} chunks of {chunk:,}"
        except Exception as err:  # noqa: BLE001  (XlaRuntimeError: RESOURCE_EXHAUSTED)
            if "RESOURCE_EXHAUSTED" not in str(err) or chunk <= 1000 or n % (chunk // 10):
                raise
            q = None
            chunk //= 10
            run.log(f"  out of memory: chunks of {chunk:,}")


def pk_throughput(method: str, chain_pk, chain, n: int, dtype: str, quick: bool) -> str:
    """pytorch-kinematics' ``method`` on ``n`` configurations: a rate, or why not."""
    torch = _bench.torch
    try:
        q = _bench.to_torch(_bench.random_configs(chain, n, dtype))
        fn = _bench.torch_synced(getattr(chain_pk, method))
        kw = dict(repeats=1, warmup=0, min_time=0.0) if quick else dict(repeats=3, warmup=1, min_time=0.3)
        return gigas(n, median_seconds(fn, q, **kw))
    except torch.OutOfMemoryError:
        return "out of memory"
    finally:
        _bench.release_torch_memory()


# --------------------------------------------------------------------------------------------- the rows


def fk_jacobian(run: Run, key: str) -> Section:
    chain = dk.robots.iiwa14()
    if key == "fk":
        fn, what, out_items, method = jax.jit(lambda q: dk.fk(chain, q)), "FK (flange pose)", 16, "forward_kinematics"
        sizes = run.sizes.fk
    else:
        fn, what, out_items, method = jax.jit(lambda q: dk.jacobian(chain, q)), "Jacobian (default)", 42, "jacobian"
        sizes = run.sizes.jacobian
    section = Section(
        key,
        f"{what} throughput, KUKA iiwa14",
        f"`dk.{'fk' if key == 'fk' else 'jacobian'}(chain, q)` jitted, the built-in DH iiwa14; configurations "
        "uniform within the limits, drawn on the device. pytorch-kinematics: `chain."
        f"{method}` of the shipped URDF (the same kinematics), torch on CUDA, up to {run.sizes.pk_max:,}.",
        ["batch", "dtype", "first call (s)", "warm", "diffkin", "pytorch-kinematics", "note"],
    )
    reason = pk_reason()
    if reason and not run.sizes.quick:
        section.notes.append(f"pytorch-kinematics: {reason}")
    for n, dtype in sizes:
        if run.over_budget():
            section.notes.append(run.skipped(f"{n:,} {dtype}"))
            continue
        run.log(f"{key} {n:,} {dtype}")
        first, warm, note = throughput(run, fn, chain, n, dtype, out_items)
        peer = "n/a"
        if pk_runs(run) and n <= run.sizes.pk_max:
            peer = pk_throughput(
                method, _bench.pk_chain("iiwa14", "iiwa14_link_ee", dtype), chain, n, dtype, run.sizes.quick
            )
        elif pk_runs(run):
            peer = f"not timed above {run.sizes.pk_max:,}"
        section.rows.append([f"{n:,}", dtype, f"{first:.2f}", duration(warm), gigas(n, warm), peer, note])
        run.figures[(key, n, dtype)] = (n / warm, gigas(n, warm), None)
    return section


def ik(run: Run) -> Section:
    section = Section(
        "ik",
        "IK of the arms: iiwa14 and Panda, 1 / 1,000 / 100,000 targets",
        "`dk.ik.solve(chain, T, key=key)` with its defaults (LM, 32 seeds, 1e-5 m / 1e-4 rad), float32, the built-in "
        "DH chains; targets are flange poses of uniform in-limit configurations. success: the solver's flag; "
        "checked: the solution's float64 FK within the tolerance (float32 rounding allowed). pytorch-kinematics: "
        "`PseudoInverseIK` eager, 30 iterations x 10 retries at its own 1 mm / 0.01 rad, on the shipped iiwa14 URDF "
        "and example-robot-data's Panda (flange `panda_link8`); its compiled solver (`use_compile=True`, a "
        "first call of 10-60 s per size) is left to `bench.py`.",
        ["robot", "targets", "first call (s)", "warm", "success", "checked", "pk eager", "pk success (1 mm)"],
    )
    robots = {"iiwa14": dk.robots.iiwa14(), "Panda": dk.robots.panda()}
    pk_chains = {}
    if pk_runs(run):
        pk_chains["iiwa14"] = lambda: _bench.pk_chain("iiwa14", "iiwa14_link_ee", "float32")

        def panda_pk():
            with open(erd("panda_description", "urdf", "panda.urdf"), "rb") as fh, quiet():
                chain = _bench.pk.build_serial_chain_from_urdf(fh.read(), "panda_link8")
            return chain.to(dtype=_bench.torch.float32, device=_bench.torch_device())

        pk_chains["Panda"] = panda_pk
    elif pk_reason():
        section.notes.append(f"pytorch-kinematics: {pk_reason()}")
    for name, chain in robots.items():
        solve = solver_jit(lambda T, key, chain=chain: dk.ik.solve(chain, T, key=key))
        for n in run.sizes.ik:
            if run.over_budget():
                section.notes.append(run.skipped(f"{name} {n:,}"))
                continue
            run.log(f"ik {name} {n:,}")
            q_true = _bench.random_configs(chain, n, np.float64, seed=1)
            T64 = np.asarray(dk.fk(chain, jnp.asarray(q_true)))
            args = (jnp.asarray(T64, jnp.float32), jax.random.key(1))
            first, warm = run.time(solve, *args)
            res = solve(*args)
            success = float(np.mean(np.asarray(res.success)))
            T = np.asarray(dk.fk(chain, jnp.asarray(np.asarray(res.q), jnp.float64)))
            pos = np.linalg.norm(T[:, :3, 3] - T64[:, :3, 3], axis=-1)
            rot = np.asarray(dk.se3.rotation_angle(np.swapaxes(T64[:, :3, :3], -1, -2) @ T[:, :3, :3]))
            checked = float(np.mean((pos <= TOL[0] + SLACK[0]) & (rot <= TOL[1] + SLACK[1])))
            peer, peer_ok = "n/a", "n/a"
            if name in pk_chains:
                try:
                    chain_pk = pk_chains[name]()
                    goal = _bench.pk.Transform3d(matrix=_bench.to_torch(T64.astype(np.float32)))
                    r = _bench.pk_ik_timed(
                        chain_pk, chain.lower, chain.upper, goal, compiled=False, repeats=1 if run.sizes.quick else 3,
                        warmup=0, min_time=0.0,
                    )  # fmt: skip
                    if r.seconds is not None:
                        peer, peer_ok = duration(r.seconds), pct(r.success)
                    else:
                        peer = "raised: " + r.note()
                except FileNotFoundError as err:
                    peer = f"skipped: {err}"
                except _bench.torch.OutOfMemoryError:
                    peer = "out of memory"
                finally:
                    _bench.release_torch_memory()
            section.rows.append(
                [name, f"{n:,}", f"{first:.1f}", duration(warm), pct(success), pct(checked), peer, peer_ok]
            )
            solved = min(success, checked)
            run.figures[("ik", name, n)] = (warm, f"{duration(warm)}, {pct(solved)} solved", solved)
    return section


def _random_q(robot, n: int, seed: int) -> np.ndarray:
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    return np.random.default_rng(seed).uniform(lo, hi, (n, robot.dof))


def _random_poses(n: int, rng, angle: float, offset: float) -> np.ndarray:
    """``(n, 4, 4)`` poses: rotation vectors and translations normal, of scales ``angle`` and ``offset``."""
    w = rng.normal(0, angle, (n, 3))
    theta = np.linalg.norm(w, axis=-1)[:, None, None]
    K = np.asarray(dk.se3.skew(w / np.maximum(theta[..., 0], 1e-300)))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K
    T[:, :3, 3] = rng.normal(0, offset, (n, 3))
    return T


def robots(run: Run) -> Section:
    section = Section(
        "robots",
        "Whole-robot IK: Baxter (two grippers), Talos (two soles and two grippers, root solved)",
        "`dk.ik.solve` with its defaults, float32, example-robot-data's `baxter.urdf` and `talos_reduced.urdf` "
        "(floating, `solve_base=True` from the identity; targets from random root poses), as "
        "`bench_ik_robots.py`; targets are frame poses of uniform in-limit configurations. pytorch-kinematics "
        "solves one end effector of a serial chain: no row.",
        ["problem", "joints", "problems", "first call (s)", "warm", "problems/s", "success", "mean iters"],
    )
    try:
        problems = {
            "Baxter, 2 grippers": (erd("baxter_description", "urdf", "baxter.urdf"), False),
            "Talos, 2 soles + 2 grippers, root solved": (erd("talos_data", "robots", "talos_reduced.urdf"), True),
        }
    except FileNotFoundError as err:
        section.notes.append(f"skipped: {err}")
        return section
    for label, (path, floating) in problems.items():
        robot = dk.load_robot(path, floating=floating) if floating else dk.load_robot(path)
        frames = (
            ["left_sole_link", "right_sole_link", "gripper_left_base_link", "gripper_right_base_link"]
            if floating
            else ["left_gripper", "right_gripper"]
        )
        fn = solver_jit(lambda t, robot=robot, floating=floating: dk.ik.solve(robot, t, solve_base=floating))
        for n in run.sizes.robots:
            if run.over_budget():
                section.notes.append(run.skipped(f"{label} {n:,}"))
                continue
            run.log(f"robots {label} {n:,}")
            base = _random_poses(n, np.random.default_rng(1), 0.3, 0.2) if floating else None
            T = np.asarray(dk.fk(robot, _random_q(robot, n, 2), frames, base=base))
            targets = {f: jnp.asarray(T[:, k], jnp.float32) for k, f in enumerate(frames)}
            first, warm = run.time(fn, targets)
            res = fn(targets)
            joints = f"{robot.dof} + 6" if floating else str(robot.dof)
            section.rows.append(
                [
                    label,
                    joints,
                    f"{n:,}",
                    f"{first:.1f}",
                    duration(warm),
                    _bench.rate(n, warm),
                    pct(float(np.mean(np.asarray(res.success)))),
                    f"{float(np.mean(np.asarray(res.iters))):.1f}",
                ]
            )
    return section


def com(run: Run) -> Section:
    section = Section(
        "com",
        "Centre of mass of Talos and its Jacobian",
        "`dk.com` + `dk.com_jacobian(include_base=True)` in one jitted call, example-robot-data's "
        "`talos_full_v2.urdf`, floating base, float64 (as `bench_com_path.py`; its Pinocchio loop is a CPU "
        "reference, left to that script). pytorch-kinematics has no centre of mass.",
        ["robot", "batch", "first call (s)", "warm", "configurations/s"],
    )
    try:
        robot = dk.load_robot(erd("talos_data", "robots", "talos_full_v2.urdf"), floating=True)
    except FileNotFoundError as err:
        section.notes.append(f"skipped: {err}")
        return section

    @jax.jit
    def both(q, base):
        return dk.com(robot, q, base=base), dk.com_jacobian(robot, q, base=base, include_base=True)

    for n in run.sizes.com:
        if run.over_budget():
            section.notes.append(run.skipped(f"{n:,}"))
            continue
        run.log(f"com {n:,}")
        q = jnp.asarray(_random_q(robot, n, 0))
        base = jnp.asarray(_random_poses(n, np.random.default_rng(0), 0.3, 1.0))
        first, warm = run.time(both, q, base)
        section.rows.append([f"Talos ({robot.dof} + 6 dof)", f"{n:,}", f"{first:.1f}", duration(warm), gigas(n, warm)])
    return section


def paths(run: Run) -> Section:
    import bench_com_path

    n, steps = run.sizes.paths
    section = Section(
        "paths",
        f"Panda paths: {n:,} paths of {steps} waypoints",
        f"`bench_com_path.bench_paths({n}, {steps})` (lines and circles of 5-10 cm, float32): `dk.ik.solve_path` "
        "(max_step 0.1 rad) against solving every waypoint alone; its medians (3 calls), its compile column; "
        "PyRoki's trajectory optimisation on the first 100 paths when importable (`_pyroki_peer.solve_paths`).",
        [
            "Panda paths, float32",
            "waypoints",
            "warm (s)",
            "compile (s)",
            "waypoint success",
            "paths all solved",
            "jumps",
            "largest step (rad)",
        ],
    )
    if run.over_budget():
        section.notes.append(run.skipped("paths"))
        return section
    jax.config.update("jax_enable_x64", False)  # float32 throughout, as bench_com_path (PyRoki's jaxls too)
    try:
        run.log("paths: solve_path and solve per waypoint")
        lines = bench_com_path.bench_paths(n, steps)
        run.log("paths: PyRoki")
        try:
            lines += bench_com_path.bench_paths_pyroki(n, steps)
            if len(lines) == 2:
                section.notes.append("PyRoki: not importable (experiments/README.md: peers not on PyPI)")
        except FileNotFoundError as err:  # example-robot-data's Panda, which PyRoki loads
            section.notes.append(f"PyRoki: skipped, {err}")
    finally:
        jax.config.update("jax_enable_x64", True)
    section.rows = [[c.strip() for c in line.strip().strip("|").split(" | ")] for line in lines]
    return section


def _collision_panda():
    import bench_collision

    erd("panda_description", "urdf", "panda.urdf")  # FileNotFoundError with the reason where it is missing
    robot, urdf, srdf = bench_collision.panda()
    return bench_collision, robot, urdf, srdf


def collision(run: Run) -> Section:
    section = Section(
        "collision",
        "Collision distances: the Panda's capsules, its self pairs and 16 obstacles, beside PyRoki",
        "`self_distances` + `world_distances` in one jitted call (`bench_collision.py`: example-robot-data's "
        "Panda and SRDF, `dk.collision.load` capsules, 8 spheres, 7 boxes, a floor), random in-limit "
        "configurations. PyRoki (`bench_collision.pyroki_distances`, its own capsules, each box as six "
        "half-spaces) on the same configurations when importable. coal's CPU loop is left to `bench_collision.py`.",
        ["dtype", "batch", "diffkin first call (s)", "diffkin warm", "PyRoki first call (s)", "PyRoki warm", "ratio"],
    )
    try:
        bc, robot, urdf, srdf = _collision_panda()
    except FileNotFoundError as err:
        section.notes.append(f"skipped: {err}")
        return section
    run.log("collision: dk.collision.load (mesh fits, cached on disk)")
    start = time.perf_counter()
    geom = dk.collision.load(urdf, robot, srdf=srdf)
    section.notes.append(f"`dk.collision.load`: {time.perf_counter() - start:.1f} s (mesh fits; cached on disk)")
    world = bc.obstacles(np.random.default_rng(0))
    peer = bc.pyroki_distances(urdf, srdf, world)
    if peer is None:
        section.notes.append("PyRoki: not importable (experiments/README.md: peers not on PyPI)")
    rng = np.random.default_rng(1)
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    for n, dtype in run.sizes.collision:
        if run.over_budget():
            section.notes.append(run.skipped(f"{n:,} {dtype}"))
            continue
        run.log(f"collision {n:,} {dtype}")
        f = jax.jit(bc.distances(robot, geom, world, np.dtype(dtype)))
        q = jnp.asarray(rng.uniform(lo, hi, (n, robot.dof)).astype(dtype))
        first, warm = run.time(f, q)
        cells = ["n/a", "n/a", "n/a"]
        if peer is not None:
            p_first, p_warm = run.time(peer, q)
            cells = [f"{p_first:.1f}", duration(p_warm), f"{p_warm / warm:.1f}x"]
        section.rows.append([dtype, f"{n:,}", f"{first:.1f}", duration(warm), *cells])
    return section


JUDGED = ("pose", "clear", "all")


def _judge(robot, clearance, q: np.ndarray, T64: np.ndarray, world64, ee: str, locked=()) -> dict[str, float]:
    """Pose within 1e-5 m / 1e-4 rad (float64 FK), joints within limits (but the ``locked`` ones, held where the
    caller put them), and diffkin's model clear (``clearance(q, world) >= 0``)."""
    T = np.asarray(dk.fk(robot, jnp.asarray(q, jnp.float64), ee))
    pos = np.linalg.norm(T[:, :3, 3] - T64[:, :3, 3], axis=-1)
    rot = np.asarray(dk.se3.rotation_angle(np.swapaxes(T64[:, :3, :3], -1, -2) @ T[:, :3, :3]))
    lo, hi = np.asarray(robot.lower), np.asarray(robot.upper)
    free = np.array([name not in locked for name in robot.joint_names])
    limits = np.all(((q >= lo - 1e-6) & (q <= hi + 1e-6))[:, free], axis=-1)
    clear = np.asarray(clearance(jnp.asarray(q, jnp.float64), world64)) >= 0
    pose = (pos <= TOL[0] + SLACK[0]) & (rot <= TOL[1] + SLACK[1])
    return {"pose": float(np.mean(pose)), "clear": float(np.mean(clear)), "all": float(np.mean(pose & limits & clear))}


def collision_ik(run: Run) -> Section:
    section = Section(
        "collision_ik",
        "Collision-aware IK: the Panda among a table, a shelf and spheres, beside PyRoki",
        "`bench_ik_collision.py`'s scene and targets (hand poses of configurations clear by 3 cm): `dk.ik.solve("
        "..., avoid=dk.ik.Avoid(geom, world, margin=0.01))` and without `avoid`, float32; PyRoki's collision IK "
        "(`_pyroki_peer.solve_batch`) when importable. Judged in float64: pose within 1e-5 m / 1e-4 rad, limits, "
        "and clear by diffkin's capsules (the real meshes, by coal: `bench_ik_collision.py`).",
        ["batch", "solver", "first call (s)", "warm", "success (flag)", "on pose", "clear (model)", "all three"],
    )
    try:
        bc, robot, urdf, srdf = _collision_panda()
    except FileNotFoundError as err:
        section.notes.append(f"skipped: {err}")
        return section
    import bench_ik_collision as bic

    geom = dk.collision.load(urdf, robot, srdf=srdf)
    s = bic.scene()
    world64, world32 = bic.world_of(s, jnp.float64), bic.world_of(s, jnp.float32)
    avoid = dk.ik.Avoid(geom, world32, margin=bic.MARGIN)
    clearance = jax.jit(lambda q, w: dk.collision.clearance(robot, geom, q, w))
    ee = bic.EE
    solvers = {
        "diffkin avoid": solver_jit(lambda T: dk.ik.solve(robot, {ee: T}, avoid=avoid)),
        "diffkin (no avoid)": solver_jit(lambda T: dk.ik.solve(robot, {ee: T})),
    }
    pyroki = None
    try:
        import _pyroki_peer

        pyroki = _pyroki_peer.panda_robot(urdf, srdf)
    except ImportError as err:
        section.notes.append(f"PyRoki: not importable ({err}; experiments/README.md)")
    rng = np.random.default_rng(0)
    for n in run.sizes.collision_ik:
        T64 = bic.targets_of(robot, geom, world64, n, rng)
        T32 = jnp.asarray(T64, jnp.float32)
        for name, fn in solvers.items():
            if run.over_budget():
                section.notes.append(run.skipped(f"{n:,} {name}"))
                continue
            run.log(f"collision_ik {n:,} {name}")
            first, warm = run.time(fn, T32)
            res = fn(T32)
            j = _judge(robot, clearance, np.asarray(res.q, np.float64), T64, world64, ee)
            success = pct(float(np.mean(np.asarray(res.success))))
            section.rows.append([f"{n:,}", name, f"{first:.1f}", duration(warm), success, *(pct(j[c]) for c in JUDGED)])
        if pyroki is not None and not run.over_budget():
            run.log(f"collision_ik {n:,} PyRoki")

            def peer(T):
                q, names = _pyroki_peer.solve_batch(*pyroki, ee, np.asarray(T), s["spheres"], s["boxes"], s["plane"])
                return q[:, [names.index(j) for j in robot.joint_names]]

            first, warm = run.time(peer, T32)
            j = _judge(robot, clearance, np.asarray(peer(T32), np.float64), T64, world64, ee)
            section.rows.append([f"{n:,}", "PyRoki", f"{first:.1f}", duration(warm), "-", *(pct(j[c]) for c in JUDGED)])
    return section


def mbm(run: Run, path: Path) -> Section:
    k = run.sizes.mbm_per_scene
    section = Section(
        "mbm",
        f"MotionBenchMaker slice: {k} Panda problem(s) per scene, one call",
        f"`bench_mbm.py`'s solve on {k} problem(s) per scene (spread evenly, `bench_mbm.subset`), every scene's "
        "problems in one call with a world per problem (padded to the same counts): `dk.ik.solve(..., avoid="
        "dk.ik.Avoid(geom, world, margin=0.005), locked=fingers)`, the tight model (`meshes='hulls'`), float32. "
        "Judged in float64 by diffkin's model (pose, the arm's limits, clearance >= 0); the real-mesh judge "
        "(coal), the whole set and cuRobo's setting are `bench_mbm.py`'s.",
        ["scene", "problems", "success (flag)", "on pose", "clear (model)", "all three"],
    )
    if not path.exists():
        section.notes.append(
            f"skipped: {path} not found (MotionBenchMaker's problems, `../shared/data/mbm/panda_mbm_problems.json`; "
            "`--mbm PATH`)"
        )
        return section
    try:
        bc, robot, urdf, srdf = _collision_panda()
    except FileNotFoundError as err:
        section.notes.append(f"skipped: {err}")
        return section
    if run.over_budget():
        section.notes.append(run.skipped("MBM"))
        return section
    import bench_geometry

    try:
        import bench_mbm
    except ImportError as err:  # PyYAML (cuRobo's world file), not installed on a bare GPU image
        section.notes.append(f"skipped: bench_mbm not importable ({err})")
        return section
    doc = json.loads(path.read_text())
    scenes = {s: bench_mbm.subset(p, k) for s, p in doc["problems"].items()}
    problems = [p for ps in scenes.values() for p in ps]
    run.log(f"mbm: {len(problems)} problems, dk.collision.load hulls")
    geom = dk.collision.load(urdf, robot, meshes="hulls", srdf=srdf)
    T64 = np.stack([bench_mbm.target_of(p) for p in problems])
    worlds = [bench_geometry.world_of(p, bench_geometry.PAD) for p in problems]
    locked = {"panda_finger_joint1": bench_geometry.FINGER}

    # bench_mbm.solve_problems' call in one jit traced once: calling it again rebuilds the Avoid, and the solver
    # traced and compiled again for it (the warm call took as long as the first on a CPU)
    avoid = dk.ik.Avoid(geom, jax.tree.map(lambda *x: jnp.stack(x), *worlds), margin=bench_geometry.MARGIN)
    T32 = jnp.asarray(T64, jnp.float32)
    solver = solver_jit(lambda T: dk.ik.solve(robot, {bench_mbm.EE: T}, avoid=avoid, locked=locked))

    def solve():
        with warnings.catch_warnings():  # the fingers held at MBM's 0.065 m, beyond their 0.04 m limit
            warnings.filterwarnings("ignore", "locked joint", UserWarning)
            return solver(T32)

    run.log("mbm: solve")
    first, warm = run.time(solve)
    res = solve()
    q = np.asarray(res.q, np.float64)
    success = np.asarray(res.success)
    clearance = jax.jit(lambda q, w: dk.collision.clearance(robot, geom, q, w))
    start = 0
    for scene, ps in scenes.items():
        sl = slice(start, start + len(ps))
        start += len(ps)
        j = [
            _judge(robot, clearance, q[i : i + 1], T64[i : i + 1], worlds[i], bench_mbm.EE, locked)
            for i in range(sl.start, sl.stop)
        ]
        section.rows.append(
            [scene, str(len(ps)), str(int(success[sl].sum()))]
            + [str(int(sum(x[key] for x in j))) for key in ("pose", "clear", "all")]
        )
    section.notes.append(
        f"{len(problems)} problems: first call {first:.1f} s (compile included), warm {duration(warm)} "
        f"({1e3 * warm / len(problems):.2g} ms a problem)"
    )
    return section


# --------------------------------------------------------------------------------------------- main


def default_out(cpu_check: bool) -> Path:
    """``experiments/results/<device kind>.md``, or a temporary file for ``--cpu-check``."""
    if cpu_check:
        return Path(tempfile.gettempdir()) / "diffkin-gpu-suite-cpu-check.md"
    slug = re.sub(r"[^a-z0-9]+", "-", jax.devices()[0].device_kind.lower()).strip("-")
    return ROOT / "experiments" / "results" / f"{slug}.md"


def parse_args(argv=None) -> argparse.Namespace:
    import bench_geometry

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cpu-check", action="store_true", help="every row at a tiny size (a check, not a benchmark)")
    parser.add_argument("--only", help=f"comma-separated rows: {','.join(PARTS)} (default all)")
    parser.add_argument("--out", type=Path, help="the markdown file (default experiments/results/<device>.md)")
    parser.add_argument("--budget", type=float, help="seconds after which the remaining sizes are skipped (450)")
    parser.add_argument("--mbm", type=Path, default=bench_geometry.MBM, help="MotionBenchMaker's problems (JSON)")
    args = parser.parse_args(argv)
    args.only = tuple(p.strip() for p in args.only.split(",") if p.strip()) if args.only else PARTS
    unknown = [p for p in args.only if p not in PARTS]
    if unknown or not args.only:
        parser.error(f"--only: unknown row {unknown[0]!r}" if unknown else "--only: no row")
    if args.budget is None:
        args.budget = None if args.cpu_check else 450.0
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.cpu_check:  # values, not speed: compile for compile time (as tests/conftest.py does)
        jax.config.update("jax_disable_most_optimizations", True)
        os.environ["XLA_FLAGS"] = " ".join(
            filter(None, ("--xla_cpu_use_fusion_emitters=false", os.environ.get("XLA_FLAGS")))
        )
    jax.config.update("jax_enable_x64", True)  # for the float64 rows; the float32 rows stay float32
    command = "python experiments/gpu_suite.py " + " ".join(sys.argv[1:] if argv is None else argv)
    out = args.out or default_out(args.cpu_check)
    run = Run(CPU_CHECK if args.cpu_check else GPU, out, args.budget, command.strip())
    run.log(f"{machine_line()}; writing {out}")
    rows = {
        "fk": lambda: fk_jacobian(run, "fk"),
        "jacobian": lambda: fk_jacobian(run, "jacobian"),
        "ik": lambda: ik(run),
        "robots": lambda: robots(run),
        "com": lambda: com(run),
        "paths": lambda: paths(run),
        "collision": lambda: collision(run),
        "collision_ik": lambda: collision_ik(run),
        "mbm": lambda: mbm(run, args.mbm),
    }
    for key in args.only:
        start = time.perf_counter()
        run.log(f"== {key}")
        try:
            section = rows[key]()
        except Exception as err:  # noqa: BLE001  (a row that raises is reported, the others still run)
            traceback.print_exc()
            run.failed.append(f"{key}: {type(err).__name__}: {err}")
            section = Section(key, f"{key}: raised", f"`{type(err).__name__}: {err}`", [])
        section.seconds = time.perf_counter() - start
        run.sections.append(section)
        run.write()
        run.log(f"== {key} done in {section.seconds:.0f} s; written {out}")
    print("\n" + run.markdown())
    run.log(f"done; written {out}")
    return 1 if run.failed else 0


if __name__ == "__main__":
    sys.exit(main())
