"""Host-side checks of the pytree models' fields (the model constructors', :class:`diffkin.srs.SRSArm`'s): each
error names the field and what was expected."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def float_array(value, name: str, shape: tuple[int, ...] | None = None, *, finite: bool = True) -> np.ndarray:
    """``value`` as a float64 array of ``shape``, with finite entries unless ``finite=False``."""
    if isinstance(value, jax.core.Tracer):
        raise TypeError(f"{name}: expected concrete numbers, got a traced value (build models outside jit/grad/vmap)")
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name}: expected an array of numbers, got {type(value).__name__}") from err
    if raw.dtype.kind in "bc":
        raise TypeError(f"{name}: expected an array of real numbers, got dtype {raw.dtype}")
    try:
        arr = np.asarray(raw, dtype=np.float64)
    except OverflowError as err:
        raise ValueError(f"{name}: expected numbers within the float64 range, got {value!r:.80}") from err
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name}: expected an array of numbers, got {type(value).__name__}") from err
    if shape is not None and arr.shape != shape:
        want = "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name}: expected finite numbers, got {arr[bad]} at index {bad}")
    if np.any(np.isnan(arr)):
        bad = tuple(int(i) for i in np.argwhere(np.isnan(arr))[0])
        raise ValueError(f"{name}: expected numbers, got NaN at index {bad}")
    return arr


def joint_types(value, dof: int, name: str = "joint_types") -> str:
    """A string of ``dof`` letters ``R`` (revolute) or ``P`` (prismatic)."""
    if not isinstance(value, str):
        raise TypeError(f"{name}: expected a string of 'R'/'P' letters, got {type(value).__name__}")
    if len(value) != dof:
        raise ValueError(f"{name}: expected {dof} letters (one per joint), got {len(value)} in {value!r}")
    for i, letter in enumerate(value):
        if letter not in "RP":
            raise ValueError(f"{name}[{i}]: expected 'R' or 'P', got {letter!r}")
    return value


def limits(lower, upper, dof: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits ``(dof,)``; ``None`` means unlimited (``-inf`` / ``inf``)."""
    lo = np.full(dof, -np.inf) if lower is None else float_array(lower, "lower", (dof,), finite=False)
    hi = np.full(dof, np.inf) if upper is None else float_array(upper, "upper", (dof,), finite=False)
    for i in range(dof):
        if lo[i] > hi[i]:
            raise ValueError(f"lower[{i}] = {lo[i]} > upper[{i}] = {hi[i]}: expected lower <= upper")
        if lo[i] == np.inf or hi[i] == -np.inf:
            raise ValueError(f"joint {i}: limits [{lo[i]}, {hi[i]}] leave no feasible value")
    return lo, hi


def rigid_transform(value, name: str, *, tol: float = 1e-6) -> np.ndarray:
    """A ``(4, 4)`` homogeneous rigid transform (orthonormal rotation, det +1, last row 0 0 0 1)."""
    T = float_array(value, name, (4, 4))
    R = T[:3, :3]
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise ValueError(f"{name}: expected last row [0, 0, 0, 1] of a rigid transform, got {T[3].tolist()}")
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > tol or np.linalg.det(R) < 0:
        raise ValueError(
            f"{name}: expected a rotation (R^T R = I, det R = +1) in the upper-left 3x3 block, "
            f"got |R^T R - I| = {err:.3g}, det R = {np.linalg.det(R):.6g}"
        )
    return T


def joint_names(value, dof: int) -> tuple[str, ...]:
    """``dof`` distinct joint names; ``None`` gives ``joint1 ... jointN``."""
    if value is None:
        return tuple(f"joint{i + 1}" for i in range(dof))
    if isinstance(value, str) or not isinstance(value, (tuple, list)):
        raise TypeError(f"joint_names: expected a tuple or list of {dof} strings, got {type(value).__name__}")
    names = tuple(value)
    if len(names) != dof or not all(isinstance(n, str) for n in names):
        raise ValueError(f"joint_names: expected {dof} strings, got {names!r}")
    if len(set(names)) != dof:
        raise ValueError(f"joint_names: expected distinct names, got {names!r}")
    return names


