"""Shared helpers of the benchmark scripts: timing, machine description, markdown tables, and the
pytorch-kinematics side (optional: ``pk`` and ``torch`` are ``None`` where it is not installed)."""

from __future__ import annotations

import atexit
import dataclasses
import gc
import importlib.metadata
import os
import platform
import re
import shutil
import statistics
import tempfile
import time

try:
    import resource
except ImportError:  # not on Windows
    resource = None

import jax
import numpy as np

import diffkin as dk

# First calls are timed cold: JAX's persistent cache, on by default for diffkin's users, stays off in the
# benchmarks and their subprocesses unless DIFFKIN_CACHE_DIR names a folder.
os.environ.setdefault("DIFFKIN_CACHE_DIR", "off")

if "TORCHINDUCTOR_CACHE_DIR" not in os.environ:
    # torch.compile keeps what it compiled on disk and reuses it in later processes: a fresh folder per run makes
    # pytorch-kinematics' compiled first call a cold start, as diffkin's is.
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="diffkin-bench-inductor-")
    atexit.register(shutil.rmtree, os.environ["TORCHINDUCTOR_CACHE_DIR"], ignore_errors=True)

try:
    import pytorch_kinematics as pk
    import torch
except ImportError:
    pk = torch = None

PK_IK_TOL = (1e-3, 1e-2)  # pytorch-kinematics' default IK tolerances: 1 mm, 0.01 rad


def example_robot_data() -> str:
    """The ``robots`` folder of example-robot-data: ``$EXAMPLE_ROBOT_DATA`` (a copy of it, as carried to a
    machine without the validation install) if set, else the installed package's."""
    robots = os.environ.get("EXAMPLE_ROBOT_DATA")
    if robots is not None:
        return os.path.abspath(robots)
    share = importlib.metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share")
    return os.path.join(str(share), "example-robot-data", "robots")


def median_seconds(fn, *args, repeats: int = 5, warmup: int = 2, min_time: float = 0.3) -> float:
    """Median wall time of ``fn(*args)`` (outputs blocked on), after ``warmup`` untimed calls.

    Times at least ``repeats`` calls and keeps going until ``min_time`` seconds have been timed, so
    that microsecond calls get thousands of samples and a stable median. The calls follow each other
    with nothing in between: a gap lets the runtime's worker threads fall asleep, and waking them
    costs tens of microseconds per call (re-summing the list of times each call once made FK of one
    configuration read 45 us instead of 5 us).
    """
    for _ in range(warmup):
        jax.block_until_ready(fn(*args))
    times, total = [], 0.0
    while len(times) < repeats or total < min_time:
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
        total += times[-1]
    return statistics.median(times)


def median_seconds_interleaved(calls: list, rounds: int = 10, min_time: float = 0.3) -> list[float]:
    """Median wall times of several ``(fn, args)`` timed in turns, as :func:`median_seconds` each.

    Each round times every call for ``min_time / rounds`` seconds (at least one call), one after the
    other, so that a slow spell of a shared machine falls on all of them alike instead of on
    whichever ran then (a call of 0.2 ms measured in separate minutes moved by 50 %).
    """
    samples: list[list[float]] = [[] for _ in calls]
    for fn, args in calls:
        jax.block_until_ready(fn(*args))
    for _ in range(rounds):
        for (fn, args), times in zip(calls, samples, strict=True):
            total, first = 0.0, True
            while first or total < min_time / rounds:
                start = time.perf_counter()
                jax.block_until_ready(fn(*args))
                times.append(time.perf_counter() - start)
                total, first = total + times[-1], False
    return [statistics.median(times) for times in samples]


