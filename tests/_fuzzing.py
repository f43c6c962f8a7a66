"""The property tests' budgets and strategies, and a time limit that fails a hanging test."""

from __future__ import annotations

import contextlib
import os
import signal

import hypothesis
import hypothesis.strategies

EXAMPLES = int(os.environ.get("DIFFKIN_FUZZ_EXAMPLES", "25"))
FUZZ = hypothesis.settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize="DIFFKIN_FUZZ_EXAMPLES" not in os.environ,
    suppress_health_check=[hypothesis.HealthCheck.too_slow, hypothesis.HealthCheck.data_too_large],
)
"""Property tests: ``DIFFKIN_FUZZ_EXAMPLES`` examples each (25, derandomized, unless set)."""
# MJCF examples run under a SIGALRM limit (a hang, such as an include bomb, fails the test instead of
# stalling CI) and a hypothesis deadline (an example slower than that is reported).
MJCF_FUZZ = hypothesis.settings(FUZZ, deadline=5000)
MJCF_TIME_LIMIT = 20.0


def finite_floats(lo, hi):
    return hypothesis.strategies.floats(lo, hi, allow_nan=False, allow_infinity=False)


def number_text(values) -> str:
    """Numbers as an XML attribute's text: ``"0.1 2.0 -3.5"``."""
    return " ".join(repr(float(v)) for v in values)


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
