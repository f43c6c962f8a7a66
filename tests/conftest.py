"""Test settings: float64 enabled (float32 tests pass float32 arrays explicitly), strict promotion off,
warnings are errors (pyproject), a mesh-fit cache of their own, shared robot fixtures, and the tiers.

The tests live in three directories, by what they need (CONTRIBUTING.md): ``unit/`` (diffkin, numpy,
scipy, jax, optax, hypothesis: ``pip install -e ".[dev]"``), ``validation/`` (other libraries: Pinocchio,
MuJoCo, pytorch-kinematics, coal, example-robot-data, dm_control, real meshes) and ``integration/``
(subprocesses, the CLI, the viewer's server, benchmarks and experiments, the docs' examples). Each test
is marked with its directory's name (``-m unit``); tests outside the unit tier are also ``slow``, so
``-m "not slow"`` selects the unit tier. Shared helpers, one module per kind (``tests/`` is put on
``sys.path`` here, so every tier imports them): ``_paths``, ``_models`` (test robots, every model kind,
random configurations), ``_reference`` (independent NumPy and Pinocchio references), ``_shapes``,
``_mjcf`` and ``_fuzzing``."""

import atexit
import ctypes
import gc
import os
import shutil
import sys
import tempfile
from pathlib import Path

import jax
import pytest

jax.config.update("jax_enable_x64", True)
# The CLI's persistent compilation cache stays off in tests (and their subprocesses) unless a test asks.
os.environ["DIFFKIN_CACHE_DIR"] = "off"
# Mesh fits are cached on disk (diffkin.collision._fitcache): the tests and their subprocesses use a folder of
# their own, removed at exit, never the user's.
_FIT_CACHE = tempfile.mkdtemp(prefix="diffkin-fit-cache-")
os.environ["DIFFKIN_FIT_CACHE"] = _FIT_CACHE
atexit.register(shutil.rmtree, _FIT_CACHE, ignore_errors=True)


def _off(value: str) -> bool:
    return value.strip().lower() in ("", "0", "off", "false", "no", "none")


def _compilation_cache() -> str | None:
    """The folder of the test runs' own persistent compilation cache, or ``None``: ``DIFFKIN_TEST_CACHE_DIR``
    (``off``, empty, ``0``, ``false``, ``no``, ``none``: no cache), else ``$XDG_CACHE_HOME/diffkin/jax-tests``
    (``~/.cache``), outside the repository. An xdist worker takes a folder of its own in it (``gw0``, ...):
    JAX writes an entry in place, so a worker reading an entry another is writing got a ``ZstdError``
    warning, which the tests' ``filterwarnings = error`` made a collection error."""
    env = os.environ.get("DIFFKIN_TEST_CACHE_DIR")
    if env is not None and _off(env):
        return None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = env if env is not None else os.path.join(base, "diffkin", "jax-tests")
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    return os.path.join(folder, worker) if worker else folder


# Most of a test run is XLA compiling: with JAX's persistent cache, a rerun compiles only the programs
# that changed (keys hold the program, the flags and the versions, not source lines). Every program is
# kept, the small ones too (eager operations): they are read back faster than they compile. JAX's own size
# limit stays off: with one, each write lists the folder and reads every entry's access time (its LRU
# bookkeeping), which cost a run from an empty folder more than the cache saved (docs/performance.md); the
# controller bounds the folder instead, once per run, before any worker starts.
CACHE_MAX_BYTES = 4 * 2**30


def _bound(folder: Path, max_bytes: int) -> None:
    """Delete the oldest files of ``folder`` and its workers' folders (by modification time) until they hold at
    most ``max_bytes``."""
    files = sorted((s.st_mtime, s.st_size, p) for p in folder.rglob("*") if p.is_file() for s in [p.stat()])
    total = sum(size for _, size, _ in files)
    for _, size, path in files:
        if total <= max_bytes:
            break
        path.unlink(missing_ok=True)
        total -= size


if (_cache := _compilation_cache()) is not None:
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if "PYTEST_XDIST_WORKER" not in os.environ and os.path.isdir(_cache):
        _bound(Path(_cache), CACHE_MAX_BYTES)

# The tests check values, not speed, so this process compiles for compile time: LLVM at -O0
# (``jax_disable_most_optimizations``) and XLA's classic CPU emitter (``dk.ik.solve``'s solvers use it
# anyway, ``diffkin._xla.SOLVER_COMPILE``): about a third of the compile time (docs/install.md). The same
# computations: no fast math, results within the last bits. XLA reads ``XLA_FLAGS`` once, at the first
# compile, so the user's ``XLA_FLAGS`` come back after it: subprocesses (the CLI, the docs' examples,
# the benchmarks) run with the options users get. ``DIFFKIN_TEST_FAST_COMPILE=off``: users' options here too.
if not _off(os.environ.get("DIFFKIN_TEST_FAST_COMPILE", "on")):
    jax.config.update("jax_disable_most_optimizations", True)
    _users_flags = os.environ.get("XLA_FLAGS")
    os.environ["XLA_FLAGS"] = " ".join(f for f in ("--xla_cpu_use_fusion_emitters=false", _users_flags) if f)
    jax.jit(lambda x: x + 1)(0.0)
    if _users_flags is None:
        del os.environ["XLA_FLAGS"]
    else:
        os.environ["XLA_FLAGS"] = _users_flags

TESTS = Path(__file__).resolve().parent
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))

from _models import URDF_ROBOTS  # noqa: E402

import diffkin as dk  # noqa: E402

TIERS = ("unit", "validation", "integration")


@pytest.hookimpl(tryfirst=True)  # before -m deselects by the markers
def pytest_collection_modifyitems(config, items):
    """Mark each test with its tier, the directory it lives in (``slow`` too outside ``unit/``)."""
    for item in items:
        parts = Path(item.path).resolve().relative_to(TESTS).parts
        tier = parts[0] if len(parts) > 1 else None
        if tier not in TIERS:
            raise pytest.UsageError(f"{item.nodeid}: a test lives in tests/unit, tests/validation or tests/integration")
        item.add_marker(tier)
        if tier != "unit":
            item.add_marker("slow")


@pytest.fixture(scope="session")
def urdf_chains():
    return {name: dk.load_urdf(path, end) for name, (path, end) in URDF_ROBOTS.items()}


# A worker keeps every program it compiled: module after module, the two workers together had filled the
# machine's memory by the end of the suite and XLA failed while compiling (a segmentation fault). Past this
# size a module's programs are dropped when it ends (the next module that needs one reads it back from the
# run's persistent cache) and freed memory goes back to the system.
RESIDENT_LIMIT_BYTES = 2 * 2**30


def _resident_bytes() -> int:
    """This process's resident memory (bytes) on Linux; elsewhere the limit itself (programs always dropped)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return RESIDENT_LIMIT_BYTES


@pytest.fixture(autouse=True, scope="module")
def _bounded_memory():
    yield
    if _resident_bytes() >= RESIDENT_LIMIT_BYTES:
        jax.clear_caches()
        gc.collect()
        trim = getattr(ctypes.CDLL(None), "malloc_trim", None) if sys.platform == "linux" else None
        if trim is not None:  # glibc's: return the freed arenas' pages
            trim(0)
