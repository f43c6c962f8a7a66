"""Batch results for the viewer to browse: every field checked when the results are given."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from diffkin._checks import rigid_poses, rigid_tol

ERRORS = ("pos_err", "rot_err")


def _real(name: str, value) -> np.ndarray:
    """``value`` as an array of real numbers (integers or floats; not booleans, complex numbers or text)."""
    array = np.asarray(value)
    if array.dtype == bool or not (np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)):
        raise ValueError(f"results {name}: expected real numbers, got dtype {array.dtype}")
    return array


def _rows(bad: np.ndarray) -> str:
    """The first rows (at most 5) where ``bad (N, ...)`` is true anywhere."""
    rows = np.flatnonzero(bad.reshape(len(bad), -1).any(axis=1))
    return "[" + ", ".join(str(r) for r in rows[:5]) + (", ...]" if len(rows) > 5 else "]")


def check_results(results, dof: int, floating: bool) -> dict[str, np.ndarray]:
    """The batch results to browse, checked field by field.

    Args:
        results: a mapping (a dict, or the arrays of an ``.npz``) with ``q (N, dof)``: finite
            real numbers, ``N >= 1``; and optionally ``success (N,)`` booleans, ``pos_err`` and
            ``rot_err`` ``(N,)`` or ``(N, k)`` (per target, as a whole robot's IK gives them):
            real numbers ``>= 0`` (``inf`` allowed, NaN not); ``base (N, 4, 4)`` root poses
            ``T_world_root`` (a floating robot's solved base): finite rigid transforms (within
            :func:`diffkin._checks.rigid_tol` of their dtype, integers as float64). Other fields
            are ignored (an ``IKResult``'s ``iters``...).
        dof: the number of joints of the model.
        floating: whether the model is a :class:`diffkin.Robot` with a floating root (only such
            a model takes ``base``).

    Returns:
        ``{field: array}`` of the fields above that are given (``q`` and ``base`` as float64).

    Raises:
        TypeError: ``results`` is not a mapping.
        ValueError: a missing ``q``, or a field of the wrong shape, dtype or values (the message
            names the field, what was expected and the first offending rows).
    """
    if not isinstance(results, Mapping):
        raise TypeError(f"results: expected a mapping of arrays (or an .npz path), got {type(results).__name__}")
    if "q" not in results:
        raise ValueError(f"results: expected an array 'q' (N, dof), got fields {sorted(results)}")
    q = _real("q", results["q"])
    if q.ndim != 2 or q.shape[0] == 0 or q.shape[1] != dof:
        raise ValueError(f"results q: expected shape (N, {dof}) with N >= 1, got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"results q: expected finite numbers, got NaN or inf in rows {_rows(~np.isfinite(q))}")
    n = len(q)
    checked = {"q": q.astype(np.float64)}
    if "success" in results:
        success = np.asarray(results["success"])
        if success.dtype != bool:
            raise ValueError(f"results success: expected booleans, got dtype {success.dtype}")
        if success.shape != (n,):
            raise ValueError(f"results success: expected shape ({n},) (one per row of q), got {success.shape}")
        checked["success"] = success
    for name in ERRORS:
        if name not in results:
            continue
        err = _real(name, results[name])
        if err.ndim not in (1, 2) or len(err) != n:
            raise ValueError(f"results {name}: expected shape ({n},) or ({n}, k) (one per row of q), got {err.shape}")
        bad = ~(err >= 0)  # NaN or negative
        if np.any(bad):
            raise ValueError(
                f"results {name}: expected errors >= 0 (inf allowed), got NaN or a negative value in rows {_rows(bad)}"
            )
        checked[name] = err
    if "base" in results:
        checked["base"] = _check_base(results["base"], n, floating)
    return checked


def _check_base(value, n: int, floating: bool) -> np.ndarray:
    """``base (n, 4, 4)`` root poses ``T_world_root`` as float64, checked (see :func:`check_results`)."""
    if not floating:
        raise ValueError("results base: root poses are drawn only for a dk.Robot with a floating root (floating=True)")
    base = _real("base", value)
    if base.shape != (n, 4, 4):
        raise ValueError(
            f"results base: expected shape ({n}, 4, 4) (a pose T_world_root per row of q), got {base.shape}"
        )
    if not np.all(np.isfinite(base)):
        raise ValueError(f"results base: expected finite numbers, got NaN or inf in rows {_rows(~np.isfinite(base))}")
    if not np.issubdtype(base.dtype, np.floating):
        base = base.astype(np.float64)
    rigid = rigid_poses(base)
    if not np.all(rigid):
        raise ValueError(
            f"results base: expected rigid transforms (within {rigid_tol(base.dtype):g}), "
            f"got others in rows {_rows(~rigid)}"
        )
    return base.astype(np.float64)


def describe(results: dict[str, np.ndarray], i: int) -> str:
    """One line on row ``i`` of checked results: ``result i of N``, its success and errors."""
    text = f"result {i} of {len(results['q'])}"
    if "success" in results:
        text += f", success {bool(results['success'][i])}"
    for name in ERRORS:
        if name in results:
            row = results[name][i]
            text += f", {name} " + (f"{row:.3g}" if row.ndim == 0 else f"[{', '.join(f'{x:.3g}' for x in row)}]")
    return text
