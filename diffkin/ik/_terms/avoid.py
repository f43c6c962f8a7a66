"""Clearance: the robot's collision shapes kept apart from each other and from the obstacles.

One-sided residuals, zero where every distance is at least ``margin + BAND``:

- one row per self-collision pair: ``a = max(0, margin + BAND - d)``;
- one row per robot shape against the world: ``sqrt(sum_o a_o^2)`` over the obstacles ``o``.

A row's Jacobian is the motion of its distance: the gradient of each distance with respect to the
placed shapes (reverse mode through :func:`diffkin.collision.distance`), turned into a wrench
``[f; tau]`` on the shape's frame and contracted with that frame's space twist per column of the
state (a point ``p`` of the frame moves by ``v + w x p``). It is exact where the closest features
are unique (:mod:`diffkin.collision`).

The band starts the push before the margin is reached, so that an iterate approaching an obstacle
is turned aside rather than stopped at it; success needs the exact clearance ``>= margin`` only:
the term's error is 0 when it holds and the largest float when it does not.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from diffkin import _rigid as rg
from diffkin._pytree import pytree_dataclass, static
from diffkin.collision._distance import distance, motion
from diffkin.collision._geometry import Geometry, moved
from diffkin.collision._robot import (
    World,
    batch_last,
    expanded,
    kind_size,
    pair_blocks,
    self_distances,
    take,
    world_distances,
    world_of_placed,
)
from diffkin.collision._shapes import Box, Capsule, Sphere
from diffkin.ik._terms import Rows

ROUND = (Sphere, Capsule)

#: metres above the margin where the residual starts (a centimetre: the size of a gripper finger).
BAND = 0.01


@pytree_dataclass
class Avoid:
    """What IK keeps clear: ``dk.ik.solve(robot, targets, avoid=dk.ik.Avoid(geom, world, margin))``.

    Attributes:
        geom: the robot's :class:`diffkin.collision.Geometry` (:func:`diffkin.collision.load`).
        world: the obstacles (:class:`diffkin.collision.World`, world frame), or ``None``.
        margin: metres, ``>= 0``: success needs every checked distance at least this (a scalar,
            traced: one compilation serves every margin).
        self_collision: static; also keep ``geom.pairs`` apart.
    """

    geom: Geometry
    world: World | None = None
    margin: jax.Array = 0.0  # type: ignore[assignment]
    self_collision: bool = static(default=True)

    def _check(self, concrete: bool) -> None:
        if not isinstance(self.geom, Geometry):
            raise TypeError(
                f"Avoid.geom: expected a diffkin.collision.Geometry (dk.collision.load), got {type(self.geom).__name__}"
            )
        if self.world is not None and not isinstance(self.world, World):
            raise TypeError(f"Avoid.world: expected a diffkin.collision.World or None, got {type(self.world).__name__}")
        if not isinstance(self.self_collision, bool):
            raise TypeError(f"Avoid.self_collision: expected a bool, got {type(self.self_collision).__name__}")
        if jnp.ndim(self.margin) != 0:
            raise ValueError(f"Avoid.margin: expected a scalar (metres), got shape {jnp.shape(self.margin)}")
        if concrete and not (np.isfinite(float(self.margin)) and float(self.margin) >= 0):
            raise ValueError(f"Avoid.margin: expected a finite distance >= 0 (metres), got {float(self.margin)}")
        if _obstacles(self) is None and not (self.self_collision and len(self.geom.pairs)):
            raise ValueError("Avoid: nothing to keep clear (no obstacles in world and no self-collision pairs)")

    def cast(self, dtype) -> Avoid:
        """The arrays in ``dtype`` (the solver's)."""
        return jax.tree.map(lambda x: jnp.asarray(x, dtype), self)

    def clearance(self, robot, q, base=None) -> jax.Array:
        """``(...,)`` metres: the smallest distance this checks at ``q`` ``(..., dof)`` (the self pairs
        when ``self_collision``, every shape to the world), ``inf`` if nothing is checked."""
        parts = [self_distances(robot, self.geom, q, base)] if self.self_collision else []
        world = _obstacles(self)
        if world is not None:
            w = world_distances(robot, self.geom, q, world, base)
            parts.append(w.reshape(*w.shape[:-2], -1))
        return jnp.min(jnp.concatenate(parts, axis=-1), axis=-1, initial=jnp.inf)


def _obstacles(avoid: Avoid) -> World | None:
    """The world of ``avoid`` if it has obstacles (at least one shape), else ``None``."""
    return avoid.world if avoid.world is not None and avoid.world.size > 0 else None


def _wrench(shape, grad) -> jax.Array:
    """``(n, P, 6)`` ``[f; tau]``: the distance gradient ``grad`` (a shape of the same kind) of placed
    shapes ``(n, P, ...)`` as a wrench at the world origin: ``dd = f . v + tau . w`` when the shapes
    move by the space twist ``[v; w]`` (a point ``p`` by ``v + w x p``, a box axis ``R_j`` by ``w x R_j``)."""
    if isinstance(shape, Sphere):
        f = grad.center
        tau = jnp.cross(shape.center, grad.center)
    elif isinstance(shape, Capsule):
        f = grad.a + grad.b
        tau = jnp.cross(shape.a, grad.a) + jnp.cross(shape.b, grad.b)
    else:
        f = grad.pose[..., :3, 3]
        tau = jnp.cross(shape.pose[..., :3, 3], f)
        tau = tau + sum(jnp.cross(shape.pose[..., :3, j], grad.pose[..., :3, j]) for j in range(3))
    return jnp.concatenate([f, tau], axis=-1)


def _pair_wrenches(a, b, weight: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(n, P, 6)`` each: ``weight`` ``(n, P)`` times the wrenches of the distances of the shapes ``a``
    and ``b`` (``(n, P, ...)``): from the closest points for round shapes (:func:`motion`), else by
    reverse mode through :func:`distance` (boxes)."""
    if isinstance(a, ROUND) and isinstance(b, ROUND):
        _, Wa, Wb = motion(a, b)
        return weight[..., None] * Wa, weight[..., None] * Wb
    _, pull = jax.vjp(lambda a, b: jnp.broadcast_to(distance(a, b), weight.shape), a, b)
    ga, gb = pull(weight)
    return _wrench(a, ga), _wrench(b, gb)


def _world_wrenches(shapes, world: World, coef: jax.Array) -> jax.Array:
    """``(S, P, 6)``: per robot shape, ``sum_o coef[s, o] W_so`` over the obstacles ``o``, ``W_so`` the
    wrench of the shape's distance to obstacle ``o`` (``coef`` ``(S, W, P)`` in the order of
    :func:`world_of_placed`)."""
    rows = np.cumsum((0, *(kind_size(s) for s in shapes)))
    kinds = world.kinds()
    cols = np.cumsum((0, *(kind_size(o) for o in kinds)))
    out = []
    for kr, shape in enumerate(shapes):
        total = jnp.zeros((rows[kr + 1] - rows[kr],) + coef.shape[2:] + (6,), coef.dtype)
        moving = expanded(shape)  # (n_kind, 1, P, ...)
        for ko, obstacle in enumerate(kinds):
            if rows[kr + 1] == rows[kr] or cols[ko + 1] == cols[ko]:
                continue
            c = coef[rows[kr] : rows[kr + 1], cols[ko] : cols[ko + 1]]  # (n_kind, n_obstacles, P)
            o = expanded(obstacle)  # (n_obstacles, 1, ...)
            if isinstance(shape, ROUND) and not isinstance(obstacle, Box):
                total = total + jnp.sum(c[..., None] * motion(moving, o)[1], axis=1)
            else:
                _, pull = jax.vjp(lambda s, o=o, c=c: jnp.broadcast_to(distance(s, o), c.shape), moving)
                (grad,) = pull(c)
                total = total + _wrench(moving, grad)[:, 0]
        out.append(total)
    return jnp.concatenate(out)


@dataclasses.dataclass(frozen=True)
class AvoidTerm:
    """The clearance term of a problem (static; its arrays are an :class:`Avoid` in the solver's dtype).

    Attributes:
        frames: the frames carrying shapes (the joints that move them move the term).
        slots: per shape, the index of its frame in ``frames``.
        self_collision: keep the self pairs apart.
    """

    frames: tuple[int, ...]
    slots: tuple[int, ...]
    self_collision: bool

    @classmethod
    def of(cls, avoid: Avoid) -> AvoidTerm:
        frames = tuple(sorted(set(avoid.geom.shape_frames)))
        return cls(frames, tuple(frames.index(f) for f in avoid.geom.shape_frames), avoid.self_collision)

    def bind(self, avoid: Avoid) -> Avoid:
        return avoid

    def _measure(self, kin, avoid: Avoid):
        """The shapes placed at the state (batch-last), the self pairs' two sides per group
        (:func:`pair_blocks`) and their distances ``(n_pairs, P)``, the world distances ``(S, W, P)``."""
        T = rg.to_matrices([kin.pose(f) for f in self.frames], kin.shape, kin.dtype)  # (P, F, 4, 4)
        shapes = batch_last(moved(avoid.geom, T, self.slots))  # each kind (n_kind, P, ...)
        blocks = pair_blocks(avoid.geom) if self.self_collision else []
        sides = [(take(shapes[ka], ia), take(shapes[kb], ib)) for _, ka, kb, ia, ib in blocks]
        d_self = [
            jnp.broadcast_to(distance(a, b), (len(block[3]),) + kin.shape)
            for (a, b), block in zip(sides, blocks, strict=True)
        ]
        world = _obstacles(avoid)
        d_world = world_of_placed(shapes, world, kin.shape[0]) if world is not None else None
        return shapes, blocks, sides, d_self, d_world

    def clearance(self, kin, avoid: Avoid) -> jax.Array:
        """``(P,)`` the smallest checked distance (exact)."""
        _, _, _, d_self, d_world = self._measure(kin, avoid)
        d = d_self + ([] if d_world is None else [d_world.reshape(-1, kin.shape[0])])
        return jnp.min(jnp.concatenate(d), axis=0)

    def rows(self, kin, avoid: Avoid, jacobian: bool) -> Rows:
        dtype, reach = kin.dtype, avoid.margin + BAND
        shapes, blocks, sides, d_self, d_world = self._measure(kin, avoid)
        a_self = [jnp.maximum(reach - d, 0.0) for d in d_self]  # (n_pairs, P) each
        r = list(a_self)
        if d_world is not None:
            a_world = jnp.maximum(reach - d_world, 0.0)  # (S, W, P)
            squares = jnp.sum(a_world**2, axis=1)
            r_world = jnp.where(squares > 0, jnp.sqrt(jnp.where(squares > 0, squares, 1.0)), 0.0)  # (S, P)
            r.append(r_world)
        J: list[jax.Array] = []
        if jacobian:
            twists = self._twists(kin)  # (F, C, 6, P)
            slot = np.asarray(self.slots, dtype=np.int64)
            starts = np.cumsum((0, *avoid.geom.counts))
            for (_, ka, kb, ia, ib), (a, b), active in zip(blocks, sides, a_self, strict=True):
                Wa, Wb = _pair_wrenches(a, b, (active > 0).astype(dtype))
                Ja = jnp.einsum("npk,nckp->ncp", Wa, twists[slot[starts[ka] + ia]])
                Jb = jnp.einsum("npk,nckp->ncp", Wb, twists[slot[starts[kb] + ib]])
                J.append(Ja + Jb)
            if avoid.world is not None and d_world is not None:
                coef = a_world / jnp.where(r_world > 0, r_world, 1.0)[:, None]  # d r_world / d(-d_world)
                wrench = _world_wrenches(shapes, avoid.world, coef)  # (S, P, 6)
                J.append(jnp.einsum("spk,sckp->scp", wrench, twists[slot]))
        d = d_self + ([] if d_world is None else [d_world.reshape(-1, kin.shape[0])])
        clear = jnp.min(jnp.concatenate(d), axis=0) >= avoid.margin
        err = jnp.where(clear, 0.0, jnp.finfo(dtype).max).astype(dtype)
        rows = jnp.concatenate(r)
        block = (rows, jnp.concatenate(J) if jacobian else jnp.zeros((rows.shape[0], 0) + kin.shape, dtype))
        return Rows([], [], err, jnp.zeros_like(err), block)

    def _twists(self, kin) -> jax.Array:
        """``(F, C, 6, P)``: per frame carrying shapes, per column of the state, its space twist ``[v; w]``."""
        per_frame = [kin.columns(f) for f in self.frames]
        entries = [e for columns in per_frame for v, w in columns for e in (*v, *w)]
        shape = (len(self.frames), len(per_frame[0]), 6) + kin.shape
        return rg.stack(entries, kin.shape, kin.dtype, axis=0).reshape(shape)

    def screen(self, kin, avoid: Avoid) -> rg.Entry:
        _, _, _, d_self, d_world = self._measure(kin, avoid)
        reach = avoid.margin + BAND
        cost = sum(jnp.sum(jnp.maximum(reach - d, 0.0) ** 2, axis=0) for d in d_self)
        if d_world is not None:
            cost = cost + jnp.sum(jnp.maximum(reach - d_world, 0.0) ** 2, axis=(0, 1))
        return cost
