"""Test settings: float64 enabled (float32 tests pass float32 arrays explicitly), strict promotion off,
warnings are errors (pyproject), and shared robot fixtures."""

import contextlib
import os
import signal

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
# The CLI's persistent compilation cache stays off in tests (and their subprocesses) unless a test asks.
os.environ["DIFFKIN_CACHE_DIR"] = "off"

import diffkin as dk  # noqa: E402

DATA = os.path.join(os.path.dirname(__file__), "data")

# URDF robots of the validation: (name, path, end link); built once per session.
URDF_ROBOTS = {
    "iiwa7": (dk.robots.urdf_path("iiwa7"), "iiwa7_link_ee"),
    "iiwa14": (dk.robots.urdf_path("iiwa14"), "iiwa14_link_ee"),
    "panda": (os.path.join(DATA, "panda.urdf"), "panda_link8"),
    "ur5": (os.path.join(DATA, "ur5.urdf"), "tool0"),
}
BUILTIN = dk.robots.BUILTIN


@contextlib.contextmanager
def time_limit(seconds: float, what: str):
    """Fail (``TimeoutError``) if the block runs longer than ``seconds``: a hang fails a test instead of stalling CI.

    SIGALRM interrupts Python code only (not a running XLA computation); main thread, POSIX.
    """

    def expire(signum, frame):
        raise TimeoutError(f"{what}: still running after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def random_q(chain, n, seed=0):
    """``(n, dof)`` float64 configurations uniform within limits (unlimited joints over one turn)."""
    lo = np.where(np.isfinite(chain.lower), chain.lower, -np.pi)
    hi = np.where(np.isfinite(chain.upper), chain.upper, np.pi)
    return np.random.default_rng(seed).uniform(lo, hi, (n, chain.dof))


@pytest.fixture(scope="session")
def urdf_chains():
    return {name: dk.load_urdf(path, end) for name, (path, end) in URDF_ROBOTS.items()}
