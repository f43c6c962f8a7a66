"""Collision shapes: sphere, capsule, box, cylinder, convex polytope and half-space, as pytrees of arrays.

A kind is one class here: its fields with their trailing ranks (:attr:`TRAILING`), its host
checks, and, for the convex solids, its *core* and *support*: every solid is a core (a point, a
segment, a box, a cylinder) swept by a ball of ``rounding`` (0 for the sharp ones), and
``core_support(n)`` is the core's farthest point along world directions ``n`` (what the general
distance of :mod:`diffkin.collision._gjk` reads), ``coords(p)`` and ``point(coords)`` name a point of
the core by coordinates that move with the shape (so that a witness point's derivative is its
shape's); ``centre()`` and ``bounding_radius()`` give a ball that contains the solid (cheap lower
bounds of distances). What two kinds' distance is lives in
:mod:`diffkin.collision._distance`'s pair table.

Every field is an array leaf with any leading batch axes (they broadcast against each other and
against the other shape of :func:`diffkin.collision.distance`). The constructors accept anything
array-like (Python numbers and lists become arrays of JAX's default float type; integer arrays
become floats) and check, on the host, the trailing shape of every field always and its values
(non-negative radii and half extents, rigid box poses, unit plane normals, finite numbers) when
they are concrete: under ``jit``/``vmap``/``grad`` only the shapes are checked and nothing raises.
"""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._pytree import pytree_dataclass
from diffkin._xla import summed_products

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


def _rigid(shape_obj, T: np.ndarray | None) -> None:
    """Raise unless every pose of ``shape_obj.pose`` (its float64 values ``T``, if concrete) is rigid."""
    if T is None:
        return
    name = type(shape_obj).__name__
    tol = _tolerance(shape_obj.pose)
    T = T.reshape(-1, 4, 4)
    R = T[:, :3, :3]
    row = np.abs(T[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    orth = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2))
    bad = np.flatnonzero((row > tol) | (orth > tol) | (np.linalg.det(R) < 0))
    if bad.size:
        index = tuple(int(i) for i in np.unravel_index(bad[0], shape_obj.pose.shape[:-2]))
        raise ValueError(
            f"{name}.pose{list(index) if index else ''}: expected a rigid transform (rotation block with "
            f"R^T R = I, det R = +1, last row [0, 0, 0, 1]), got |R^T R - I| = {orth[bad[0]]:.3g}, "
            f"det R = {np.linalg.det(R[bad[0]]):.6g}, last row {T[bad[0], 3].tolist()}"
        )


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

    TRAILING: ClassVar[dict[str, int]] = {"center": 1, "radius": 0}

    def _check(self, concrete: bool) -> None:
        _field(self, "center", (3,), concrete)
        _non_negative(_field(self, "radius", (), concrete), "Sphere.radius")
        _batch(self, {"center": 1, "radius": 0})

    def core_support(self, n: jax.Array) -> jax.Array:
        return jnp.broadcast_to(self.center, jnp.broadcast_shapes(self.center.shape, n.shape))

    def rounding(self) -> jax.Array:
        return self.radius

    def centre(self) -> jax.Array:
        return self.center

    def bounding_radius(self) -> jax.Array:
        return self.radius

    def bounding_box(self) -> Box:
        """A box that contains the shape (:func:`diffkin.collision._distance.lower_bound` of distances)."""
        return unchecked(
            Box,
            pose=_translation(self.center),
            half_extents=jnp.broadcast_to(self.radius[..., None], self.center.shape),
        )

    def coords(self, p: jax.Array) -> jax.Array:
        """Coordinates of core points ``p`` that move with the shape (:meth:`point` inverts them)."""
        return jnp.zeros(p.shape[:-1], p.dtype)

    def solid(self) -> Solid:
        return Solid(
            _translation(self.center),
            jnp.zeros(self.radius.shape + (1, 3), self.radius.dtype),
            0.0 * self.radius,
            self.radius,
        )

    def moved_by(self, T: jax.Array) -> Sphere:
        """The shape in the outer frame of poses ``T (..., 4, 4)`` (the shape given in their inner frame)."""
        return unchecked(Sphere, center=_apply(T, self.center), radius=self.radius)

    def point(self, coords: jax.Array) -> jax.Array:
        return jnp.broadcast_to(self.center, jnp.broadcast_shapes(self.center.shape, coords.shape + (3,)))


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

    TRAILING: ClassVar[dict[str, int]] = {"a": 1, "b": 1, "radius": 0}

    def _check(self, concrete: bool) -> None:
        _field(self, "a", (3,), concrete)
        _field(self, "b", (3,), concrete)
        _non_negative(_field(self, "radius", (), concrete), "Capsule.radius")
        _batch(self, {"a": 1, "b": 1, "radius": 0})

    def core_support(self, n: jax.Array) -> jax.Array:
        first = jnp.sum(n * (self.a - self.b), axis=-1, keepdims=True) >= 0
        return jnp.where(first, self.a, self.b)

    def rounding(self) -> jax.Array:
        return self.radius

    def centre(self) -> jax.Array:
        return 0.5 * (self.a + self.b)

    def bounding_radius(self) -> jax.Array:
        return 0.5 * jnp.sqrt(jnp.sum((self.b - self.a) ** 2, axis=-1)) + self.radius

    def bounding_box(self) -> Box:
        return unchecked(
            Box, pose=_translation(self.centre()), half_extents=0.5 * jnp.abs(self.b - self.a) + self.radius[..., None]
        )

    def coords(self, p: jax.Array) -> jax.Array:
        axis = self.b - self.a
        return jnp.clip(_ratio(jnp.sum((p - self.a) * axis, axis=-1), jnp.sum(axis * axis, axis=-1)), 0.0, 1.0)

    def point(self, coords: jax.Array) -> jax.Array:
        return self.a + coords[..., None] * (self.b - self.a)

    def solid(self) -> Solid:
        c = self.centre()
        return Solid(_translation(c), jnp.stack([self.a - c, self.b - c], axis=-2), 0.0 * self.radius, self.radius)

    def moved_by(self, T: jax.Array) -> Capsule:
        return unchecked(Capsule, a=_apply(T, self.a), b=_apply(T, self.b), radius=self.radius)


