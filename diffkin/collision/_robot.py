"""Distances of a robot: its shapes against each other (self) and against a :class:`World` of obstacles."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._xla import blocks_joined, configurations_in_steps
from diffkin.collision._distance import distance
from diffkin.collision._geometry import KINDS, Geometry, placed
from diffkin.collision._shapes import SHAPES, unchecked
from diffkin.models.robot import Robot

#: Batches larger than this go through :func:`diffkin._xla.in_steps`, ``STEP`` configurations at a
#: time: the memory then stays bounded whatever the batch (at 100,000 Panda configurations the
#: unstepped world distances asked for a 52 GB buffer), and each step's intermediates stay in cache.
#: Each step is two independent halves, one per CPU thread (docs/performance.md).
STEP = 1024


def _fields(shape) -> dict[str, jax.Array]:
    return {name: getattr(shape, name) for name in type(shape).TRAILING}


def batch_shape(shape) -> tuple[int, ...]:
    return jnp.broadcast_shapes(
        *(jnp.shape(v)[: jnp.ndim(v) - type(shape).TRAILING[k]] for k, v in _fields(shape).items())
    )


def _map(shape, fn):
    """A shape of the same kind with ``fn(value, trailing_rank)`` applied to every field (unchecked)."""
    return unchecked(type(shape), **{k: fn(v, type(shape).TRAILING[k]) for k, v in _fields(shape).items()})


@jax.tree_util.register_pytree_node_class
class World:
    """Obstacles: every shape given, stacked per kind (spheres, capsules, boxes, cylinders, convex
    polytopes, half-spaces, in that order: :data:`diffkin.collision._shapes.SHAPES`).

    ``World(*shapes)``: each argument a :class:`Sphere`, :class:`Capsule`, :class:`Box`,
    :class:`Cylinder`, :class:`Convex` or :class:`Plane` whose last batch axis lists obstacles (a
    shape without batch axes is one obstacle). Leading batch axes ``(...)`` before it make a world
    per problem: ``Box(pose (100, 11, 4, 4), ...)`` is 11 boxes for each of 100 problems, and
    problem ``i`` (of configurations or IK targets of batch shape ``(100,)``) sees only its own. The
    leading axes of all arguments broadcast (a shared floor beside per-problem boxes). A world is a
    pytree of fixed shapes, so one compiled function serves any obstacles of the same counts: to
    change the number of obstacles without recompiling, pad with far-away shapes.

    Attributes:
        spheres, capsules, boxes, cylinders, convexes, planes: each kind stacked, batch axes
            ``(..., n_kind)`` (``n_kind`` possibly 0).
        batch: the problem axes ``(...)``, ``()`` for one world shared by every problem.
    """

    def __init__(self, *shapes):
        groups: dict[type, list] = {cls: [] for cls in SHAPES}
        for i, shape in enumerate(shapes):
            if not isinstance(shape, SHAPES):
                raise TypeError(
                    f"World: argument {i}: expected a Sphere, Capsule, Box, Cylinder, Convex or Plane, "
                    f"got {type(shape).__name__}"
                )
            groups[type(shape)].append(shape)
        leading = [batch_shape(s)[:-1] for group in groups.values() for s in group]
        try:
            lead = tuple(jnp.broadcast_shapes(*leading)) if leading else ()
        except ValueError:
            raise ValueError(
                f"World: the shapes' problem axes (all batch axes but the last) do not broadcast: {leading}"
            ) from None
        dtype = (
            jnp.result_type(*(v for g in groups.values() for s in g for v in _fields(s).values()))
            if shapes
            else jnp.result_type(float)
        )
        stacked: list[Any] = []
        cls: Any
        for cls in SHAPES:
            if groups[cls]:
                parts = [_obstacles_of(s, lead) for s in groups[cls]]
                stacked.append(
                    unchecked(
                        cls,
                        **{k: jnp.concatenate([getattr(s, k) for s in parts], axis=len(lead)) for k in cls.TRAILING},
                    )
                )
            else:
                empty = {
                    k: jnp.zeros(lead + (0,) + {"pose": (4, 4), "vertices": (1, 3)}.get(k, (3,) * r), dtype)
                    for k, r in cls.TRAILING.items()
                }
                stacked.append(unchecked(cls, **empty))
        self._kinds = tuple(stacked)

    spheres = property(lambda self: self._kinds[0])
    capsules = property(lambda self: self._kinds[1])
    boxes = property(lambda self: self._kinds[2])
    cylinders = property(lambda self: self._kinds[3])
    convexes = property(lambda self: self._kinds[4])
    planes = property(lambda self: self._kinds[5])

    @property
    def batch(self) -> tuple[int, ...]:
        """The problem axes ``(...)``: ``()`` for a world shared by every problem."""
        return batch_shape(self._kinds[0])[:-1]

    @property
    def size(self) -> int:
        """The number of obstacles ``W`` (of each problem)."""
        return sum(int(batch_shape(s)[-1]) for s in self.kinds())

    def kinds(self) -> tuple:
        """Each kind stacked, in the order of :data:`diffkin.collision._shapes.SHAPES`."""
        return self._kinds

    def tree_flatten(self):
        return self._kinds, None

    @classmethod
    def tree_unflatten(cls, aux, children):
        obj = object.__new__(cls)
        obj._kinds = tuple(children)
        return obj


def _obstacles_of(shape, lead: tuple[int, ...]):
    """The obstacles of one ``World`` argument, every field broadcast to batch axes ``lead + (n,)`` (one
    obstacle, ``n = 1``, for a shape without batch axes)."""
    batch = batch_shape(shape)
    n = batch[-1] if batch else 1
    return _map(shape, lambda v, r: jnp.broadcast_to(v, lead + (n,) + jnp.shape(v)[jnp.ndim(v) - r :]))


def check_geometry(robot, geom) -> None:
    """Raise unless ``robot`` is a Robot and ``geom`` a Geometry loaded for it."""
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected a diffkin.Robot, got {type(robot).__name__}")
    if not isinstance(geom, Geometry):
        raise TypeError(f"geom: expected a diffkin.collision.Geometry (dk.collision.load), got {type(geom).__name__}")
    names = robot.frame_names
    for frame, link in zip(geom.shape_frames, geom.shape_links, strict=True):
        if frame >= len(names) or names[frame] != link:
            raise ValueError(
                f"geom: its shape on {link!r} is not on a frame of robot {robot.name!r} of that name "
                "(load the geometry with this robot: dk.collision.load(source, robot))"
            )


def self_distances(robot: Robot, geom: Geometry, q, base=None) -> jax.Array:
    """Signed distances of the robot's self-collision pairs.

    Args:
        robot: the :class:`diffkin.Robot`.
        geom: its :class:`Geometry` (:func:`diffkin.collision.load`).
        q: ``(..., dof)`` joint values.
        base: ``(..., 4, 4)`` pose ``T_world_root`` of the root (a floating base); default identity.

    Returns:
        ``(..., P)``, metres, in ``geom.pairs`` order.
    """
    check_geometry(robot, geom)
    return per_problem(lambda q_, base_, _: _self_distances(robot, geom, q_, base_), q, base, None, last=True)


def batch_last(shapes) -> list:
    """Placed shapes of one flat batch ``(N, n_kind)`` as ``(n_kind, N)`` (a field that does not move: ``(n_kind, 1)``).

    The pair functions are entry by entry over the broadcast batch, and XLA's CPU loops vectorise
    the innermost axis: with the configurations last it is long (not the few obstacles or pairs).
    """
    return [_map(shape, lambda v, r: jnp.moveaxis(v if jnp.ndim(v) - r > 1 else v[None], 0, 1)) for shape in shapes]


def _self_distances(robot: Robot, geom: Geometry, q, base) -> jax.Array:
    """``(P, N)`` for ``q (N, dof)``."""
    return self_of_placed(geom, batch_last(placed(robot, geom, q, base)), q.shape[0])


def pair_blocks(geom: Geometry) -> list[tuple[np.ndarray, int, int, np.ndarray, np.ndarray]]:
    """The self-collision pairs grouped by the kinds of their two shapes: per group, ``(rows, kind_a,
    kind_b, index_a, index_b)``: the rows of ``geom.pairs`` and each side's index within its kind."""
    counts = geom.counts
    starts = np.cumsum((0, *counts))
    pairs = geom.pairs
    kind_of = np.searchsorted(starts, np.arange(sum(counts)), side="right") - 1
    out = []
    for ka in range(len(counts)):
        for kb in range(ka, len(counts)):
            rows = np.flatnonzero((kind_of[pairs[:, 0]] == ka) & (kind_of[pairs[:, 1]] == kb)) if len(pairs) else None
            if rows is not None and len(rows):
                out.append((rows, ka, kb, pairs[rows, 0] - starts[ka], pairs[rows, 1] - starts[kb]))
    return out


