"""Clearance: the robot's collision shapes kept apart from each other and from the obstacles.

One-sided residuals, zero where every distance is at least ``margin + BAND`` (the band narrows to
the targets' error as they converge: :meth:`AvoidTerm.rows`):

- one row per self-collision pair: ``a = max(0, margin + BAND - d)``;
- one row per robot shape against the world: ``sqrt(sum_o a_o^2)`` over the obstacles ``o``.

A row's Jacobian is the motion of its distance: a wrench ``[f; tau]`` per shape from the contact's
normal and witness points (:func:`diffkin.collision._distance.motion`), contracted with the space
twist of the shape's frame per column of the state (a point ``p`` of the frame moves by
``v + w x p``). It is exact where the closest features are unique (:mod:`diffkin.collision`).

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
from diffkin._checks import instance
from diffkin._pytree import pytree_dataclass, static
from diffkin._xla import blocks_joined
from diffkin.collision import Geometry, World
from diffkin.collision.interface import (
    NEAR_SHARE,
    batch_last,
    check_geometry,
    expanded,
    moved,
    near_motions,
    obstacles_last,
    pair_blocks,
    smallest_distance,
    take,
)
from diffkin.ik._terms import Rows

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

    def flat(self, batch: tuple[int, ...]) -> Avoid:
        """A world per problem broadcast to the targets' ``batch`` (of a path: its paths) and flattened:
        obstacles ``(n, n_kind, ...)`` (a shared world as it is).

        Raises:
            ValueError: the world's problem axes do not broadcast to ``batch`` (shapes are static: at
                the call, before anything runs).
        """
        if self.world is None or not self.world.batch:
            return self
        try:
            joint = jnp.broadcast_shapes(self.world.batch, batch)
        except ValueError:
            joint = None
        if joint != tuple(batch):
            raise ValueError(
                f"Avoid.world: its problem axes {self.world.batch} must broadcast to the targets' batch shape "
                f"{tuple(batch)} (a world per target; along a path, per path)"
            )
        lead, n = len(self.world.batch), int(np.prod(batch, dtype=np.int64))
        world = jax.tree.map(
            lambda v: jnp.broadcast_to(v, batch + v.shape[lead:]).reshape((n,) + v.shape[lead:]), self.world
        )
        return dataclasses.replace(self, world=world)

    def tiled(self, tile) -> Avoid:
        """A flat world per problem (:meth:`flat`) with ``tile`` (``(n, ...) -> (P, ...)``: the problems a
        search runs, from their targets) applied to its obstacles."""
        if self.world is None or not self.world.batch:
            return self
        return dataclasses.replace(self, world=jax.tree.map(tile, self.world))

    def clearance(self, robot, q, base=None) -> jax.Array:
        """``(...,)`` metres: the smallest distance this checks at ``q`` ``(..., dof)`` (the self pairs
        when ``self_collision``, every shape to the world), ``inf`` if nothing is checked."""
        check_geometry(robot, self.geom)
        return smallest_distance(robot, self.geom, q, _obstacles(self), base, self.self_collision)


def check_avoid(robot, avoid, name: str = "avoid") -> Avoid:
    """``avoid`` if it is an :class:`Avoid` of ``robot``'s collision geometry: the one host-side check of
    every ``avoid=`` (IK, the SRS self-motion, the workspace maps, base placement, trajectories, the viewer;
    each checks its own model's form first).

    Args:
        robot: the :class:`diffkin.Robot` the geometry was loaded for.
        avoid: the value given.
        name: how the message names it (``"avoid"``; ``"avoid[1]"`` for the SRS arm's pair).

    Raises:
        TypeError: ``avoid`` is not an :class:`Avoid`, or ``robot`` not a Robot.
        ValueError: ``avoid.geom`` was not loaded for ``robot``.
    """
    instance(avoid, Avoid, name, "a dk.ik.Avoid(geom, world, margin)")
    check_geometry(robot, avoid.geom)
    return avoid


def _obstacles(avoid: Avoid) -> World | None:
    """The world of ``avoid`` if it has obstacles (at least one shape), else ``None``."""
    return avoid.world if avoid.world is not None and avoid.world.size > 0 else None


def _world_wrench(w_world: list, coef: jax.Array) -> jax.Array:
    """``(S, P, 6)``: per robot shape, ``sum_o coef[s, o] W_so`` over the obstacles, ``W_so`` its wrench
    against obstacle ``o`` (``w_world[kind][obstacle kind]`` ``(n_kind, n_obstacles, P, 6)``; ``coef``
    ``(S, W, P)`` in the order of :func:`world_of_placed`)."""
    out, row = [], 0
    for per_kind in w_world:
        col, total = 0, jnp.zeros((), coef.dtype)
        for W in per_kind:
            c = coef[row : row + W.shape[0], col : col + W.shape[1]]
            total = total + jnp.sum(c[..., None] * W, axis=1)
            col += W.shape[1]
        out.append(jnp.broadcast_to(total, (per_kind[0].shape[0],) + coef.shape[2:] + (6,)))
        row += per_kind[0].shape[0]
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
    #: ``1 / share`` of the pairs measured exactly at a time (:func:`near_motions`)
    share: int = NEAR_SHARE
    #: its rows (every pair's distance and motion) cost far more than a pose target's: a search
    #: iterates without them (:meth:`diffkin.ik._problem.Problem.undeferred`) and checks the clearance
    #: (:meth:`clearance`) of its first round's best states and of every seed of its later rounds; a target
    #: whose states are on its pose but not clear iterates with them in its last rounds
    #: (:func:`diffkin.ik._search._retry_unsolved`).
    deferred = True

    @classmethod
    def of(cls, avoid: Avoid) -> AvoidTerm:
        frames = tuple(sorted(set(avoid.geom.shape_frames)))
        return cls(frames, tuple(frames.index(f) for f in avoid.geom.shape_frames), avoid.self_collision)

    def bind(self, avoid: Avoid) -> Avoid:
        return avoid

    def measure(self, kin, avoid: Avoid, reach, jacobian: bool = False):
        """The self pairs' blocks (:func:`pair_blocks`) with their distances ``(n_pairs, P)`` each and the
        world distances ``(S, W, P)`` at the state, exact below ``reach`` and lower bounds above it
        (:func:`near_motions`); with ``jacobian``, also the wrenches of the self pairs'
        two sides ``(n_pairs, P, 6)`` and of the robot shapes against each obstacle kind
        (``[[(n_kind, n_obstacles, P, 6)]]``)."""
        T = rg.to_matrices([kin.pose(f) for f in self.frames], kin.shape, kin.dtype)  # (P, F, 4, 4)
        shapes = batch_last(moved(avoid.geom, T, self.slots))  # each kind (n_kind, P, ...)
        blocks = pair_blocks(avoid.geom) if self.self_collision else []
        world = _obstacles(avoid)
        n = kin.shape[0]
        pairs = [(take(shapes[ka], ia), take(shapes[kb], ib)) for _, ka, kb, ia, ib in blocks]
        if world is not None:  # each robot kind against each obstacle kind: (n_kind, n_obstacles, P)
            pairs += [(expanded(shape), obstacles) for shape in shapes for obstacles in obstacles_last(world)]
        measured = near_motions(pairs, reach, self.share)
        d_self = [d for d, _, _ in measured[: len(blocks)]]
        w_self = [(Wa, Wb) for _, Wa, Wb in measured[: len(blocks)]] if jacobian else []
        d_world, w_world = None, []
        if world is not None:
            per_kind = len(world.kinds())
            rows = [measured[len(blocks) + k * per_kind : len(blocks) + (k + 1) * per_kind] for k in range(len(shapes))]
            d_world = blocks_joined([[d for d, _, _ in row] for row in rows], n)
            w_world = [[Wa for _, Wa, _ in row] for row in rows] if jacobian else []
        return blocks, d_self, d_world, w_self, w_world

    def _smallest(self, kin, avoid: Avoid, reach) -> jax.Array:
        """``(P,)`` the smallest checked distance: exact below ``reach``, a lower bound above it."""
        _, d_self, d_world, _, _ = self.measure(kin, avoid, reach)
        d = d_self + ([] if d_world is None else [d_world.reshape(-1, kin.shape[0])])
        return jnp.min(jnp.concatenate(d), axis=0)

    def clearance(self, kin, avoid: Avoid, exact=True) -> jax.Array:
        """``(P,)`` the smallest checked distance: exact where ``exact`` (a bool, may be traced), else exact
        only below the margin (only the distances below it need computing) and a lower bound at least
        the margin elsewhere."""
        return self._smallest(kin, avoid, jnp.where(exact, jnp.inf, avoid.margin))

    def slack_of(self, clearance: jax.Array, avoid: Avoid) -> jax.Array:
        """``(P,)`` metres: the slack of a ``clearance`` (:meth:`clearance`), it less the margin (met where
        ``>= 0``)."""
        return clearance - avoid.margin

    def rows(self, kin, avoid: Avoid, jacobian: bool, off=None) -> Rows:
        """The rows of the module docstring, their band narrowed to the targets' error ``off`` ``(P,)``
        where given: a goal that clears the margin is then reached exactly (the rows vanish there),
        not left where the band's push balances the pose's pull."""
        dtype = kin.dtype
        reach = avoid.margin + (BAND if off is None else jnp.minimum(BAND, off))
        blocks, d_self, d_world, w_self, w_world = self.measure(kin, avoid, avoid.margin + BAND, jacobian)
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
            for (_, ka, kb, ia, ib), (Wa, Wb), active in zip(blocks, w_self, a_self, strict=True):
                on = (active > 0).astype(dtype)[..., None]
                Ja = jnp.einsum("npk,nckp->ncp", on * Wa, twists[slot[starts[ka] + ia]])
                Jb = jnp.einsum("npk,nckp->ncp", on * Wb, twists[slot[starts[kb] + ib]])
                J.append(Ja + Jb)
            if d_world is not None:
                coef = a_world / jnp.where(r_world > 0, r_world, 1.0)[:, None]  # d r_world / d(-d_world)
                wrench = _world_wrench(w_world, coef)  # (S, P, 6)
                J.append(jnp.einsum("spk,sckp->scp", wrench, twists[slot]))
        d = d_self + ([] if d_world is None else [d_world.reshape(-1, kin.shape[0])])
        clear = jnp.min(jnp.concatenate(d), axis=0) >= avoid.margin
        err = jnp.where(clear, 0.0, jnp.finfo(dtype).max).astype(dtype)
        rows = jnp.concatenate(r)
        block = (rows, jnp.concatenate(J) if jacobian else jnp.zeros((rows.shape[0], 0) + kin.shape, dtype))
        return Rows([], [], err, jnp.zeros_like(err), block)

    def distances(self, kin, avoid: Avoid, reach) -> tuple[jax.Array, jax.Array]:
        """Every checked distance and its motion, one row each (a velocity-IK step's linearised
        constraints): ``d`` ``(k, P)`` metres (the self pairs, then each robot shape against each
        obstacle), exact below ``reach`` and a lower bound at least ``reach`` above it, and ``J``
        ``(k, C, P)``: ``dd/dx`` per column of the state (zero above ``reach``)."""
        blocks, d_self, d_world, w_self, w_world = self.measure(kin, avoid, reach, True)
        twists = self._twists(kin)  # (F, C, 6, P)
        slot = np.asarray(self.slots, dtype=np.int64)
        starts = np.cumsum((0, *avoid.geom.counts))
        d, J = list(d_self), []
        for (_, ka, kb, ia, ib), (Wa, Wb) in zip(blocks, w_self, strict=True):
            Ja = jnp.einsum("npk,nckp->ncp", Wa, twists[slot[starts[ka] + ia]])
            J.append(Ja + jnp.einsum("npk,nckp->ncp", Wb, twists[slot[starts[kb] + ib]]))
        if d_world is not None:  # (S, W, P) and per robot shape, per obstacle, its wrench
            wrench = jnp.concatenate([jnp.concatenate(per_kind, axis=1) for per_kind in w_world])  # (S, W, P, 6)
            J_world = jnp.einsum("swpk,sckp->swcp", wrench, twists[slot])
            d.append(d_world.reshape(-1, kin.shape[0]))
            J.append(J_world.reshape((-1,) + J_world.shape[2:]))
        return jnp.concatenate(d), jnp.concatenate(J)

    def _twists(self, kin) -> jax.Array:
        """``(F, C, 6, P)``: per frame carrying shapes, per column of the state, its space twist ``[v; w]``."""
        per_frame = [kin.columns(f) for f in self.frames]
        entries = [e for columns in per_frame for v, w in columns for e in (*v, *w)]
        shape = (len(self.frames), len(per_frame[0]), 6) + kin.shape
        return rg.stack(entries, kin.shape, kin.dtype, axis=0).reshape(shape)

    def screen(self, kin, avoid: Avoid) -> rg.Entry:
        reach = avoid.margin + BAND
        _, d_self, d_world, _, _ = self.measure(kin, avoid, reach)
        cost = sum(jnp.sum(jnp.maximum(reach - d, 0.0) ** 2, axis=0) for d in d_self)
        if d_world is not None:
            cost = cost + jnp.sum(jnp.maximum(reach - d_world, 0.0) ** 2, axis=(0, 1))
        return cost
