"""Test settings: float64 enabled (float32 tests pass float32 arrays explicitly), strict promotion off,
warnings are errors (pyproject), shared robot fixtures, and the tiers.

The tests live in three directories, by what they need (CONTRIBUTING.md): ``unit/`` (diffkin, numpy,
jax, optax, hypothesis: ``pip install -e ".[dev]"``), ``validation/`` (other libraries: Pinocchio,
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
