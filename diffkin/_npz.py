"""Reading ``.npz`` archives of arrays (never pickled objects), with errors that name the file."""

from __future__ import annotations

import os
import zipfile
import zlib

import numpy as np

# what numpy raises on an empty, truncated or corrupt archive, or a member it may not unpickle
_UNREADABLE = (EOFError, OSError, ValueError, zipfile.BadZipFile, zlib.error)


def read_npz(path, what: str) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` archive at ``path``, read eagerly and without pickle.

    Args:
        path: the file.
        what: what the archive should be, for the messages (``"written by ReachabilityMap.save"``).

    Returns:
        ``{name: array}`` of every member.

    Raises:
        ValueError: ``{path}: expected a .npz archive {what}, ...``: the file is empty, truncated,
            corrupt, not a zip archive, a single ``.npy`` array, or holds object arrays.
        FileNotFoundError: no such file.
    """
    path = os.fspath(path)
    expected = f"{path}: expected a .npz archive {what}"
    with open(path, "rb") as file:  # closed here even when numpy fails half-way
        try:
            data = np.load(file, allow_pickle=False)
            arrays = {name: data[name] for name in data.files} if isinstance(data, np.lib.npyio.NpzFile) else None
        except _UNREADABLE as err:
            raise ValueError(f"{expected}, could not read it ({type(err).__name__}: {err})") from err
    if arrays is None:
        raise ValueError(f"{expected}, got a single array")
    return arrays