@pytree_dataclass
class Box:
    """A solid box (cuboid).

    Attributes:
        pose: ``(..., 4, 4)`` rigid pose ``T_world_box`` of the box's centre and axes.
        half_extents: ``(..., 3)`` half edge lengths along the box's x, y, z axes, metres, ``>= 0``.
    """

    pose: jax.Array
    half_extents: jax.Array

    TRAILING: ClassVar[dict[str, int]] = {"pose": 2, "half_extents": 1}

    def _check(self, concrete: bool) -> None:
        T = _field(self, "pose", (4, 4), concrete)
        _non_negative(_field(self, "half_extents", (3,), concrete), "Box.half_extents")
        _batch(self, {"pose": 2, "half_extents": 1})
        _rigid(self, T)

    def core_support(self, n: jax.Array) -> jax.Array:
        R = self.pose[..., :3, :3]
        local = jnp.einsum("...ji,...j->...i", R, n)
        corner = jnp.where(local >= 0, self.half_extents, -self.half_extents)
        return jnp.einsum("...ij,...j->...i", R, corner) + self.pose[..., :3, 3]

    def rounding(self) -> jax.Array:
        return jnp.zeros(self.half_extents.shape[:-1], self.half_extents.dtype)

    def centre(self) -> jax.Array:
        return self.pose[..., :3, 3]

    def bounding_radius(self) -> jax.Array:
        return jnp.sqrt(jnp.sum(self.half_extents**2, axis=-1))

    def bounding_box(self) -> Box:
        return self

    def coords(self, p: jax.Array) -> jax.Array:
        return _posed_coords(self.pose, p, self.half_extents)

    def point(self, coords: jax.Array) -> jax.Array:
        return _posed_point(self.pose, coords, self.half_extents)

    def solid(self) -> Solid:
        corners = self.half_extents[..., None, :] * jnp.asarray(_CORNERS, self.half_extents.dtype)
        return Solid(self.pose, corners, self.rounding(), self.rounding())

    def moved_by(self, T: jax.Array) -> Box:
        return unchecked(Box, pose=T @ self.pose, half_extents=self.half_extents)


