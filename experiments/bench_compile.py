"""What the first call costs: trace, lower and compile times, and the compile's peak memory.

    python experiments/bench_compile.py [--quick] [--only fk,jacobian,ik] [--timeout 300] [--max-gb 4] [--cache]
    python experiments/bench_compile.py --only clutter --parts

``--quick``: one case, the first of the parts asked for (FK of the 7-joint arm by default).

For FK, the world Jacobian (analytic, the default, and autodiff) and the default IK (``dk.ik.solve``, 1,000
targets) of synthetic DH chains of 7, 20 and 50 joints (IK: the iiwa14 and chains of 20 and 50 joints), for FK
and Jacobians of a whole tree (Talos from example-robot-data, 32 joints, 60 frames, where installed), and for
whole-robot IK (``--only ik-robots``: Baxter's two grippers, Talos' two soles and two grippers with the root
solved, the Unitree G1's two feet, a hand and its centre of mass with the root
solved): ``jax.jit(f).trace(x)``, ``.lower()`` and ``.compile()`` timed separately, float32 (the IK with the
compiler options ``dk.ik.solve`` gives its own ``jit``), and the compiled program's kernels (XLA fusions: its
CPU compile time follows their number). A ``PYTHONPATH`` given comes before this checkout, so that
``PYTHONPATH=/path/to/other/checkout`` measures another commit's ``diffkin`` with this script. Each case runs
in a fresh subprocess (so nothing is cached between cases). Its memory is the subprocess's own: its resident
memory just before tracing (JAX and the model loaded, ``VmRSS``) and its peak resident memory while tracing,
lowering and compiling (``VmHWM`` of ``/proc/self/status``, reset to the current resident memory by writing
``5`` to ``/proc/self/clear_refs`` just before tracing). Not ``getrusage``'s ``ru_maxrss``: on Linux a process
started by ``subprocess`` starts with its parent's peak there, so every case would read at least the parent's
memory. Where ``/proc`` is missing (not Linux) the table says ``ru_maxrss`` and is an upper bound. A case is
stopped after ``--timeout`` seconds or above ``--max-gb`` GB of resident memory and reported as such. The
batch (1,000 configurations) does not change what is compiled.

``--parts``: also each case's kernels by where the IK search calls them (the chain of its functions on a
kernel's call stack, read from the compiled module's stack tables) and by part (collision, forward pass,
other): where a solver's compile time goes.

``--cache``: what JAX's persistent cache (on by default for diffkin's users) saves a script's second run:
each IK case (the iiwa14, Baxter, Talos' contacts, and the Panda with ``avoid``: capsules, a few
obstacles, 5 mm margin) runs twice, each time in a fresh subprocess, with one fresh cache folder;
the table gives both runs' trace + lower and compile times.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

SIZES = (7, 20, 50)
QUICK_SIZES = (7,)
BATCH = 1000
ROOT = Path(__file__).resolve().parents[1]  # this checkout


def chain(dof: int):
    """A DH chain of ``dof`` revolute joints with fixed pseudo-random parameters (the iiwa14 for 7)."""
    import numpy as np

    import diffkin as dk

    if dof == 7:
        return dk.robots.iiwa14()
    rng = np.random.default_rng(dof)
    table = np.stack(
        [
            rng.uniform(0.0, 0.3, dof),
            rng.choice([-np.pi / 2, 0.0, np.pi / 2], dof),
            rng.uniform(0.0, 0.3, dof),
            np.zeros(dof),
        ],
        axis=1,
    )
    return dk.DHChain.from_table(table, lower=-np.pi * np.ones(dof), upper=np.pi * np.ones(dof), name=f"dh{dof}")


def example_robot_data_root() -> Path | None:
    """The ``robots`` folder of example-robot-data; ``None`` if not installed."""
    from importlib import metadata

    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        return None
    return Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))


def erd_robot(relative: str, floating: bool = False):
    """A robot of example-robot-data (a path below its ``robots`` folder); ``None`` if not installed."""
    import diffkin as dk

    root = example_robot_data_root()
    path = None if root is None else root / relative
    return dk.load_robot(str(path), floating=floating) if path is not None and path.is_file() else None


def talos():
    """Talos (``talos_full_v2.urdf``, 60 frames) as a :class:`dk.Robot`; ``None`` if not installed."""
    return erd_robot("talos_data/robots/talos_full_v2.urdf")


# Whole-robot IK (as experiments/bench_ik_robots.py solves it): robot, its targets, floating root solved.
ROBOT_IK = {
    "baxter": ("baxter_description/urdf/baxter.urdf", ["left_gripper", "right_gripper"], False),
    "talos-contacts": (
        "talos_data/robots/talos_reduced.urdf",
        ["left_sole_link", "right_sole_link", "gripper_left_base_link", "gripper_right_base_link"],
        True,
    ),
    # Unitree G1 (29 joints; example-robot-data's URDF: the MJCF of issue 57 is not installed here)
    "g1-com": (
        "g1_description/urdf/g1_29dof_rev_1_0.urdf",
        ["left_ankle_roll_link", "right_ankle_roll_link", "left_rubber_hand"],
        True,
    ),
}
#: the cases of ROBOT_IK that also keep the centre of mass (horizontal, ``com=``) where it was
WITH_COM = ("g1-com",)


def panda_avoid():
    """``(f, args)``: the Panda's collision-aware IK (``meshes="capsules"``, the default model; 1,000 targets,
    a box and two spheres, 5 mm margin, fingers locked), as a user of ``avoid=`` first calls it."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import diffkin as dk

    folder = example_robot_data_root()
    urdf, srdf = folder / "panda_description/urdf/panda.urdf", folder / "panda_description/srdf/panda.srdf"
    m = dk.load_robot(str(urdf))
    geom = dk.collision.load(str(urdf), m, srdf=str(srdf))
    world = dk.collision.World(
        dk.collision.Box(jnp.eye(4).at[:3, 3].set(jnp.array([0.6, 0.0, 0.2]))[None], jnp.array([[0.1, 0.3, 0.2]])),
        dk.collision.Sphere(jnp.array([[0.3, 0.4, 0.5], [0.3, -0.4, 0.5]]), jnp.array([0.08, 0.08])),
    )
    lo, hi = np.asarray(m.lower), np.asarray(m.upper)
    q = np.random.default_rng(0).uniform(lo, hi, (BATCH, m.dof))
    T = jnp.asarray(dk.fk(m, q, "panda_hand"), jnp.float32)
    avoid = dk.ik.Avoid(geom, world, margin=0.005)
    locked = {"panda_finger_joint1": 0.02}
    return (lambda t, key: dk.ik.solve(m, {"panda_hand": t}, key=key, avoid=avoid, locked=locked)), (
        T,
        jax.random.key(1),
    )


