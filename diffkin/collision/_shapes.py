"""Primitive collision shapes: sphere, capsule, box and half-space, as pytrees of arrays.

Every field is an array leaf with any leading batch axes (they broadcast against each other and
against the other shape of :func:`diffkin.collision.distance`). The constructors accept anything
array-like (Python numbers and lists become arrays of JAX's default float type; integer arrays
become floats) and check, on the host, the trailing shape of every field always and its values
(non-negative radii and half extents, rigid box poses, unit plane normals, finite numbers) when
they are concrete: under ``jit``/``vmap``/``grad`` only the shapes are checked and nothing raises.
"""

from __future__ import annotations

from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._pytree import pytree_dataclass

T = TypeVar("T")


def _tolerance(value) -> float:
    """Tolerance of the rigidity and unit-length checks: 1e-6 (float64), 1e-5 (float32 and below)."""
    return 1e-6 if np.finfo(value.dtype).bits >= 64 else 1e-5


def _field(shape_obj, name: str, tail: tuple[int, ...], concrete: bool) -> np.ndarray | None:
    """Make field ``name`` a floating array whose trailing axes are ``tail``; its float64 values if concrete."""
    where = f"{type(shape_obj).__name__}.{name}"
    value = getattr(shape_obj, name)
    array: Any
    if isinstance(value, jax.core.Tracer):
        array = value
    else:
        try:
            raw = np.asarray(value) if not isinstance(value, jax.Array) else value
        except (TypeError, ValueError) as err:
            raise TypeError(f"{where}: expected an array of numbers, got {type(value).__name__}") from err
        if raw.dtype.kind not in "fiu":
            raise TypeError(f"{where}: expected an array of real numbers, got dtype {raw.dtype}")
        array = jnp.asarray(raw) if raw.dtype.kind == "f" else jnp.asarray(raw, dtype=jnp.result_type(float))
        object.__setattr__(shape_obj, name, array)
    if not jnp.issubdtype(array.dtype, jnp.floating):
        raise TypeError(f"{where}: expected a real floating-point array, got dtype {array.dtype}")
    shape = tuple(array.shape)
    if len(shape) < len(tail) or shape[len(shape) - len(tail) :] != tail:
        want = "(..., " + ", ".join(map(str, tail)) + ")" if tail else "(...)"
        raise ValueError(f"{where}: expected shape {want}, got {shape}")
    if not concrete:
        return None
    host = np.asarray(array, dtype=np.float64)
    if not np.all(np.isfinite(host)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(host))[0])
        raise ValueError(f"{where}: expected finite numbers, got {host[bad]} at index {bad}")
    return host


def _non_negative(values: np.ndarray | None, where: str) -> None:
    if values is not None and np.any(values < 0):
        bad = tuple(int(i) for i in np.argwhere(values < 0)[0])
        raise ValueError(f"{where}: expected values >= 0, got {values[bad]} at index {bad}")


def _batch(shape_obj, fields: dict[str, int]) -> None:
    """The leading axes of the fields (each with its trailing rank) must broadcast together."""
    try:
        jnp.broadcast_shapes(
            *(jnp.shape(getattr(shape_obj, n))[: jnp.ndim(getattr(shape_obj, n)) - k] for n, k in fields.items())
        )
    except ValueError as err:
        shapes = {n: tuple(jnp.shape(getattr(shape_obj, n))) for n in fields}
        raise ValueError(
            f"{type(shape_obj).__name__}: the batch axes of the fields do not broadcast: {shapes}"
        ) from err


@pytree_dataclass
class Sphere:
    """A ball.

    Attributes:
        center: ``(..., 3)`` centre, metres, in the world (or whatever frame the other shape uses).
        radius: ``(...,)`` radius, metres, ``>= 0``.
    """

    center: jax.Array
    radius: jax.Array

    def _check(self, concrete: bool) -> None:
        _field(self, "center", (3,), concrete)
        _non_negative(_field(self, "radius", (), concrete), "Sphere.radius")
        _batch(self, {"center": 1, "radius": 0})


@pytree_dataclass
class Capsule:
    """The set of points within ``radius`` of the segment from ``a`` to ``b`` (a sphere if ``a == b``).

    Attributes:
        a, b: ``(..., 3)`` end points of the axis segment, metres.
        radius: ``(...,)`` radius, metres, ``>= 0``.
    """

    a: jax.Array
    b: jax.Array
    radius: jax.Array

    def _check(self, concrete: bool) -> None:
        _field(self, "a", (3,), concrete)
        _field(self, "b", (3,), concrete)
        _non_negative(_field(self, "radius", (), concrete), "Capsule.radius")
        _batch(self, {"a": 1, "b": 1, "radius": 0})


@pytree_dataclass
class Box:
    """A solid box (cuboid).

    Attributes:
        pose: ``(..., 4, 4)`` rigid pose ``T_world_box`` of the box's centre and axes.
        half_extents: ``(..., 3)`` half edge lengths along the box's x, y, z axes, metres, ``>= 0``.
    """

    pose: jax.Array
    half_extents: jax.Array

    def _check(self, concrete: bool) -> None:
        T = _field(self, "pose", (4, 4), concrete)
        _non_negative(_field(self, "half_extents", (3,), concrete), "Box.half_extents")
        _batch(self, {"pose": 2, "half_extents": 1})
        if T is None:
            return
        tol = _tolerance(self.pose)
        T = T.reshape(-1, 4, 4)
        R = T[:, :3, :3]
        row = np.abs(T[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
        orth = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2))
        bad = np.flatnonzero((row > tol) | (orth > tol) | (np.linalg.det(R) < 0))
        if bad.size:
            index = tuple(int(i) for i in np.unravel_index(bad[0], self.pose.shape[:-2]))
            raise ValueError(
                f"Box.pose{list(index) if index else ''}: expected a rigid transform (rotation block with "
                f"R^T R = I, det R = +1, last row [0, 0, 0, 1]), got |R^T R - I| = {orth[bad[0]]:.3g}, "
                f"det R = {np.linalg.det(R[bad[0]]):.6g}, last row {T[bad[0], 3].tolist()}"
            )


@pytree_dataclass
class Plane:
    """The half-space ``normal . x <= offset`` (its boundary is the plane; the solid side is below it).

    Attributes:
        normal: ``(..., 3)`` unit outward normal.
        offset: ``(...,)`` signed distance of the boundary plane from the origin along ``normal``, metres.
    """

    normal: jax.Array
    offset: jax.Array

    def _check(self, concrete: bool) -> None:
        n = _field(self, "normal", (3,), concrete)
        _field(self, "offset", (), concrete)
        _batch(self, {"normal": 1, "offset": 0})
        if n is not None:
            err = np.abs(np.linalg.norm(n, axis=-1) - 1.0)
            if np.any(err > _tolerance(self.normal)):
                bad = tuple(int(i) for i in np.argwhere(err > _tolerance(self.normal))[0])
                raise ValueError(f"Plane.normal: expected unit vectors, got norm {1 + err[bad]:.6g} at index {bad}")


def unchecked(cls: type[T], **fields) -> T:
    """A shape of derived values (e.g. moved by a pose), built without the constructor's checks:
    they already hold, and a host check of every batch entry at every call would cost time."""
    obj = object.__new__(cls)
    for name, value in fields.items():
        object.__setattr__(obj, name, value)
    return obj


Shape = Sphere | Capsule | Box | Plane
SHAPES: tuple[type, ...] = (Sphere, Capsule, Box, Plane)
