"""The obstacles of ``--avoid SCENE.json`` (``ik``, ``place``, ``view``): a ``dk.collision.Scene`` read for the
commands."""

from __future__ import annotations

import dataclasses

from diffkin.cli._errors import CLIError
from diffkin.cli._robots import jax_x64


def read_scene(path: str, margin: float | None):
    """The ``dk.collision.Scene`` of ``--avoid PATH`` in float64, its margin replaced by ``--margin``.

    Raises:
        CLIError: a file that cannot be read or is not a valid scene (the message names the field).
    """
    jax_x64()  # the obstacles' arrays in float64
    from diffkin.collision import load_scene

    try:
        scene = load_scene(path)
    except (OSError, ValueError) as e:
        raise CLIError(f"--avoid: {e}") from None
    return scene if margin is None else dataclasses.replace(scene, margin=margin)
