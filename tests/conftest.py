"""Test settings: float64 enabled (float32 tests pass float32 arrays explicitly), strict promotion off,
warnings are errors (pyproject), shared robot fixtures, and the tiers.

The tests live in three directories, by what they need (CONTRIBUTING.md): ``unit/`` (diffkin, numpy,
scipy, jax, optax, hypothesis: ``pip install -e ".[dev]"``), ``validation/`` (other libraries: Pinocchio,
MuJoCo, pytorch-kinematics, coal, example-robot-data, dm_control, real meshes) and ``integration/``
(subprocesses, the CLI, the viewer's server, benchmarks and experiments, the docs' examples). Each test
is marked with its directory's name (``-m unit``); tests outside the unit tier are also ``slow``, so
``-m "not slow"`` selects the unit tier. Shared helpers: ``tests/_reference.py`` (``tests/`` is put on
``sys.path`` here, so every tier imports it as ``_reference``)."""

import os
import sys
from pathlib import Path

import jax
import pytest

jax.config.update("jax_enable_x64", True)
# The CLI's persistent compilation cache stays off in tests (and their subprocesses) unless a test asks.
os.environ["DIFFKIN_CACHE_DIR"] = "off"


def _compilation_cache() -> str | None:
    """The folder of the test runs' own persistent compilation cache, or ``None``: ``DIFFKIN_TEST_CACHE_DIR``
    (``off``, empty, ``0``, ``false``, ``no``, ``none``: no cache), else ``$XDG_CACHE_HOME/diffkin/jax-tests``
    (``~/.cache``), outside the repository."""
    env = os.environ.get("DIFFKIN_TEST_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in ("", "0", "off", "false", "no", "none") else env
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "diffkin", "jax-tests")


# Most of a test run is XLA compiling: with JAX's persistent cache, a rerun compiles only the programs
# that changed (keys hold the program, the flags and the versions, not source lines; at most 4 GiB, least
# recently used out). Every program is kept, the small ones too: the ~2,100 small programs (eager
# operations, 10-30 ms each) are read back faster than they compile (CONTRIBUTING.md has the figures).
if (_cache := _compilation_cache()) is not None:
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    jax.config.update("jax_compilation_cache_max_size", 4 * 2**30)

TESTS = Path(__file__).resolve().parent
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))

from _reference import URDF_ROBOTS  # noqa: E402

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