def panda_mbm(avoid: bool):
    """``(f, args)``: the Panda's IK of one MotionBenchMaker problem (``bench_mbm.py``'s first: the box scene's
    first grasp, its fingers locked), with ``avoid=`` (``meshes="hulls"``, the problem's own boxes and
    cylinders padded as bench_mbm pads them, 5 mm margin) or, ``avoid=False``, the same IK without it:
    the issue's first call and what it is compared with."""
    import jax
    import jax.numpy as jnp
    from bench_geometry import FINGER, MARGIN, MBM, PAD, panda, world_of
    from bench_mbm import EE, target_of

    import diffkin as dk

    robot, urdf, srdf = panda()
    problem = json.loads(MBM.read_text())["problems"]["box"][0]
    T = jnp.asarray(target_of(problem)[None], jnp.float32)
    locked = {"panda_finger_joint1": FINGER}
    if not avoid:
        return (lambda t: dk.ik.solve(robot, {EE: t}, locked=locked)), (T,)
    geom = dk.collision.load(urdf, robot, srdf=srdf, meshes="hulls")
    world = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), world_of(problem, PAD))
    solve = lambda t, w: dk.ik.solve(robot, {EE: t}, avoid=dk.ik.Avoid(geom, w, margin=MARGIN), locked=locked)  # noqa: E731
    return solve, (T, world)