def expanded(shape):
    """The shapes with a new axis 1: robot shapes ``(n_kind, 1, N, ...)``, obstacles ``(n_obstacles, 1, ...)``,
    whose distances broadcast to ``(n_kind, n_obstacles, N)``."""
    return _map(shape, lambda v, r: jnp.expand_dims(v, 1))


def take(shape, idx):
    """The shapes ``idx`` of a batch-last kind (:func:`batch_last`)."""
    return _map(shape, lambda v, r: jnp.take(v, idx, axis=0))


def self_of_placed(geom: Geometry, shapes, n: int) -> jax.Array:
    """``(P, n)`` the self-collision distances (``geom.pairs`` order) of shapes placed batch-last."""
    blocks = pair_blocks(geom)
    if not blocks:
        return jnp.zeros((0, n), jnp.result_type(float))
    pieces = [distance(take(shapes[ka], ia), take(shapes[kb], ib)) for _, ka, kb, ia, ib in blocks]
    out = jnp.concatenate([jnp.broadcast_to(p, (p.shape[0], n)) for p in pieces], axis=0)
    inverse = np.argsort(np.concatenate([rows for rows, *_ in blocks]))
    return out[inverse] if not np.array_equal(inverse, np.arange(len(inverse))) else out


def world_distances(robot: Robot, geom: Geometry, q, world: World, base=None) -> jax.Array:
    """Signed distances of every robot shape to every obstacle.

    Args:
        robot, geom, q, base: as :func:`self_distances`.
        world: the obstacles (:class:`World`), in the world frame; a world per problem when it has
            problem axes (:attr:`World.batch`, broadcast with those of ``q``).

    Returns:
        ``(..., S, W)``, metres: shapes in :attr:`Geometry.shape_names` order, obstacles in the
        world's order (spheres, capsules, boxes, cylinders, convex polytopes, half-spaces).
    """
    check_geometry(robot, geom)
    _check_world(world, required=True)
    return per_problem(
        lambda q_, base_, world_: world_of_placed(batch_last(placed(robot, geom, q_, base_)), world_, q_.shape[0]),
        q,
        base,
        world,
        last=True,
    )


