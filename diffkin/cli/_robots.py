"""The robots the commands work on: built-in names and URDF/MJCF files, loaded once per process."""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from pathlib import Path

from diffkin.cli._errors import CLIError

ROBOTS = ("iiwa7", "iiwa14", "panda", "ur5", "puma560")  # dk.robots.BUILTIN, without importing JAX (--help)
SRS_ROBOTS = ("iiwa7", "iiwa14")


def jax_x64():
    """Import jax with float64 enabled (every command computes in float64)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    return jax


def robot_key(spec: str, end_link: str | None, base_link: str | None) -> tuple:
    """A hashable key of a robot argument (files by absolute path and modification time)."""
    if spec in ROBOTS:
        if end_link is not None or base_link is not None:
            raise CLIError(f"--end-link/--base-link apply to URDF and MJCF files, not to the built-in robot {spec!r}")
        return (spec,)
    path = robot_file(spec)
    return (str(path.resolve()), path.stat().st_mtime_ns, end_link, base_link)


def robot_file(spec: str) -> Path:
    """The readable URDF or MJCF file ``spec`` names (not a built-in robot's name).

    Raises:
        CLIError: a path that does not exist, a directory, an unreadable file, or a name that is neither
            a built-in robot nor a file.
    """
    path = Path(spec)
    if path.is_dir():
        raise CLIError(f"{spec!r} is a directory: expected a URDF or MJCF file or one of {', '.join(ROBOTS)}")
    if not path.exists():
        if os.sep in spec or "/" in spec or path.suffix.lower() in (".urdf", ".xml", ".mjcf"):
            raise CLIError(f"robot file {spec!r} does not exist")
        raise CLIError(f"unknown robot {spec!r}: expected one of {', '.join(ROBOTS)} or a URDF or MJCF file path")
    if not os.access(path, os.R_OK):
        raise CLIError(f"cannot read {spec!r}")
    return path


def frame_of(robot, name: str, flag: str) -> str:
    """``name`` if it is a frame of ``robot``, else a :class:`CLIError` for ``flag`` naming the closest frames."""
    try:
        robot.frame_index(name)
    except ValueError as e:
        raise CLIError(f"{flag}: {e} (`diffkin info` lists them all)") from None
    return name


@functools.lru_cache(maxsize=16)
def _tree_for(path: str, _mtime: int):
    """The whole robot (``dk.Robot``) of a URDF or MJCF file."""
    import diffkin as dk

    return dk.load_robot(path)


@functools.lru_cache(maxsize=16)
def chain_for(key: tuple):
    """The chain of a :func:`robot_key`: a built-in robot, or one path of a file's tree."""
    import diffkin as dk

    if len(key) == 1:
        return getattr(dk.robots, key[0])()
    path, mtime, end_link, base_link = key
    robot = _tree_for(path, mtime)
    for flag, name in (("--end-link", end_link), ("--base-link", base_link)):
        if name is not None:
            frame_of(robot, name, flag)
    return robot.chain(end_link or single_end(robot), base_link)


def single_end(robot) -> str:
    """The end frame of a robot whose tree has one leaf body: its last frame (the deepest fixed link)."""
    parents = set(robot.parents)
    leaves = [b for b in range(len(robot.parents) + 1) if b not in parents and b > 0] or [0]
    if len(leaves) > 1:
        ends = [robot.frame_names[max(f for f, b in enumerate(robot.frame_bodies) if b == leaf)] for leaf in leaves]
        raise CLIError(f"the robot is a tree with {len(leaves)} branches: choose --end-link, e.g. one of {ends}")
    return robot.frame_names[max(f for f, b in enumerate(robot.frame_bodies) if b == leaves[0])]


@functools.lru_cache(maxsize=4)
def _geometry_for(path: str, mtime: int, srdf: tuple[tuple[str, int], ...]):
    """The collision geometry (``dk.collision.Geometry``) of a URDF or MJCF file's whole robot, without the
    pairs of the SRDFs ``srdf`` (``(path, mtime)`` each)."""
    import diffkin as dk

    return dk.collision.load(path, _tree_for(path, mtime), srdf=[p for p, _ in srdf] or None)


def srdf_key(srdf: Sequence[str] | None) -> tuple[tuple[str, int], ...]:
    """``--srdf`` files as ``(absolute path, mtime)`` (a cache key: an edited file is read again).

    Raises:
        CLIError: a file that does not exist.
    """
    out = []
    for path in srdf or ():
        if not os.path.isfile(path):
            raise CLIError(f"--srdf: no such file {path!r}")
        out.append((os.path.abspath(path), os.stat(path).st_mtime_ns))
    return tuple(out)


def robot_with_geometry(spec: str, srdf: Sequence[str] | None = None):
    """The whole robot (``dk.Robot``) of a URDF or MJCF file and its collision geometry, without the
    self-collision pairs that the SRDF files ``srdf`` disable.

    Raises:
        CLIError: a built-in robot (no collision geometry), a file without collision shapes, a
            missing or malformed SRDF, or collision meshes without trimesh (the ``diffkin[collision]`` extra).
        ValueError: a malformed file or collision element (from :func:`diffkin.collision.load`).
    """
    if spec in ROBOTS:
        raise CLIError(
            f"--avoid: the built-in robot {spec!r} has no collision geometry: "
            "give a URDF or MJCF file with <collision> elements or geoms"
        )
    jax_x64()
    path, mtime = robot_key(spec, None, None)[:2]
    try:
        geom = _geometry_for(path, mtime, srdf_key(srdf))
    except ImportError:
        raise CLIError(
            f"--avoid: the collision meshes of {spec!r} need trimesh, which is not installed: "
            "pip install 'diffkin[collision]' (or pip install trimesh)"
        ) from None
    if not geom.shape_names:
        raise CLIError(f"--avoid: {spec!r} has no collision geometry (no <collision> elements or geoms)")
    return _tree_for(path, mtime), geom


def tree(spec: str):
    """The ``dk.Robot`` of a URDF or MJCF path (``None`` for a built-in robot name)."""
    key = robot_key(spec, None, None)
    return None if len(key) == 1 else _tree_for(key[0], key[1])


def load_robot(spec: str, end_link: str | None = None, base_link: str | None = None):
    """The chain of a built-in robot name, or of one path of a URDF or MJCF file's tree.

    Args:
        spec: ``iiwa7``, ``iiwa14``, ``panda``, ``ur5``, ``puma560`` or a URDF/MJCF file path.
        end_link: end frame of the chain (default: the last frame of the single leaf).
        base_link: base frame of the chain (default: the root).

    Returns:
        A ``DHChain`` (built-in robots) or ``PoEChain`` (``robot.chain(end_link, base_link)``).

    Raises:
        CLIError: an unknown name, a missing or unreadable file, link options with a built-in robot,
            a tree with several leaves and no ``end_link``.
        ValueError: a malformed file (from :func:`diffkin.load_robot`) or an unknown frame.
    """
    jax_x64()
    return chain_for(robot_key(spec, end_link, base_link))