def case_function(work: str, model: str):
    """``(f, args)`` of one case: a function of arrays and its float32 arguments."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import diffkin as dk

    if model == "panda-avoid":
        return panda_avoid()
    if model in ("panda-mbm", "panda-mbm-avoid"):
        return panda_mbm(model == "panda-mbm-avoid")
    if model in ROBOT_IK:
        path, frames, floating = ROBOT_IK[model]
        m = erd_robot(path, floating)
        lo = np.where(np.isfinite(m.lower), m.lower, -np.pi)
        hi = np.where(np.isfinite(m.upper), m.upper, np.pi)
        q = np.random.default_rng(0).uniform(lo, hi, (BATCH, m.dof))
        T = jnp.asarray(dk.fk(m, q, frames), jnp.float32)
        targets = {f: T[:, k] for k, f in enumerate(frames)}
        if model in WITH_COM:
            c = jnp.asarray(dk.com(m, q)[:, :2], jnp.float32)
            solve = lambda t, c, key: dk.ik.solve(m, t, com=c, key=key, solve_base=floating)  # noqa: E731
            return solve, (targets, c, jax.random.key(1))
        return (lambda t, key: dk.ik.solve(m, t, key=key, solve_base=floating)), (targets, jax.random.key(1))
    if model == "talos":
        m = talos()
        frame = "gripper_left_base_link"
    else:
        m, frame = chain(int(model)), None
    lo = np.where(np.isfinite(m.lower), m.lower, -np.pi)
    hi = np.where(np.isfinite(m.upper), m.upper, np.pi)
    q = jnp.asarray(np.random.default_rng(0).uniform(lo, hi, (BATCH, m.dof)), jnp.float32)
    names = () if frame is None else (frame,)
    if work == "FK":
        return (lambda q: dk.fk(m, q, *names)), (q,)
    if work.startswith("Jacobian"):
        method = "analytic" if "analytic" in work else "autodiff"
        return (lambda q: dk.jacobian(m, q, *names, method=method)), (q,)
    T = dk.fk(m, q)
    return (lambda T, key: dk.ik.solve(m, T, key=key)), (T, jax.random.key(1))


def _status_gb(field: str) -> float | None:
    """A memory field of ``/proc/self/status`` (``VmRSS``, ``VmHWM``) in GB; ``None`` without ``/proc``."""
    try:
        with open("/proc/self/status") as fh:
            return next(int(line.split()[1]) for line in fh if line.startswith(field + ":")) / 1e6  # kB -> GB
    except (OSError, StopIteration):
        return None


def _reset_peak() -> bool:
    """Reset this process's ``VmHWM`` to its current resident memory (Linux ``clear_refs``); whether it worked."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


#: a kernel's part: the first of these folders found on its call stack (collision, forward pass), else other
PARTS = ("/diffkin/collision/", "/diffkin/models/")
#: what a kernel does in the search: the first of these functions on its call stack
SITES = {
    "_iterate": "iterations",
    "Problem.screen_cost": "seed screening",
    "Problem.deferred_measure": "clearance check",
    "Problem.deferred_slack": "clearance check",  # (its name before 2026-11-30: older revisions on PYTHONPATH)
    "constraints_at": "clearance",
}


def _sections(text: str) -> dict[str, dict[int, str]]:
    """The numbered tables after a compiled module's HLO (``FileNames``, ``FunctionNames``, ``FileLocations``,
    ``StackFrames``: the call stacks that ``stack_frame_id`` names)."""
    out: dict[str, dict[int, str]] = {}
    table = None
    for line in text.splitlines():
        if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
            table = out.setdefault(line, {})
        elif table is not None and re.match(r"^\d+ ", line):
            number, rest = line.split(" ", 1)
            table[int(number)] = rest
        else:
            table = None
    return out