def page_faults_per_call(fn, *args, calls: int = 10) -> float | None:
    """Mean minor page faults of one warm call of ``fn(*args)`` (``None`` where the OS does not count them).

    Thousands per call mean the allocator hands every call fresh pages that the kernel must map and
    zero: glibc serves blocks above its mmap threshold (at most 32 MiB) with a new ``mmap`` each time.
    """
    if resource is None:
        return None
    jax.block_until_ready(fn(*args))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(calls):
        jax.block_until_ready(fn(*args))
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / calls


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``, else what :mod:`platform` knows)."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def cpu_cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def _accelerator() -> str | None:
    """``"<device kind> x<count>"`` of JAX's default devices when they are not the CPU."""
    devices = jax.devices()
    return None if devices[0].platform == "cpu" else f"{devices[0].device_kind} x{len(devices)}"


def machine_line() -> str:
    """One line naming the machine, the JAX devices, the software versions and JAX's memory settings (GPU)."""
    devices = jax.devices()
    parts = [
        f"CPU: {cpu_model()} ({cpu_cores()} cores)",
        f"jax {jax.__version__}",
        f"jax devices: {devices[0].device_kind} x{len(devices)}",
    ]
    if pk is not None:
        parts += [
            f"torch {torch.__version__} on {torch_device()}",
            f"pytorch-kinematics {importlib.metadata.version('pytorch-kinematics')}",
        ]
    parts += [f"{k}={v}" for k, v in sorted(os.environ.items()) if k.startswith("XLA_PYTHON_CLIENT_")]
    return ", ".join(parts)


def busy_note() -> str:
    """A warning when other processes load the CPU (1-minute load average above half the cores), else ``""``."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    if load <= cpu_cores() / 2:
        return ""
    return (
        f"**The machine was busy** (1-minute load average {load:.1f} on {cpu_cores()} cores before the run): "
        "these timings are unreliable."
    )


def machine_slug() -> str:
    """A file name for this machine: the accelerator, else the CPU model and core count (``amd-epyc-2-cores``)."""
    name = _accelerator() or f"{cpu_model()} {cpu_cores()} cores"
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def publish(parts: list[str], name: str | None = None) -> None:
    """Print a report, its non-empty ``parts`` joined by blank lines; with ``name``, also write it to
    ``experiments/results/<machine>-<name>.md`` (:func:`machine_slug`)."""
    text = "\n\n".join(p for p in parts if p)
    print("\n" + text)
    if name is not None:
        out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", f"{machine_slug()}-{name}.md")
        with open(out, "w") as fh:
            fh.write(text + "\n")
        print(f"\n# written: {out}")


def rate(n: int, seconds: float) -> str:
    """Throughput ``n / seconds`` in a readable unit."""
    per_s = n / seconds
    if per_s >= 1e5:
        return f"{per_s / 1e6:.2f} M/s"
    return f"{per_s / 1e3:.1f} k/s" if per_s >= 1e3 else f"{per_s:.0f}/s"


def duration(seconds: float) -> str:
    """A time in s, ms or us with three significant digits."""
    if seconds >= 1:
        return f"{seconds:.3g} s"
    return f"{seconds * 1e3:.3g} ms" if seconds >= 1e-3 else f"{seconds * 1e6:.3g} us"


def random_configs(chain, n: int, dtype, seed: int = 0) -> np.ndarray:
    """``(n, dof)`` configurations uniform within the joint limits of ``chain``."""
    return np.random.default_rng(seed).uniform(chain.lower, chain.upper, (n, chain.dof)).astype(dtype)


# --------------------------------------------------------------------------------------------- pytorch-kinematics


def torch_device() -> str:
    """``"cuda"`` where torch sees a GPU, else ``"cpu"``."""
    return "cuda" if torch.cuda.is_available() else "cpu"


def torch_synced(fn):
    """``fn`` followed by waiting for the GPU (torch runs CUDA kernels asynchronously), for timing."""
    if torch_device() == "cpu":
        return fn

    def synced(*args):
        out = fn(*args)
        torch.cuda.synchronize()
        return out

    return synced


def release_torch_memory() -> None:
    """Give torch's cached GPU memory back to the device (JAX allocates from the same GPU); nothing on a CPU."""
    if torch_device() == "cuda":
        gc.collect()
        torch.cuda.empty_cache()


