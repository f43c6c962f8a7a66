"""The mesh fits' cache on disk: a capsule fit is computed once per vertex set and fit settings (host).

An entry is stored under the sha256 of the fit's settings (its version included) and of the vertices
it fitted (float64, C order: after scale and placement), so a changed mesh, scale, placement or fit is
fitted again. The folder: ``DIFFKIN_FIT_CACHE`` (empty, ``0``, ``off``, ``false``, ``no`` or ``none``:
no cache), else ``$XDG_CACHE_HOME/diffkin/fits`` (default ``~/.cache/diffkin/fits``). Each entry is
one ``.npz`` file written atomically (a temporary file in the same folder, then :func:`os.replace`).
An entry is never trusted: one that cannot be read, is malformed or does not contain every vertex is
ignored with a warning, fitted again and overwritten. A folder that cannot be written: no cache.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

_OFF = ("", "0", "off", "false", "no", "none")  # DIFFKIN_FIT_CACHE values that disable the cache

Fit = tuple[np.ndarray, np.ndarray, float]  # (a, b, radius)


def folder() -> Path | None:
    """The cache's folder, or ``None`` when ``DIFFKIN_FIT_CACHE`` turns it off."""
    env = os.environ.get("DIFFKIN_FIT_CACHE")
    if env is not None:
        return None if env.strip().lower() in _OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "diffkin" / "fits"


def key(vertices: np.ndarray, settings: str) -> str:
    """The entry's name: sha256 of ``settings`` and of the float64, C-order bytes of ``vertices``."""
    h = hashlib.sha256(settings.encode())
    h.update(b"\0")
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    return h.hexdigest()


def cached(
    vertices: np.ndarray,
    settings: str,
    fit: Callable[[np.ndarray], Fit],
    contains: Callable[[np.ndarray, np.ndarray, np.ndarray, float], bool],
) -> Fit:
    """``fit(vertices)``, read from the cache when an entry for these vertices and settings holds a
    capsule that ``contains`` every vertex, else computed and stored."""
    where = folder()
    if where is None:
        return fit(vertices)
    path = where / f"{key(vertices, settings)}.npz"
    hit = _read(path, vertices, contains)
    if hit is not None:
        return hit
    a, b, r = fit(vertices)
    if _malformed(a, b, r, vertices, contains) is None:  # never store what would not be trusted
        _write(path, a, b, r)
    return a, b, r


def _read(path: Path, vertices: np.ndarray, contains) -> Fit | None:
    try:
        data = path.read_bytes()
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as err:
        if not os.access(path.parent, os.R_OK | os.X_OK):  # the folder itself is out of reach: no cache
            return None
        reason = f"cannot be read: {err}"
    else:
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as entry:
                a, b, r = (np.asarray(entry[name], dtype=np.float64) for name in ("a", "b", "radius"))
        except Exception as err:  # not an .npz, other arrays, other types
            reason = f"cannot be read: {type(err).__name__}: {err}"
        else:
            reason = _malformed(a, b, r, vertices, contains) or ""
            if not reason:
                return a, b, float(r)
    warnings.warn(f"ignoring the cached capsule fit {str(path)!r} ({reason}): fitting again", UserWarning, stacklevel=4)
    return None


def _malformed(a, b, r, vertices: np.ndarray, contains) -> str | None:
    """Why ``(a, b, r)`` is not a capsule containing ``vertices``, or ``None``."""
    a, b, r = (np.asarray(x, dtype=np.float64) for x in (a, b, r))
    if a.shape != (3,) or b.shape != (3,) or r.shape != ():
        return f"shapes {a.shape}, {b.shape}, {r.shape}: expected (3,), (3,), ()"
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.isfinite(r) and r >= 0):
        return "not finite, or a negative radius"
    if not contains(vertices, a, b, float(r)):
        return "a vertex is outside its capsule"
    return None


def _write(path: Path, a: np.ndarray, b: np.ndarray, r: float) -> None:
    """Store an entry atomically; any failure to write leaves the cache as it was."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem[:16]}-", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, a=np.asarray(a, np.float64), b=np.asarray(b, np.float64), radius=np.float64(r))
        os.replace(tmp, path)
        tmp = None
    except OSError:
        pass
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
