"""The mesh fits' cache on disk (host): a mesh file's fit, and a capsule fit of a vertex set, computed once.

Two kinds of entries. A mesh FILE's fit (:func:`cached_mesh`: the whole result, its kind, parameters,
volumes and overshoot) is stored under the sha256 of the file's bytes, its scale and placement (float64),
the fit asked for (``"hulls"``, ``"capsules"``) and the fit code's version and settings: a second load
reads neither the mesh (no trimesh) nor fits it. A capsule fit of points (:func:`cached`: inline MJCF
meshes, which have no file) is stored under the sha256 of the fit's settings (its version included) and
of the vertices it fitted (float64, C order: after scale and placement). A changed mesh, scale,
placement or fit is fitted again. The folder: ``DIFFKIN_FIT_CACHE`` (empty, ``0``, ``off``, ``false``,
``no`` or ``none``: no cache), else ``$XDG_CACHE_HOME/diffkin/fits`` (default ``~/.cache/diffkin/fits``).
Each entry is one ``.npz`` file written atomically (a temporary file in the same folder, then
:func:`os.replace`), read with ``allow_pickle=False``. An entry is never trusted: one that cannot be read
or is malformed (other shapes, values not finite, a capsule with a negative radius, a hull without
vertices; a capsule fit of points that does not contain every point) is ignored with a warning, fitted
again and overwritten. A folder that cannot be written: no cache.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

_OFF = ("", "0", "off", "false", "no", "none")  # DIFFKIN_FIT_CACHE values that disable the cache

Fit = tuple[np.ndarray, np.ndarray, float]  # (a, b, radius)
MeshFit = tuple[str, np.ndarray, float, float, float]  # (kind, params, volume, fitted volume, overshoot)


def folder() -> Path | None:
    """The cache's folder, or ``None`` when ``DIFFKIN_FIT_CACHE`` turns it off."""
    env = os.environ.get("DIFFKIN_FIT_CACHE")
    if env is not None:
        return None if env.strip().lower() in _OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "diffkin" / "fits"


def key(vertices: np.ndarray, settings: str) -> str:
    """A capsule fit's entry name: sha256 of ``settings`` and of the float64, C-order bytes of ``vertices``."""
    h = hashlib.sha256(settings.encode())
    h.update(b"\0")
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    return h.hexdigest()


def mesh_key(content: bytes, scale: np.ndarray, T: np.ndarray, meshes: str, settings: str) -> str:
    """A mesh file's entry name: sha256 of ``settings``, ``meshes``, the float64 bytes of ``scale (3,)`` and
    ``T (4, 4)`` and the file's bytes ``content``."""
    h = hashlib.sha256(b"mesh file\0")
    h.update(f"{settings}\0{meshes}\0".encode())
    h.update(np.ascontiguousarray(scale, dtype=np.float64).reshape(3).tobytes())
    h.update(np.ascontiguousarray(T, dtype=np.float64).reshape(16).tobytes())
    h.update(content)
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

    def check(entry: dict[str, np.ndarray]) -> str | None:
        return _malformed(entry["a"], entry["b"], entry["radius"], vertices, contains)

    entry = _read(path, ("a", "b", "radius"), check, "the cached capsule fit")
    if entry is not None:
        return entry["a"], entry["b"], float(entry["radius"])
    a, b, r = fit(vertices)
    if _malformed(a, b, r, vertices, contains) is None:  # never store what would not be trusted
        _write(path, {"a": np.asarray(a, np.float64), "b": np.asarray(b, np.float64), "radius": np.float64(r)})
    return a, b, r


