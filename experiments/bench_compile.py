"""What the first call costs: trace, lower and compile times, and the compile's peak memory.

    python experiments/bench_compile.py [--quick] [--only fk,jacobian,ik] [--timeout 300] [--max-gb 4]

For FK, the world Jacobian (analytic, the default, and autodiff) and the default IK
(``dk.ik.solve``, 1,000 targets) of synthetic DH chains of 7, 20 and 50 joints (IK: the iiwa14
and chains of 20 and 50 joints), and for FK and Jacobians of a whole tree (Talos from
example-robot-data, 32 joints, 60 frames, where installed): ``jax.jit(f).trace(x)``,
``.lower()`` and ``.compile()`` timed separately, float32 (the IK with the compiler options
``dk.ik.solve`` gives its own ``jit``). Each case runs in a fresh subprocess
(so nothing is cached between cases) whose peak resident memory (``ru_maxrss``) is reported,
with the same process's resident memory just before tracing (JAX and the model loaded) for
reference; a case is stopped after ``--timeout`` seconds or above ``--max-gb`` GB and reported
as such. The batch (1,000 configurations) does not change what is compiled.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

SIZES = (7, 20, 50)
QUICK_SIZES = (7,)
BATCH = 1000


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


def talos():
    """Talos (example-robot-data, ``talos_full_v2.urdf``) as a :class:`dk.Robot`; ``None`` if not installed."""
    from importlib import metadata

    import diffkin as dk

    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        return None
    path = Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))
    path = path / "talos_data" / "robots" / "talos_full_v2.urdf"
    return dk.load_robot(str(path)) if path.is_file() else None


def case_function(work: str, model: str):
    """``(f, args)`` of one case: a function of arrays and its float32 arguments."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import diffkin as dk

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


def run_case(work: str, model: str) -> dict:
    """Time trace, lower and compile of one case in this process (the subprocess side)."""
    import jax

    from diffkin._xla import SOLVER_COMPILE

    f, args = case_function(work, model)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB -> GB
    t0 = time.perf_counter()
    # The IK compiles with the options dk.ik.solve gives its own jit (diffkin._xla.SOLVER_COMPILE).
    options = SOLVER_COMPILE if work.startswith("IK") else None
    traced = jax.jit(f, compiler_options=options).trace(*args)
    t1 = time.perf_counter()
    lowered = traced.lower()
    t2 = time.perf_counter()
    lowered.compile()
    t3 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    return {"trace": t1 - t0, "lower": t2 - t1, "compile": t3 - t2, "rss_before_gb": rss_before, "peak_gb": peak}


def measure(work: str, model: str, timeout: float, max_gb: float) -> dict:
    """One case in a fresh subprocess, stopped beyond ``timeout`` seconds or ``max_gb`` of resident memory."""
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]),
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
        return {"stopped": f"failed: {err.strip().splitlines()[-1] if err.strip() else proc.returncode}"}
    return json.loads(out.strip().splitlines()[-1])


def cases(parts, sizes) -> list[tuple[str, str]]:
    """The (work, model) pairs of the parts."""
    out = []
    for dof in sizes:
        if "fk" in parts:
            out.append(("FK", str(dof)))
        if "jacobian" in parts:
            out += [("Jacobian (analytic)", str(dof)), ("Jacobian (autodiff)", str(dof))]
        if "ik" in parts:
            out.append(("IK (LM defaults, 1,000 targets)", str(dof)))
    if talos() is not None:
        out += [
            (w, "talos")
            for w in ("FK", "Jacobian (analytic)", "Jacobian (autodiff)")
            if (w == "FK" and "fk" in parts) or (w != "FK" and "jacobian" in parts)
        ]
    return out


def rows(parts=("fk", "jacobian", "ik"), quick: bool = False, timeout: float = 300.0, max_gb: float = 4.0):
    """Markdown rows ``[work, model, trace, lower, compile, peak memory]`` of every case."""
    out = []
    for work, model in cases(parts, QUICK_SIZES if quick else SIZES):
        r = measure(work, model, timeout, max_gb)
        name = (
            "Talos (tree, 32 joints)"
            if model == "talos"
            else ("iiwa14 (7 joints)" if model == "7" else f"DH chain, {model} joints")
        )
        if "stopped" in r:
            out.append([work, name, r["stopped"], "", "", ""])
        else:
            out.append(
                [
                    work,
                    name,
                    f"{r['trace']:.2f} s",
                    f"{r['lower']:.2f} s",
                    f"{r['compile']:.2f} s",
                    f"{r['peak_gb']:.2f} GB (before tracing {r['rss_before_gb']:.2f} GB)",
                ]
            )
        print(" | ".join(out[-1]), file=sys.stderr, flush=True)
    return out


HEADER = ["work", "model", "trace", "lower", "compile", "peak memory of the process"]


def section(quick: bool = False) -> str:
    """The markdown section of ``experiments/bench.py``: a heading, what was measured, and the table."""
    from _bench import table  # the parent only: a case's subprocess imports neither torch nor pk

    about = (
        f"`jax.jit(f).trace(x)`, `.lower()`, `.compile()` timed apart, float32, batch {BATCH:,}, each case "
        "in a fresh subprocess (peak resident memory, and the same process just before tracing); cases "
        "stopped after 300 s or above 4 GB say so."
    )
    return "\n\n".join(["## Compile cost (the first call)", about, table(HEADER, rows(quick=quick))])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", nargs=2, metavar=("WORK", "MODEL"), help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="the 7-joint cases (and Talos) only")
    parser.add_argument("--only", default="fk,jacobian,ik", help="comma-separated parts: fk,jacobian,ik")
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per case (default 300)")
    parser.add_argument("--max-gb", type=float, default=4.0, help="resident memory per case (default 4 GB)")
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(*args.case)))
        return 0
    from _bench import busy_note, machine_line, table

    body = rows(tuple(args.only.split(",")), args.quick, args.timeout, args.max_gb)
    print("\n\n".join(p for p in ["# diffkin compile cost", machine_line(), busy_note(), table(HEADER, body)] if p))
    return 0


if __name__ == "__main__":
    sys.exit(main())