def kernels_by_part(text: str) -> list[tuple[str, int, int, int]]:
    """The kernels (fusions) of a compiled module by where the IK search calls them and what they compute:
    ``(site, collision, forward pass, other)`` per site, most kernels first. A site is the part of the
    search a kernel's call stack passes through (the first round, a pass of later rounds named by the line
    of ``_retry_unsolved`` that runs it, the final check) and what it does there (:data:`SITES`); a kernel's
    part is the first folder of :data:`PARTS` on its stack. Empty where the module has no stack tables."""
    t = _sections(text)
    if not t.get("StackFrames"):
        return []
    files = {k: v.strip('"') for k, v in t["FileNames"].items()}
    names = {k: v.strip('"').replace("<locals>.", "") for k, v in t["FunctionNames"].items()}
    where, frames = {}, {}
    for k, v in t["FileLocations"].items():
        f = dict(re.findall(r"(\w+)=(\d+)", v))
        where[k] = (files[int(f["file_name_id"])], names[int(f["function_name_id"])], int(f["line"]))
    for k, v in t["StackFrames"].items():
        f = dict(re.findall(r"(\w+)=(\d+)", v))
        frames[k] = (int(f["file_location_id"]), int(f["parent_frame_id"]) - 1)  # printed one above: 0 none

    def stack(frame: int) -> list[tuple[str, str, int]]:
        out = []
        while frame > 0:
            location, frame = frames[frame]
            out.append(where[location])
        return out[::-1]

    counts: dict[str, list[int]] = {}
    for line in text.splitlines():
        if " fusion(" not in line:
            continue
        found = re.search(r"stack_frame_id=(\d+)", line)
        calls = stack(int(found.group(1))) if found else []
        functions = [fn for _, fn, _ in calls]
        phase = next((f"later rounds (_retry_unsolved:{n})" for _, fn, n in calls if fn == "_retry_unsolved"), None)
        if phase is None and "search.phase" in functions:  # one loop: the first round's check, the final value
            phase = "the first round's check and the final value"
        phase = phase or ("the final check" if "constraints_at" in functions else "the first round")
        what = next((label for fn, label in SITES.items() if fn in functions), None)
        site = f"{phase}: {what}" if what else "the rest"
        part = min((k for f, _, _ in calls for k, folder in enumerate(PARTS) if folder in f), default=len(PARTS))
        counts.setdefault(site, [0, 0, 0])[part] += 1
    return sorted(((s, *c) for s, c in counts.items()), key=lambda r: -sum(r[1:]))


def run_case(work: str, model: str) -> dict:
    """Time trace, lower and compile of one case in this process (the subprocess side), and its own memory."""
    import jax

    from diffkin._xla import SOLVER_COMPILE

    f, args = case_function(work, model)
    rss_before = _status_gb("VmRSS")
    own = rss_before is not None and _reset_peak()
    t0 = time.perf_counter()
    # The IK compiles with the options dk.ik.solve gives its own jit (diffkin._xla.SOLVER_COMPILE).
    options = SOLVER_COMPILE if work.startswith("IK") else None
    traced = jax.jit(f, compiler_options=options).trace(*args)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2 = time.perf_counter()
    compiled = lowered.compile()
    t3 = time.perf_counter()
    text = compiled.as_text()
    if own:
        peak, source = _status_gb("VmHWM"), "VmHWM"
    else:  # no /proc: getrusage, which includes what the parent held when it started this process
        import resource

        peak, source = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, "ru_maxrss"
    return {
        "trace": t1 - t0,
        "lower": t2 - t1,
        "compile": t3 - t2,
        "kernels": text.count(" fusion("),
        "parts": kernels_by_part(text),
        "rss_before_gb": rss_before,
        "peak_gb": peak,
        "peak_source": source,
    }