@pytree_dataclass
class Cylinder:
    """A solid circular cylinder: its axis the local z of ``pose``, centred on the pose's origin.

    Attributes:
        pose: ``(..., 4, 4)`` rigid pose ``T_world_cylinder`` of the centre and axes (axis: the third column).
        radius: ``(...,)`` radius, metres, ``>= 0``.
        half_length: ``(...,)`` half the length along the axis, metres, ``>= 0``.
    """

    pose: jax.Array
    radius: jax.Array
    half_length: jax.Array

    TRAILING: ClassVar[dict[str, int]] = {"pose": 2, "radius": 0, "half_length": 0}

    def _check(self, concrete: bool) -> None:
        T = _field(self, "pose", (4, 4), concrete)
        _non_negative(_field(self, "radius", (), concrete), "Cylinder.radius")
        _non_negative(_field(self, "half_length", (), concrete), "Cylinder.half_length")
        _batch(self, {"pose": 2, "radius": 0, "half_length": 0})
        _rigid(self, T)

    def core_support(self, n: jax.Array) -> jax.Array:
        """The rim point farthest along ``n``: the radial direction of ``n`` (any, where ``n`` is along the
        axis) and the cap that ``n`` points to."""
        R = self.pose[..., :3, :3]
        m = jnp.einsum("...ji,...j->...i", R, n)
        rho_sq = m[..., 0] ** 2 + m[..., 1] ** 2
        ok = rho_sq > 0
        scale = jnp.where(ok, self.radius / jnp.sqrt(jnp.where(ok, rho_sq, 1.0)), 0.0)
        z = jnp.where(m[..., 2] >= 0, self.half_length, -self.half_length)
        local = jnp.stack(jnp.broadcast_arrays(scale * m[..., 0], scale * m[..., 1], z), axis=-1)
        return jnp.einsum("...ij,...j->...i", R, local) + self.pose[..., :3, 3]

    def rounding(self) -> jax.Array:
        return jnp.zeros_like(self.radius)

    def centre(self) -> jax.Array:
        return self.pose[..., :3, 3]

    def bounding_radius(self) -> jax.Array:
        return jnp.sqrt(self.radius**2 + self.half_length**2)

    def _extents(self) -> jax.Array:
        return jnp.stack(jnp.broadcast_arrays(self.radius, self.radius, self.half_length), axis=-1)

    def bounding_box(self) -> Box:
        return unchecked(Box, pose=self.pose, half_extents=self._extents())

    def coords(self, p: jax.Array) -> jax.Array:
        return _posed_coords(self.pose, p, self._extents())

    def point(self, coords: jax.Array) -> jax.Array:
        return _posed_point(self.pose, coords, self._extents())

    def solid(self) -> Solid:
        caps = jnp.stack(jnp.broadcast_arrays(0.0 * self.half_length, 0.0 * self.half_length, self.half_length), -1)
        return Solid(self.pose, jnp.stack([-caps, caps], axis=-2), self.radius, self.rounding())

    def moved_by(self, T: jax.Array) -> Cylinder:
        return unchecked(Cylinder, pose=T @ self.pose, radius=self.radius, half_length=self.half_length)