def _check_world(world, required: bool) -> None:
    if (world is not None or required) and not isinstance(world, World):
        expected = "a diffkin.collision.World" + ("" if required else " or None")
        raise TypeError(f"world: expected {expected}, got {type(world).__name__}")


def per_problem(fn, q, base, world: World | None, last: bool = False) -> jax.Array:
    """``fn(q, base, world)`` of flat configurations ``(N, dof)``, :data:`STEP` at a time when the batch
    is large (:func:`configurations_in_steps`), with the world of each configuration: a shared one
    as it is, per-problem ones flattened with the configurations (:func:`obstacles_last` reads both)."""
    if world is None or not world.batch:
        return configurations_in_steps(lambda q_, base_: fn(q_, base_, world), q, base, STEP, last, halves=True)
    return configurations_in_steps(fn, q, base, STEP, last, halves=True, extra=world, extra_batch=world.batch)


def obstacles_last(world: World) -> list:
    """Each kind of obstacles laid out to broadcast against robot shapes ``(n_kind, 1, N, ...)``
    (:func:`batch_last`, :func:`expanded`): a shared world's ``(n_obstacles, 1, ...)``, a world per
    configuration (batch ``(N,)``) as ``(n_obstacles, N, ...)``."""
    if not world.batch:
        return [expanded(o) for o in world.kinds()]
    return [_map(o, lambda v, r: jnp.moveaxis(v, 0, 1)) for o in world.kinds()]


def world_of_placed(shapes, world: World, n: int) -> jax.Array:
    """``(S, W, n)`` the distances of shapes placed batch-last (:func:`batch_last`) to the obstacles
    (:func:`obstacles_last`)."""
    obstacles = obstacles_last(world)
    blocks = []
    for shape in shapes:
        blocks.append([_distance(expanded(shape), o) for o in obstacles])  # (n_kind, n_obstacles, N) each
    return blocks_joined(blocks, n)


def _distance(a, b) -> jax.Array:
    """:func:`distance`, or its empty array where ``a`` or ``b`` has no shape (the pair's code is not traced:
    a robot of one kind among obstacles of one kind would trace all 36 pairs of kinds)."""
    batch = tuple(jnp.broadcast_shapes(batch_shape(a), batch_shape(b)))
    if np.prod(batch):
        return distance(a, b)
    return jnp.zeros(batch, jnp.result_type(*jax.tree.leaves((a, b))))


def clearance(robot: Robot, geom: Geometry, q, world: World | None = None, base=None) -> jax.Array:
    """The smallest signed distance: of the self-collision pairs and, if ``world`` is given, of the shapes
    to it (a world per problem when it has problem axes, as :func:`world_distances`).

    Returns:
        ``(...,)``, metres (``inf`` if there is nothing to measure).
    """
    check_geometry(robot, geom)
    _check_world(world, required=False)
    return smallest_distance(robot, geom, q, world, base)


def smallest_distance(robot: Robot, geom: Geometry, q, world: World | None, base=None, self_pairs: bool = True):
    """:func:`clearance` (arguments checked), over the self pairs only where ``self_pairs``: ``(...,)``.

    One pass per step gives both the self and the world distances, reduced within the step."""

    def smallest(q_, base_, world_):
        n = q_.shape[0]
        shapes = batch_last(placed(robot, geom, q_, base_))
        parts = [self_of_placed(geom, shapes, n)] if self_pairs else []
        if world_ is not None:
            parts.append(world_of_placed(shapes, world_, n).reshape(-1, n))
        if not parts:
            return jnp.full((n,), jnp.inf, q_.dtype)
        return jnp.min(jnp.concatenate(parts, axis=0), axis=0, initial=jnp.inf)

    return per_problem(smallest, q, base, world)


__all__ = ["KINDS", "World", "clearance", "self_distances", "world_distances"]
