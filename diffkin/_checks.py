"""Checks shared by the functions: host-side argument checks (raising a TypeError or ValueError that
names the argument), and traceable validity checks (no raising: they give a boolean per problem).

Host side: :func:`instance` (the type of a model or an arm), :func:`positive_int` (counts),
:func:`real_array` (numbers: ``q``, ``psi``, targets), :func:`pose_array` (``(..., 4, 4)`` poses),
:func:`sign_array` (``+-1`` entries, checked when known), :func:`broadcast_batch` (batch shapes).
The model constructors' field checks are in :mod:`diffkin._validate`.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._static import is_concrete


def rigid_tol(dtype) -> float:
    """Tolerance of :func:`rigid_poses`: 1e-9 in float64, 1e-5 in float32."""
    return 1e-9 if jnp.finfo(dtype).bits >= 64 else 1e-5


def rigid_poses(T):
    """``(...,)`` whether each ``(..., 4, 4)`` pose is a rigid transform within :func:`rigid_tol`.

    ``|R^T R - I|``, ``|det R - 1|`` and the last row's distance from ``[0, 0, 0, 1]`` (max norms);
    false for non-finite poses. A NumPy array is checked with NumPy (the host-side check of a
    concrete target: op-by-op JAX dispatch of these ~60 small operations cost ~1 ms per call), a
    JAX array or tracer with ``jax.numpy``.
    """
    xp = np if isinstance(T, np.ndarray) else jnp
    tol = rigid_tol(T.dtype)
    R = [[T[..., i, j] for j in range(3)] for i in range(3)]  # entries: no batched 3x3 matmuls (slow on CPU)
    gram = [
        xp.abs(sum(R[k][i] * R[k][j] for k in range(3)) - (1.0 if i == j else 0.0))
        for i in range(3)
        for j in range(i, 3)
    ]
    row = [xp.abs(T[..., 3, j] - (1.0 if j == 3 else 0.0)) for j in range(4)]
    det = (
        R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1])
        - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0])
        + R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0])
    )
    worst = functools.reduce(xp.maximum, [*gram, *row, xp.abs(det - 1.0)])
    return worst <= tol  # false for NaN


def instance(value, types: type | tuple[type, ...], name: str, expected: str) -> None:
    """Raise ``TypeError("{name}: expected {expected}, got <type>")`` unless ``value`` is one of ``types``."""
    if not isinstance(value, types):
        raise TypeError(f"{name}: expected {expected}, got {type(value).__name__}")


def positive_int(value, name: str, what: str = "a positive int") -> int:
    """``value`` as an ``int >= 1`` (Python or NumPy ints; not bools).

    Raises:
        TypeError: not an int.
        ValueError: ``value < 1``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: expected {what}, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name}: expected {what}, got {value}")
    return int(value)


def real_array(value, name: str, what: str = "numbers") -> jax.Array:
    """``value`` as a real floating array (integers cast to the default float); raises on the host.

    Raises:
        ValueError: numbers beyond the float range.
        TypeError: not numbers, or bool or complex values.
    """
    if isinstance(value, (str, bytes)):  # jnp.asarray reads a string as a dtype: "," raises SyntaxError
        raise TypeError(f"{name}: expected an array of {what}, got {type(value).__name__}")
    try:
        x = jnp.asarray(value)
    except OverflowError as err:
        raise ValueError(f"{name}: expected {what} within the float range, got {value!r:.80}") from err
    except TypeError as err:
        raise TypeError(f"{name}: expected an array of {what}, got {type(value).__name__}") from err
    if x.dtype == bool or jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"{name}: expected real {what}, got dtype {x.dtype}")
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))


def pose_array(value, name: str = "target") -> jax.Array:
    """``value`` as a real floating array of ``(..., 4, 4)`` homogeneous poses (see :func:`real_array`)."""
    T = real_array(value, name, "poses")
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise ValueError(f"{name}: expected shape (..., 4, 4) homogeneous poses, got {T.shape}")
    return T


def sign_array(value, name: str, size: int, what: str) -> jax.Array:
    """``(..., size)`` array of ``+1``/``-1`` entries (``what`` names them); the values are checked when concrete."""
    x = jnp.asarray(value)
    if x.ndim == 0 or x.shape[-1] != size:
        raise ValueError(f"{name}: expected shape (..., {size}) with entries {what}, got {x.shape}")
    if is_concrete(x):
        values = np.asarray(x)
        bad = np.argwhere(np.abs(values) != 1)
        if bad.size:
            index = tuple(int(i) for i in bad[0])
            raise ValueError(f"{name}: expected entries +1 or -1, got {values[index]} at index {index}")
    return x


def broadcast_batch(**shapes: tuple[int, ...]) -> tuple[int, ...]:
    """Broadcast the named batch shapes, or a ValueError listing them."""
    try:
        return tuple(np.broadcast_shapes(*shapes.values()))
    except ValueError as err:
        listed = ", ".join(f"{k} {v}" for k, v in shapes.items())
        raise ValueError(f"expected batch shapes that broadcast together, got {listed}") from err