@pytree_dataclass
class Convex:
    """A convex polytope: the convex hull of its vertices (e.g. of a collision mesh).

    Attributes:
        pose: ``(..., 4, 4)`` rigid pose ``T_world_shape`` of the frame the vertices are given in.
        vertices: ``(..., V, 3)`` points in that frame, metres (repeat one to pad shapes of fewer points).
    """

    pose: jax.Array
    vertices: jax.Array

    TRAILING: ClassVar[dict[str, int]] = {"pose": 2, "vertices": 2}

    def _check(self, concrete: bool) -> None:
        T = _field(self, "pose", (4, 4), concrete)
        _field(self, "vertices", (3,), concrete)
        if jnp.ndim(self.vertices) < 2 or jnp.shape(self.vertices)[-2] == 0:
            raise ValueError(f"Convex.vertices: expected shape (..., V, 3) with V >= 1, got {jnp.shape(self.vertices)}")
        _batch(self, {"pose": 2, "vertices": 2})
        _rigid(self, T)

    def core_support(self, n: jax.Array) -> jax.Array:
        R = self.pose[..., :3, :3]
        m = jnp.einsum("...ji,...j->...i", R, n)
        scores = summed_products(self.vertices, m[..., None, :], axis=-1)  # (..., V)
        pick = jax.nn.one_hot(jnp.argmax(scores, axis=-1), scores.shape[-1], dtype=self.vertices.dtype)
        local = jnp.einsum("...v,...vi->...i", pick, self.vertices)
        return jnp.einsum("...ij,...j->...i", R, local) + self.pose[..., :3, 3]

    def rounding(self) -> jax.Array:
        return jnp.zeros(self.vertices.shape[:-2], self.vertices.dtype)

    def centre(self) -> jax.Array:
        return self.pose[..., :3, 3]

    def bounding_radius(self) -> jax.Array:
        return jnp.sqrt(jnp.max(jnp.sum(self.vertices**2, axis=-1), axis=-1))

    def bounding_box(self) -> Box:
        """The box of the vertices' extremes along the shape's own axes."""
        low, high = jnp.min(self.vertices, axis=-2), jnp.max(self.vertices, axis=-2)
        return unchecked(Box, pose=self.pose @ _translation(0.5 * (low + high)), half_extents=0.5 * (high - low))

    def coords(self, p: jax.Array) -> jax.Array:
        return jnp.einsum("...ji,...j->...i", self.pose[..., :3, :3], p - self.pose[..., :3, 3])

    def point(self, coords: jax.Array) -> jax.Array:
        return jnp.einsum("...ij,...j->...i", self.pose[..., :3, :3], coords) + self.pose[..., :3, 3]

    def solid(self) -> Solid:
        return Solid(self.pose, self.vertices, self.rounding(), self.rounding())

    def moved_by(self, T: jax.Array) -> Convex:
        return unchecked(Convex, pose=T @ self.pose, vertices=self.vertices)


@pytree_dataclass
class Plane:
    """The half-space ``normal . x <= offset`` (its boundary is the plane; the solid side is below it).

    Attributes:
        normal: ``(..., 3)`` unit outward normal.
        offset: ``(...,)`` signed distance of the boundary plane from the origin along ``normal``, metres.
    """

    normal: jax.Array
    offset: jax.Array

    TRAILING: ClassVar[dict[str, int]] = {"normal": 1, "offset": 0}

    def _check(self, concrete: bool) -> None:
        n = _field(self, "normal", (3,), concrete)
        _field(self, "offset", (), concrete)
        _batch(self, {"normal": 1, "offset": 0})
        if n is not None:
            err = np.abs(np.linalg.norm(n, axis=-1) - 1.0)
            if np.any(err > _tolerance(self.normal)):
                bad = tuple(int(i) for i in np.argwhere(err > _tolerance(self.normal))[0])
                raise ValueError(f"Plane.normal: expected unit vectors, got norm {1 + err[bad]:.6g} at index {bad}")


@pytree_dataclass
class Solid:
    """Any convex solid in one form, for the general distance of many kinds in one batch
    (:mod:`diffkin.collision._near`): a core, the convex hull of ``vertices`` plus a disc of radius
    ``disc`` in the local xy plane (a cylinder's rim), swept by a ball of ``radius``. Each kind's
    ``solid()`` gives its own; not a shape of the public API.

    Attributes:
        pose: ``(..., 4, 4)`` rigid pose of the frame of the vertices and the disc.
        vertices: ``(..., V, 3)`` the core's points in that frame.
        disc: ``(...,)`` radius of the disc summed with the points' hull (0: none).
        radius: ``(...,)`` the rounding.
    """

    pose: jax.Array
    vertices: jax.Array
    disc: jax.Array
    radius: jax.Array

    TRAILING: ClassVar[dict[str, int]] = {"pose": 2, "vertices": 2, "disc": 0, "radius": 0}

    def core_support(self, n: jax.Array) -> jax.Array:
        R = self.pose[..., :3, :3]
        m = jnp.einsum("...ji,...j->...i", R, n)
        scores = summed_products(self.vertices, m[..., None, :], axis=-1)  # (..., V)
        points = jnp.broadcast_to(self.vertices, scores.shape + (3,))
        local = jnp.take_along_axis(points, jnp.argmax(scores, axis=-1)[..., None, None], axis=-2)[..., 0, :]
        rho_sq = m[..., 0] ** 2 + m[..., 1] ** 2
        ok = rho_sq > 0
        scale = jnp.where(ok, self.disc / jnp.sqrt(jnp.where(ok, rho_sq, 1.0)), 0.0)
        rim = jnp.stack([scale * m[..., 0], scale * m[..., 1], jnp.zeros_like(scale)], axis=-1)
        return jnp.einsum("...ij,...j->...i", R, local + rim) + self.pose[..., :3, 3]

    def rounding(self) -> jax.Array:
        return self.radius

    def centre(self) -> jax.Array:
        return self.pose[..., :3, 3]

    def bounding_radius(self) -> jax.Array:
        return jnp.sqrt(jnp.max(jnp.sum(self.vertices**2, axis=-1), axis=-1)) + self.disc + self.radius


