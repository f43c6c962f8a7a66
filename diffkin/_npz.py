"""Reading and writing ``.npz`` archives of arrays (never pickled objects), with errors that name the file."""

from __future__ import annotations

import dataclasses
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


def save_dataclass(obj, path) -> None:
    """Write every field of the dataclass ``obj`` to ``path`` as a ``.npz`` archive (numpy appends ``.npz``)."""
    fields = {f.name: np.asarray(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    np.savez_compressed(path, **fields)  # type: ignore[arg-type]  # numpy's stub reads **fields as allow_pickle


def read_dataclass_fields(cls, path, what: str) -> tuple[str, dict[str, np.ndarray]]:
    """``(path, fields)``: the archive :func:`save_dataclass` wrote for a ``cls`` at ``path`` (``path`` or,
    as numpy named it, ``path + ".npz"``), every field of ``cls`` present and ``counts`` a 3-d grid.

    Raises:
        ValueError: the file is not such an archive (:func:`read_npz`), lacks a field of ``cls`` or holds
            a ``counts`` that is not 3-d (the message names the file, the ``what`` and the field).
        FileNotFoundError: no such file.
    """
    path = os.fspath(path)
    if not os.path.exists(path) and not path.endswith(".npz") and os.path.exists(path + ".npz"):
        path += ".npz"  # as np.savez named it
    fields = read_npz(path, f"written by {cls.__name__}.save")
    missing = [f.name for f in dataclasses.fields(cls) if f.name not in fields]
    if missing:
        raise ValueError(f"{path}: not a complete {what}, missing field(s) {', '.join(missing)}")
    if fields["counts"].ndim != 3:
        raise ValueError(f"{path}: field counts: expected a 3-d grid, got shape {fields['counts'].shape}")
    return path, fields