def flag(value, name: str) -> bool:
    """A Python ``bool`` (``numpy.bool_`` accepted); a string such as ``'False'`` is a TypeError."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected True or False, got {value!r} ({type(value).__name__})")
    return bool(value)


def text(value, name: str) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{name}: expected a string, got {type(value).__name__}")
    return value


def leaf(value, name: str, shape: tuple[int, ...], concrete: bool, *, finite: bool = True) -> np.ndarray | None:
    """Check an array field of a model: a real floating array of ``shape``.

    Returns its values as float64 (finite unless ``finite=False``) when ``concrete``, else ``None``
    (a traced leaf: only its dtype and shape are known).
    """
    if not hasattr(value, "shape") or not hasattr(value, "dtype"):
        raise TypeError(f"{name}: expected an array, got {type(value).__name__} (use the from_* builders)")
    if not np.issubdtype(value.dtype, np.floating):
        raise TypeError(f"{name}: expected a real floating-point array, got dtype {value.dtype}")
    if tuple(value.shape) != shape:
        want = "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name}: expected shape {want}, got {tuple(value.shape)}")
    if not concrete:
        return None
    return float_array(value, name, shape, finite=finite)


def tolerance(value) -> float:
    """Tolerance of the rigidity and unit-length checks of a leaf: 1e-6 (float64), 1e-5 (float32 and below)."""
    return 1e-6 if np.finfo(value.dtype).bits >= 64 else 1e-5


def static_names(value, dof: int) -> None:
    """``joint_names`` of a model: ``()`` (unnamed) or ``dof`` distinct strings."""
    if value != ():
        joint_names(value, dof)


def dof_of(joint_types_value) -> int:
    """The number of joints given by the static ``joint_types`` string (checked)."""
    if not isinstance(joint_types_value, str):
        raise TypeError(f"joint_types: expected a string of 'R'/'P' letters, got {type(joint_types_value).__name__}")
    if not joint_types_value:
        raise ValueError("joint_types: expected at least one joint, got ''")
    return len(joint_types(joint_types_value, len(joint_types_value)))


def chain_statics(chain) -> int:
    """The static fields every chain has, ``joint_types``, ``joint_names`` and ``name``; returns ``dof``."""
    dof = dof_of(chain.joint_types)
    static_names(chain.joint_names, dof)
    text(chain.name, "name")
    return dof


def limit_leaves(chain, dof: int, concrete: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The ``lower`` and ``upper`` leaves of a model with ``dof`` joints: their values when ``concrete``."""
    return (
        leaf(chain.lower, "lower", (dof,), concrete, finite=False),
        leaf(chain.upper, "upper", (dof,), concrete, finite=False),
    )


def velocity(value, dof: int) -> np.ndarray:
    """Velocity limits ``(dof,)`` (rad/s, m/s), each ``>= 0``; ``None`` means none (``inf``)."""
    if value is None:
        return np.full(dof, np.inf)
    v = float_array(value, "velocity", (dof,), finite=False)
    if np.any(v < 0):
        i = int(np.argmax(v < 0))
        raise ValueError(f"velocity[{i}]: expected a limit >= 0 (rad/s or m/s; inf: none), got {v[i]}")
    return v


def velocity_leaf(model, dof: int, concrete: bool) -> None:
    """The ``velocity`` leaf of a model with ``dof`` joints: its shape, and its values when ``concrete``."""
    v = leaf(model.velocity, "velocity", (dof,), concrete, finite=False)
    if v is not None:
        velocity(v, dof)


def no_velocity_limits(model) -> dict:
    """``{"velocity": inf per joint}`` (dtype of ``lower``) for a model built without ``velocity`` (the
    models' ``_fill``: :mod:`diffkin._pytree`), else ``{}``.

    A concrete ``velocity`` of ``inf`` only (none) but of another length than ``lower`` is refilled too:
    "none" has no length, and a model rebuilt with fewer joints by ``dataclasses.replace`` keeps it
    (the closed loops' dependent joints leave ``q``: :func:`diffkin.models._loops.close`)."""
    lower, v = model.lower, model.velocity
    if not hasattr(lower, "dtype"):  # (a bad ``lower``: the check names it)
        return {}
    none = v is None or (
        hasattr(v, "shape")
        and np.shape(v) != np.shape(lower)
        and not isinstance(v, jax.core.Tracer)
        and bool(np.all(np.isposinf(np.asarray(v))))
    )
    return {"velocity": jnp.full(np.shape(lower), np.inf, lower.dtype)} if none else {}