def measure(work: str, model: str, timeout: float, max_gb: float, cache: str | None = None) -> dict:
    """One case in a fresh subprocess, stopped beyond ``timeout`` seconds or ``max_gb`` of resident memory;
    JAX's persistent cache in folder ``cache``, else off (cold)."""
    env = dict(
        os.environ,
        DIFFKIN_CACHE_DIR=cache or os.environ.get("DIFFKIN_CACHE_DIR", "off"),
        # a PYTHONPATH given (another checkout's diffkin, to compare) before this checkout
        PYTHONPATH=os.pathsep.join(filter(None, [os.environ.get("PYTHONPATH"), str(ROOT)])),
    )
    proc = subprocess.Popen(
        [sys.executable, __file__, "--case", work, model],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    start, peak, stopped = time.perf_counter(), 0.0, None
    while proc.poll() is None:
        time.sleep(0.2)
        try:
            with open(f"/proc/{proc.pid}/status") as fh:
                rss = next(int(line.split()[1]) for line in fh if line.startswith("VmRSS")) / 1e6
            peak = max(peak, rss)
        except (OSError, StopIteration):
            pass
        if time.perf_counter() - start > timeout:
            stopped = f"stopped after {timeout:.0f} s"
        elif peak > max_gb:
            stopped = f"stopped above {max_gb:g} GB"
        if stopped:
            proc.kill()
            proc.wait()
            return {"stopped": stopped}
    out, err = proc.communicate()
    if proc.returncode != 0:
        errors = [line for line in err.splitlines() if re.match(r"^[\w.]+(Error|Exception)\b", line)]
        return {"stopped": f"failed: {errors[-1] if errors else err.strip()[-300:] or proc.returncode}"}
    return json.loads(out.strip().splitlines()[-1])


def cases(parts, quick: bool = False) -> list[tuple[str, str]]:
    """The (work, model) pairs of the parts (``quick``: the first of them only, on the 7-joint arm)."""
    out = []
    for dof in QUICK_SIZES if quick else SIZES:
        if "fk" in parts:
            out.append(("FK", str(dof)))
        if "jacobian" in parts:
            out += [("Jacobian (analytic)", str(dof)), ("Jacobian (autodiff)", str(dof))]
        if "ik" in parts:
            out.append(("IK (LM defaults, 1,000 targets)", str(dof)))
    if quick:
        return out[:1]
    if "clutter" in parts and example_robot_data_root() is not None:
        out += [("IK (1 target)", "panda-mbm"), ("IK (1 target)", "panda-mbm-avoid")]
    if "ik" in parts or "ik-robots" in parts:
        out += [("IK (LM defaults, 1,000 targets)", model) for model in ROBOT_IK if erd_robot(ROBOT_IK[model][0])]
    if talos() is not None:
        out += [
            (w, "talos")
            for w in ("FK", "Jacobian (analytic)", "Jacobian (autodiff)")
            if (w == "FK" and "fk" in parts) or (w != "FK" and "jacobian" in parts)
        ]
    return out


NAMES = {
    "talos": "Talos (tree, 32 joints)",
    "7": "iiwa14 (7 joints)",
    "baxter": "Baxter, two grippers (2 poses)",
    "talos-contacts": "Talos, 2 soles + 2 grippers (4 poses), root solved",
    "g1-com": "Unitree G1 (URDF), 2 feet + a hand (3 poses), centre of mass (horizontal), root solved",
    "panda-avoid": "Panda with avoid= (capsules, 3 obstacles, 5 mm margin)",
    "panda-mbm": "Panda, one MotionBenchMaker target, no avoid=",
    "panda-mbm-avoid": "Panda, one MotionBenchMaker target, avoid= (hulls, its obstacles padded to 21, 5 mm margin)",
}


def rows(
    parts=("fk", "jacobian", "ik"), quick: bool = False, timeout: float = 300.0, max_gb: float = 4.0, by_part=None
):
    """Markdown rows ``[work, model, trace, lower, compile, kernels, peak memory]`` of every case; given a list
    ``by_part``, each case's ``(name, kernels_by_part rows)`` appended to it."""
    out = []
    for work, model in cases(parts, quick):
        r = measure(work, model, timeout, max_gb)
        name = NAMES.get(model, f"DH chain, {model} joints")
        if by_part is not None and r.get("parts"):
            by_part.append((name, r["parts"]))
        if "stopped" in r:
            out.append([work, name, r["stopped"], "", "", "", ""])
        else:
            before = "" if r["rss_before_gb"] is None else f" (before tracing {r['rss_before_gb']:.2f} GB)"
            upper = "" if r["peak_source"] == "VmHWM" else " (ru_maxrss: an upper bound)"
            out.append(
                [
                    work,
                    name,
                    f"{r['trace']:.2f} s",
                    f"{r['lower']:.2f} s",
                    f"{r['compile']:.2f} s",
                    f"{r['kernels']:,}",
                    f"{r['peak_gb']:.2f} GB{before}{upper}",
                ]
            )
        print(" | ".join(out[-1]), file=sys.stderr, flush=True)
    return out


def cache_rows(timeout: float = 300.0, max_gb: float = 4.0):
    """Markdown rows ``[model, first run, second run, second/first]`` of the IK cases, each run twice in fresh
    subprocesses sharing one fresh persistent-cache folder (trace + lower, then compile, of each run)."""
    import tempfile

    models = ["7", *[m for m in ROBOT_IK if erd_robot(ROBOT_IK[m][0])]]
    if example_robot_data_root() is not None:
        models.append("panda-avoid")
    out = []
    for model in models:
        with tempfile.TemporaryDirectory(prefix="diffkin-bench-cache-") as folder:
            runs = [measure("IK (LM defaults, 1,000 targets)", model, timeout, max_gb, folder) for _ in range(2)]
        name = NAMES.get(model, model)
        if any("stopped" in r for r in runs):
            out.append([name, *(r.get("stopped", "") for r in runs), ""])
        else:
            first, second = (f"{r['trace'] + r['lower']:.2f} s + {r['compile']:.2f} s" for r in runs)
            total = [r["trace"] + r["lower"] + r["compile"] for r in runs]
            ratio = runs[1]["compile"] / runs[0]["compile"]
            out.append([name, first, second, f"{total[1] / total[0]:.2f} (compile {ratio:.3f})"])
        print(" | ".join(out[-1]), file=sys.stderr, flush=True)
    return out


CACHE_HEADER = ["IK case (1,000 targets)", "first run: trace + lower, compile", "second run", "second / first"]
PART_HEADER = ["call site (the search's functions)", "collision", "forward pass", "other", "kernels"]
HEADER = ["work", "model", "trace", "lower", "compile", "kernels", "peak resident memory of the case's own process"]
MEMORY = (
    "Memory: each case's own subprocess, its peak resident memory while tracing, lowering and compiling "
    "(`VmHWM` of `/proc/self/status`, reset just before tracing), and its resident memory just before tracing "
    "(JAX, numpy and the model loaded); not `getrusage`, which in a subprocess starts from the parent's peak."
)


def section(quick: bool = False) -> str:
    """The markdown section of ``experiments/bench.py``: a heading, what was measured, and the table."""
    from _bench import table  # the parent only: a case's subprocess imports neither torch nor pk

    about = (
        f"`jax.jit(f).trace(x)`, `.lower()`, `.compile()` timed apart, float32, batch {BATCH:,}, each case "
        "in a fresh subprocess; cases stopped after 300 s or above 4 GB say so."
    )
    return "\n\n".join(["## Compile cost (the first call)", about, MEMORY, table(HEADER, rows(quick=quick))])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", nargs=2, metavar=("WORK", "MODEL"), help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="the first case only (FK of the 7-joint arm)")
    parser.add_argument(
        "--only",
        default="fk,jacobian,ik",
        help="comma-separated parts: fk,jacobian,ik (ik includes ik-robots),clutter (MotionBenchMaker, with and "
        "without avoid=)",
    )
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per case (default 300)")
    parser.add_argument("--max-gb", type=float, default=4.0, help="resident memory per case (default 4 GB)")
    parser.add_argument("--cache", action="store_true", help="the IK cases' second runs with JAX's persistent cache")
    parser.add_argument(
        "--parts",
        action="store_true",
        help="also each case's kernels by the search's call site and by part (collision, forward pass, other)",
    )
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(*args.case)))
        return 0
    from _bench import busy_note, machine_line, table

    if args.cache:
        body = cache_rows(args.timeout, args.max_gb)
        paragraphs = ["# diffkin: what the persistent cache saves a second run", machine_line(), busy_note()]
        print("\n\n".join([p for p in paragraphs if p] + [table(CACHE_HEADER, body)]))
        return 0

    by_part: list = []
    body = rows(tuple(args.only.split(",")), args.quick, args.timeout, args.max_gb, by_part)
    paragraphs = ["# diffkin compile cost", machine_line(), busy_note(), MEMORY, table(HEADER, body)]
    if args.parts:
        for name, parts in by_part:
            lines = [[site, *(f"{k:,}" for k in (*c, sum(c)))] for site, *c in parts]
            paragraphs += [f"Kernels of {name}, by call site:", table(PART_HEADER, lines)]
    print("\n\n".join(p for p in paragraphs if p))
    return 0


if __name__ == "__main__":
    sys.exit(main())
