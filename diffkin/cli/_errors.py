"""User errors of the command line: one line ``diffkin: error: ...`` with exit status 2."""

from __future__ import annotations

import importlib
import re

# Python parameter names in messages of diffkin's functions, and the flags that set them
_FLAGS = {
    "end_link": "--end-link",
    "base_link": "--base-link",
    "voxel_size": "--voxel",
    "n_samples": "--samples",
    "num_seeds": "--seeds",
    "pos_tol": "--pos-tol",
    "rot_tol": "--rot-tol",
    "q0": "--q0",
}
# the extra that provides each optional module
EXTRAS = {
    "optax": "ik",
    "matplotlib": "plot",
    "tqdm": "progress",
    "torch": "validate",
    "pytorch_kinematics": "validate",
    "pinocchio": "validate",
}


class CLIError(Exception):
    """A user error: reported as one line ``diffkin: error: ...`` with exit status 2."""


def need(module: str, what: str, extra: str = "demo"):
    """Import an optional dependency, or a one-line CLIError naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise CLIError(
            f"{what} needs {module}, which is not installed: pip install 'diffkin[{extra}]' (or pip install {module})"
        ) from None


def with_flags(message: str) -> str:
    """A message of diffkin's library with its Python parameter names replaced by the CLI's flags."""
    for name, flag in _FLAGS.items():
        message = re.sub(rf"(?<![\w'\"-]){name}\b(?!['\"])", flag, message)  # not a quoted link name
    return message
