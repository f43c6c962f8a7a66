"""Where the tests' files are, and how they run the command: the checkout's folders, and ``python -m diffkin``
with Ctrl-C handled as usual. (``tests/conftest.py`` puts ``tests/`` on ``sys.path``: every tier imports
the helper modules ``_paths``, ``_models``, ``_reference``, ``_shapes``, ``_mjcf`` and ``_fuzzing``; test
modules do not import each other.)"""

from __future__ import annotations

import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(TESTS)
"""The source checkout (``pyproject.toml``, ``docs/``, ``experiments/``)."""
DATA = os.path.join(TESTS, "data")
EXPERIMENTS = os.path.join(ROOT, "experiments")

#: ``python -m diffkin`` with Ctrl-C handled as usual even when started from a shell's background
#: job (which inherits SIGINT ignored): ``[*INTERRUPTIBLE, "demo", ...]``.
INTERRUPTIBLE = [
    sys.executable,
    "-c",
    "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "sys.argv = sys.argv[1:]; runpy.run_module('diffkin', run_name='__main__', alter_sys=True)",
    "diffkin",
]
