"""Mesh files named by robot description files (URDF, MJCF): where a reference points to.

``package://NAME/rest`` is resolved by looking for a folder ``NAME`` next to the description file
and in each of its parent folders (also under ``share/``); relative paths are relative to the file.
Shared by the viewer (visual meshes) and :mod:`diffkin.collision` (collision meshes).
"""

from __future__ import annotations

import os


def resolve_mesh(filename: str, base_dir: str | None) -> str | None:
    """The file a URDF/MJCF mesh reference points to, or ``None`` if it is not found.

    Args:
        filename: ``package://NAME/rest``, ``file://path``, an absolute path or a path relative
            to ``base_dir``.
        base_dir: folder of the description file (``None`` for XML given as text: only absolute
            paths resolve).
    """
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://") :].partition("/")
        folder = base_dir
        while folder:
            for candidate in (os.path.join(folder, package), os.path.join(folder, "share", package)):
                if os.path.isfile(os.path.join(candidate, rest)):
                    return os.path.join(candidate, rest)
            if os.path.basename(folder) == package and os.path.isfile(os.path.join(folder, rest)):
                return os.path.join(folder, rest)
            parent = os.path.dirname(folder)
            folder = parent if parent != folder else None
        return None
    if os.path.isabs(filename):
        return filename if os.path.isfile(filename) else None
    if base_dir is None:
        return None
    path = os.path.join(base_dir, filename)
    return path if os.path.isfile(path) else None