#: the corners of the unit box ``[-1, 1]^3``
_CORNERS = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)])


def _translation(p: jax.Array) -> jax.Array:
    """``(..., 4, 4)`` poses of no rotation at points ``p (..., 3)``."""
    T = jnp.broadcast_to(jnp.eye(4, dtype=p.dtype), p.shape[:-1] + (4, 4))
    return T.at[..., :3, 3].set(p)


def _apply(T: jax.Array, p: jax.Array) -> jax.Array:
    """Points ``p (..., 3)`` of the inner frame of poses ``T (..., 4, 4)`` in their outer frame."""
    return jnp.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def _ratio(num: jax.Array, den: jax.Array) -> jax.Array:
    """``num / den`` where ``den > 0``, else 0 (a point of a flat shape's centre plane)."""
    ok = den > 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def _posed_coords(pose: jax.Array, p: jax.Array, extents: jax.Array) -> jax.Array:
    """Points ``p`` in a posed shape's frame, in units of its ``extents`` ``(..., 3)``."""
    local = jnp.einsum("...ji,...j->...i", pose[..., :3, :3], p - pose[..., :3, 3])
    return _ratio(local, extents)


def _posed_point(pose: jax.Array, units: jax.Array, extents: jax.Array) -> jax.Array:
    return jnp.einsum("...ij,...j->...i", pose[..., :3, :3], units * extents) + pose[..., :3, 3]


def unchecked(cls: type[T], **fields) -> T:
    """A shape of derived values (e.g. moved by a pose), built without the constructor's checks:
    they already hold, and a host check of every batch entry at every call would cost time."""
    obj = object.__new__(cls)
    for name, value in fields.items():
        object.__setattr__(obj, name, value)
    return obj


def taken(shape, batch: tuple[int, ...], idx: jax.Array):
    """The entries ``idx`` (flat indices of the broadcast ``batch``) of every field of ``shape``, read
    without broadcasting the fields first (a robot's polytope vertices are not copied per pair)."""
    multi = jnp.unravel_index(idx, batch) if batch else ()
    out = {}
    for name, r in type(shape).TRAILING.items():
        v = getattr(shape, name)
        own = (1,) * (len(batch) - (jnp.ndim(v) - r)) + jnp.shape(v)[: jnp.ndim(v) - r]
        flat = jnp.zeros_like(idx)
        for m, size in zip(multi, own, strict=True):
            flat = flat * size + (m if size > 1 else 0)
        tail = jnp.shape(v)[jnp.ndim(v) - r :]
        out[name] = jnp.reshape(v, (int(np.prod(own)),) + tail)[flat]
    return unchecked(type(shape), **out)


Shape = Sphere | Capsule | Box | Cylinder | Convex | Plane
#: every kind, in the order a World stacks them (and ``world_distances`` lists obstacles)
SHAPES: tuple[type, ...] = (Sphere, Capsule, Box, Cylinder, Convex, Plane)
#: the bounded kinds, in the order a robot's Geometry stacks them
SOLIDS: tuple[type, ...] = SHAPES[:-1]