def to_torch(x: np.ndarray):
    """A numpy array as a torch tensor on :func:`torch_device`."""
    return torch.as_tensor(x, device=torch_device())


def pk_chain(name: str, end_link: str, dtype: str):
    """pytorch-kinematics' serial chain of diffkin's shipped URDF ``name``, in ``dtype``, on :func:`torch_device`."""
    with open(dk.robots.urdf_path(name), "rb") as fh:
        chain = pk.build_serial_chain_from_urdf(fh.read(), end_link)
    return chain.to(dtype=getattr(torch, dtype), device=torch_device())  # .to() rebinds this fresh chain


def first_call_seconds(fn, *args) -> float:
    """Wall time of one call of ``fn(*args)``, outputs blocked on: the first call, compile included."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - start


def pk_ik_solver(
    chain,
    lower,
    upper,
    *,
    iterations: int = 30,
    retries: int = 10,
    tol=PK_IK_TOL,
    compiled: bool = False,
    seed: int = 0,
):
    """pytorch-kinematics' ``PseudoInverseIK`` of ``chain`` within ``[lower, upper]`` (float32).

    ``compiled``: its ``use_compile=True`` (``torch.compile`` of its FK, Jacobian and step kernels; the
    first solve compiles them). The solver draws its ``retries`` starting configurations once, when it
    is built, from torch's global RNG (the same ones for every target and every solve): ``seed`` seeds
    that RNG just before, so a run is reproducible (seeding before a solve changes nothing).
    """
    limits = to_torch(np.stack([lower, upper], -1).astype(np.float32))
    torch.manual_seed(seed)
    return pk.PseudoInverseIK(
        chain,
        max_iterations=iterations,
        num_retries=retries,
        joint_limits=limits,
        early_stopping_any_converged=True,
        pos_tolerance=tol[0],
        rot_tolerance=tol[1],
        use_compile=compiled,
    )


@dataclasses.dataclass
class PkIK:
    """pytorch-kinematics' IK of a batch of targets: the run that worked, and the draws of retries that raised."""

    first: float | None = None  # seconds of the first call (compile included when compiled); None: every draw raised
    seconds: float | None = None  # median seconds of the warm calls
    success: float | None = None  # fraction of targets within its tolerance
    seed: int | None = None  # the seed of the retries of the run that worked
    failures: list[tuple[int, float, str]] = dataclasses.field(default_factory=list)  # (seed, seconds, message)

    def note(self) -> str:
        """What a reader needs besides the time: the draws that raised, and the seed that was timed."""
        failed = [f"retries from seed {s} raised LinAlgError after {duration(t)} ({m})" for s, t, m in self.failures]
        timed = [f"timed with the retries of seed {self.seed}"] if self.failures and self.seed is not None else []
        return "; ".join(failed + timed)


def pk_ik_timed(
    chain, lower, upper, goal, *, compiled: bool, seeds=(0, 1, 2), repeats: int = 3, warmup: int = 1, min_time=0.3
):
    """Time ``PseudoInverseIK.solve(goal)`` (:func:`pk_ik_solver`), its first call apart, from the retries of
    ``seeds[0]``; where a solve raises ``torch.linalg.LinAlgError`` (its damped least squares met a singular
    matrix), the failure is recorded and the next seed's retries are tried (a later compiled first call then
    finds torch.compile's caches warm)."""
    out = PkIK()
    for seed in seeds:
        solver = pk_ik_solver(chain, lower, upper, compiled=compiled, seed=seed)
        solve, start = torch_synced(solver.solve), time.perf_counter()
        try:
            first = first_call_seconds(solve, goal)
            seconds = median_seconds(solve, goal, repeats=repeats, warmup=warmup, min_time=min_time)
            success = float(solver.solve(goal).converged_any.float().mean())
        except torch.linalg.LinAlgError as e:
            out.failures.append((seed, time.perf_counter() - start, str(e).split(":")[-1].strip().rstrip(".")))
            continue
        finally:
            release_torch_memory()
        out.first, out.seconds, out.success, out.seed = first, seconds, success, seed
        break
    return out