def cached_mesh(
    file: str, scale: np.ndarray, T: np.ndarray, meshes: str, settings: str, fit: Callable[[], MeshFit]
) -> MeshFit:
    """``fit()``, the fit of the mesh ``file`` scaled by ``scale`` and placed by ``T`` as ``meshes`` asks, read
    from the cache when an entry for the file's bytes, scale, placement, ``meshes`` and ``settings`` holds a
    well-formed fit of that kind (``"convex"`` for ``"hulls"``, else ``"capsule"``), else computed and stored.
    A file that cannot be read here is fitted (and fails there) without the cache."""
    where = folder()
    if where is None:
        return fit()
    try:
        content = Path(file).read_bytes()
    except OSError:
        return fit()
    path = where / f"{mesh_key(content, scale, T, meshes, settings)}.npz"
    kind = "convex" if meshes == "hulls" else "capsule"

    def check(entry: dict[str, np.ndarray]) -> str | None:
        return _malformed_mesh(kind, *(entry[name] for name in _MESH_FIELDS))

    entry = _read(path, _MESH_FIELDS, check, f"the cached fit of the mesh {file!r}:", texts=("kind",))
    if entry is not None:
        got, params, volume, fitted_volume, overshoot = (entry[name] for name in _MESH_FIELDS)
        return str(got), params, float(volume), float(fitted_volume), float(overshoot)
    result = fit()
    arrays = dict(
        zip(_MESH_FIELDS, (np.str_(result[0]), *(np.asarray(x, np.float64) for x in result[1:])), strict=True)
    )
    if _malformed_mesh(kind, *arrays.values()) is None:  # never store what would not be trusted
        _write(path, arrays)
    return result


_MESH_FIELDS = ("kind", "params", "volume", "fitted_volume", "overshoot")


def _read(
    path: Path,
    names: tuple[str, ...],
    check: Callable[[dict[str, np.ndarray]], str | None],
    what: str,
    texts: tuple[str, ...] = (),
) -> dict[str, np.ndarray] | None:
    """The arrays ``names`` of the entry at ``path`` (as float64, but ``texts`` as stored) when ``check`` finds
    nothing wrong with them, else ``None``: no entry, or one ignored with a warning naming ``what`` it holds."""
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
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                entry = {name: npz[name] if name in texts else np.asarray(npz[name], np.float64) for name in names}
        except Exception as err:  # not an .npz, other arrays, other types
            reason = f"cannot be read: {type(err).__name__}: {err}"
        else:
            reason = check(entry) or ""
            if not reason:
                return entry
    warnings.warn(f"ignoring {what} {str(path)!r} ({reason}): fitting again", UserWarning, stacklevel=4)
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


def _malformed_mesh(kind: str, got, params, volume, fitted_volume, overshoot) -> str | None:
    """Why ``(got, params, volume, fitted_volume, overshoot)`` is not a well-formed fit of ``kind``
    (``"capsule"``: a (3), b (3), radius >= 0; ``"convex"``: at least one vertex, 3 numbers each), or ``None``.
    Volumes are NaN where the hull has none (a flat mesh, no scipy), else >= 0; the overshoot is >= 0."""
    got, params, numbers = np.asarray(got), np.asarray(params), [np.asarray(x) for x in (volume, fitted_volume)]
    if got.shape != () or str(got) != kind:
        return f"a fit of kind {got.tolist()!r}: expected {kind!r}"
    expected = "(7,)" if kind == "capsule" else "(3 n,), n >= 1"
    n = params.size
    if params.ndim != 1 or (n != 7 if kind == "capsule" else n == 0 or n % 3):
        return f"parameters of shape {params.shape}: expected {expected}"
    overshoot = np.asarray(overshoot)
    if any(x.shape != () for x in (*numbers, overshoot)):
        return "volumes or overshoot not scalars"
    if not (np.all(np.isfinite(params)) and np.isfinite(overshoot) and overshoot >= 0):
        return "not finite, or a negative overshoot"
    if kind == "capsule" and params[6] < 0:
        return "a negative radius"
    if any(not (np.isnan(v) or (np.isfinite(v) and v >= 0)) for v in numbers):
        return "a volume neither NaN nor finite and >= 0"
    return None


def _write(path: Path, arrays: dict[str, Any]) -> None:
    """Store an entry atomically; any failure to write leaves the cache as it was."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem[:16]}-", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
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
