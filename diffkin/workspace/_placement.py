"""Base placement from a capability map (:func:`diffkin.workspace.base_placement`): the map inverted over a
grid of planar base poses, and the best bases verified by IK (:meth:`Placement.verify`)."""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from diffkin._checks import positive_int
from diffkin.models.robot import Robot
from diffkin.workspace._bins import _orientation_bin
from diffkin.workspace._blocked import blocked, checked
from diffkin.workspace._capability import CapabilityMap, split_bins
from diffkin.workspace._cells import edge_bits, orientation_halves, reached, slice_codes, slices_around


def planar_poses(x, y, yaw, height: float) -> np.ndarray:
    """``T_world_base`` of bases at ``(x, y, height)`` turned by ``yaw`` about the world z axis: ``(..., 4, 4)``."""
    x, y, yaw = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float), np.asarray(yaw, float))
    T = np.zeros((*x.shape, 4, 4))
    c, s = np.cos(yaw), np.sin(yaw)
    T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1] = c, -s, s, c
    T[..., 2, 2] = T[..., 3, 3] = 1.0
    T[..., 0, 3], T[..., 1, 3], T[..., 2, 3] = x, y, height
    return T


@dataclasses.dataclass(frozen=True)
class Verification:
    """The best bases of a :class:`Placement` re-solved by IK on every task.

    Attributes:
        bases: ``(k, 4, 4)`` ``T_world_base`` of the bases, best map score first.
        score: ``(k,)`` the map's fraction of the tasks each base reaches.
        success: ``(k, N)`` bool, whether :func:`diffkin.ik.solve` solved each task from each base.
        verified: ``(k,)`` the fraction of the tasks IK solved from each base.
    """

    bases: np.ndarray
    score: np.ndarray
    success: np.ndarray
    verified: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class Placement:
    """The fraction of the tasks a capability map reaches from each planar base pose of a grid.

    The base of cell ``(i, j, k)`` is ``T_world_base`` at ``(x[i], y[j], base_height)`` turned by
    ``yaw[k]`` about the world z axis (:meth:`base`).

    Attributes:
        score: ``(nx, ny, nyaw)`` the fraction of the tasks whose tool pose in the base frame,
            ``inv(T_world_base) @ T_world_task``, the map reaches.
        x: ``(nx,)`` base x, metres (the centres of the region's cells), world frame.
        y: ``(ny,)`` base y, metres.
        yaw: ``(nyaw,)`` base yaw, radians, ``2 pi k / nyaw``.
        base_height: base z, metres.
        tasks: ``(N, 4, 4)`` ``T_world_task``, the task poses.
        blocked_bases: ``(nx, ny, nyaw)`` bool, with ``avoid``: the bases whose root body is within the
            margin of an obstacle (they collide at every configuration: score 0); ``None`` without.
        blocked_tasks: ``(N,)`` bool, with ``avoid``: the tasks whose tool body, at the task pose, is
            within the margin of an obstacle (they collide at every solution: reached from no base);
            ``None`` without.
    """

    score: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    base_height: float
    tasks: np.ndarray
    blocked_bases: np.ndarray | None = None
    blocked_tasks: np.ndarray | None = None

    def base(self, i, j, k) -> np.ndarray:
        """``T_world_base`` of cell ``(i, j, k)`` (int arrays broadcast together): ``(..., 4, 4)``."""
        return planar_poses(self.x[i], self.y[j], self.yaw[k], self.base_height)

    def best_cells(self, k: int = 1) -> np.ndarray:
        """``(k, 3)`` cells ``(i, j, yaw index)`` of the ``k`` best scores, best first (ties: the first in C order)."""
        k = positive_int(k, "k")
        order = np.argsort(-self.score, axis=None, kind="stable")[: min(k, self.score.size)]
        return np.stack(np.unravel_index(order, self.score.shape), axis=1)

    def best(self, k: int = 1) -> np.ndarray:
        """``(k, 4, 4)`` ``T_world_base`` of the ``k`` best bases, best first."""
        cells = self.best_cells(k)
        return self.base(cells[:, 0], cells[:, 1], cells[:, 2])

    def verify(self, model, k: int = 10, *, avoid=None, key=None, **solve_kwargs) -> Verification:
        """Re-solve every task from each of the ``k`` best bases with :func:`diffkin.ik.solve`.

        The map is a prior and IK the truth: a base whose map score is 1 may miss a task at the
        boundary of the workspace, where a cell holds reachable and unreachable poses.

        Args:
            model: the map's chain, or its ``(robot, frame_name)`` pair (solved with ``base=`` and
                ``avoid=``).
            k: number of bases.
            avoid: a :class:`~diffkin.ik.Avoid` for a ``(robot, frame_name)`` pair: a task counts only
                if solved clear of the obstacles (in the world frame).
            key: a JAX PRNG key for the IK seeds.
            **solve_kwargs: more arguments of :func:`diffkin.ik.solve` (``num_seeds``, tolerances).

        Returns:
            The :class:`Verification`.
        """
        from diffkin import ik

        cells = self.best_cells(k)
        bases = self.base(cells[:, 0], cells[:, 1], cells[:, 2])
        n = self.tasks.shape[0]
        tasks = np.broadcast_to(self.tasks, (len(bases), n, 4, 4))
        if isinstance(model, tuple) and len(model) == 2 and isinstance(model[0], Robot):
            robot, frame = model
            base = np.broadcast_to(bases[:, None], tasks.shape)
            result = ik.solve(robot, {frame: tasks}, base=base, avoid=avoid, key=key, **solve_kwargs)
        else:
            if avoid is not None:
                raise ValueError("avoid: needs a (robot, frame_name) pair as model (collision geometry is a robot's)")
            targets = np.linalg.inv(bases)[:, None] @ tasks  # T_base_task
            result = ik.solve(model, targets, key=key, **solve_kwargs)
        success = np.asarray(result.success, bool)
        return Verification(bases, self.score[tuple(cells.T)], success, success.mean(axis=1))


@functools.partial(jax.jit, static_argnums=(0, 1))
def _task_bins(n_dir: int, n_roll: int, R) -> tuple[jax.Array, jax.Array]:
    """Orientation bins of rotations ``R (M, 3, 3)``, as the map's, and the halves of them they lie in
    along ``u``, ``v`` and the roll: ``(M,)``, ``(M, 3)`` bool."""
    entries = tuple(tuple(R[:, i, j] for j in range(3)) for i in range(3))
    bins = _orientation_bin(entries, n_roll, n_dir)
    return bins, orientation_halves(entries, bins, n_roll, n_dir)


LOOK_UPS_PER_GROUP = 1 << 18
"""About how many (task, base) look-ups :func:`_scores` makes at once: the tasks go in groups small enough
for a group's look-ups to stay in the CPU's cache (all the tasks of a large placement at once run several
times slower)."""


def _task_groups(n_tasks: int, n_bases: int) -> tuple[int, int]:
    """``(groups, size)``: the fewest groups of at most ``LOOK_UPS_PER_GROUP // n_bases`` tasks (at least
    one) that hold ``n_tasks``, all of one size (the last padded)."""
    groups = -(-n_tasks // max(1, LOOK_UPS_PER_GROUP // n_bases))
    return groups, -(-n_tasks // groups)


@functools.partial(jax.jit, static_argnames="n_tasks")
def _scores(table, slices, edges, c, d, origin_xy, inv_voxel, *, n_tasks: int):
    """``(nx, ny, nyaw)`` mean over the ``n_tasks`` tasks of whether the map reaches each task's pose in
    each base frame: ``c (nyaw, G, n, 2)`` the tasks' and ``d (nyaw, nx, ny, 2)`` the bases' xy turned by
    ``-yaw``; ``slices (nyaw, G, n)`` the table slice of each task's (bin, z layer), ``-1`` for none (and
    for the padding of the last of the ``G`` groups of ``n`` tasks, :func:`_task_groups`); ``table (S,
    mx, my)`` the slices' codes (:func:`slice_codes`); ``edges (nyaw, G, n)`` the code bits of each task's
    halves along z, ``u``, ``v`` and the roll (the x and y halves depend on the base)."""
    mx, my = table.shape[1:]
    codes = table.reshape(-1)

    def one_group(count, group, d):
        # x and y apart (not on a last axis of 2): XLA vectorizes the look-ups then.
        c, slices, edges = group
        sx = ((c[:, 0, None, None] - d[None, ..., 0]) - origin_xy[0]) * inv_voxel  # (n, nx, ny), the base frame
        sy = ((c[:, 1, None, None] - d[None, ..., 1]) - origin_xy[1]) * inv_voxel
        ix, iy = jnp.floor(sx), jnp.floor(sy)
        inside = (slices[:, None, None] >= 0) & (ix >= 0) & (ix < mx) & (iy >= 0) & (iy < my)
        flat = (jnp.maximum(slices, 0)[:, None, None] * mx + ix.astype(jnp.int32)) * my + iy.astype(jnp.int32)
        code = jnp.take(codes, jnp.where(inside, flat, 0))  # one flat gather: XLA's fastest
        edge = edges[:, None, None] | edge_bits((sx - ix >= 0.5, sy - iy >= 0.5), (0, 1))
        hit = inside & reached(code, edge)
        return count + jnp.sum(hit, axis=0, dtype=jnp.int32), None

    def one_yaw(args):
        c, d, slices, edges = args
        count = jnp.zeros(d.shape[:2], jnp.int32)
        return jax.lax.scan(functools.partial(one_group, d=d), count, (c, slices, edges))[0]

    return jnp.moveaxis(jax.lax.map(one_yaw, (c, d, slices, edges)), 0, -1) / n_tasks


def _region(region) -> np.ndarray:
    try:
        r = np.asarray(region, np.float64)
    except (TypeError, ValueError):
        r = np.full(0, np.nan)
    if r.shape != (2, 2) or not np.all(np.isfinite(r)) or np.any(r[1] <= r[0]):
        raise ValueError(
            f"region: expected [[xmin, ymin], [xmax, ymax]] (metres, world) with min < max, got {region!r}"
        )
    return r


def _number(value, name: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name}: expected a number of metres, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0):
        raise ValueError(f"{name}: expected a {'positive ' if positive else ''}finite number of metres, got {value}")
    return value


def base_placement(
    cap: CapabilityMap,
    tasks,
    *,
    region,
    yaw_bins: int = 36,
    base_height: float = 0.0,
    cell: float | None = None,
    min_count: int = 1,
    at_pose: bool = True,
    model=None,
    avoid=None,
) -> Placement:
    """Score planar base poses by the fraction of the task poses a capability map says they reach.

    The inverse of the map: for a base ``T_world_base`` at ``(x, y, base_height)`` turned by ``yaw``, a
    task ``T_world_task`` is reached when the map holds ``inv(T_world_base) @ T_world_task``
    (:meth:`CapabilityMap.reaches`). The bases form a grid of ``cell``-wide squares over ``region``
    (their centres) times ``yaw_bins`` yaws ``2 pi k / yaw_bins``. A task's orientation bin and z
    layer do not depend on the base's x and y: the map's ``(x, y)`` slices that the tasks need (and those
    beside them, which :meth:`CapabilityMap.reaches` judges a pose by) are gathered and coded once, and
    every base cell then costs one look-up per task.

    With ``avoid`` (obstacles in the world), what collides at every solution is ruled out before any
    IK: a base whose robot's root body (the shapes no joint moves) is within the margin of an
    obstacle scores 0, and a task whose tool body (the shapes fixed to the tool frame), placed at the
    task pose, is within the margin counts for no base (:attr:`Placement.blocked_bases`,
    :attr:`Placement.blocked_tasks`). The links between are checked by IK:
    :meth:`Placement.verify` with the same ``avoid``.

    Args:
        cap: the :class:`CapabilityMap` of the robot (in its base frame).
        tasks: ``(N, 4, 4)`` ``T_world_task``, the tool poses to reach, world frame, metres.
        region: ``[[xmin, ymin], [xmax, ymax]]`` where the base may stand, world frame, metres.
        yaw_bins: number of base yaws.
        base_height: the base's z in the world, metres.
        cell: edge of the base grid's squares, metres (default: the map's voxel size).
        min_count: samples a map cell needs to be held (:meth:`CapabilityMap.reaches`).
        at_pose: judge each task's pose by the map's cells around it (default), or by its cell alone
            (``False``: arms with fewer than 6 joints; :meth:`CapabilityMap.reaches`).
        model: with ``avoid``, the map's ``(robot, frame_name)`` pair.
        avoid: a :class:`~diffkin.ik.Avoid` of ``model``'s robot with obstacles (one world, in the world
            frame, metres): bases and tasks within its margin of them at every solution score 0 (above).

    Returns:
        The :class:`Placement`; :meth:`Placement.best` gives the best bases and
        :meth:`Placement.verify` re-solves them by IK.

    Raises:
        ValueError, TypeError: bad arguments (named in the message).
    """
    if not isinstance(cap, CapabilityMap):
        raise TypeError(f"cap: expected a CapabilityMap (dk.workspace.capability), got {type(cap).__name__}")
    T = np.asarray(tasks, np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] == 0:
        raise ValueError(f"tasks: expected (N, 4, 4) task poses with N >= 1, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError("tasks: expected finite poses")
    r = _region(region)
    yaw_bins = positive_int(yaw_bins, "yaw_bins")
    min_count = positive_int(min_count, "min_count")
    if not isinstance(at_pose, (bool, np.bool_)):
        raise TypeError(f"at_pose: expected a bool, got {type(at_pose).__name__}")
    base_height = _number(base_height, "base_height")
    if avoid is None and model is not None:
        raise ValueError("model: only needed with avoid (the robot whose shapes are checked)")
    robot_frame = None if avoid is None else checked(model, avoid)
    cell = cap.voxel_size if cell is None else _number(cell, "cell", positive=True)
    nx, ny = (max(1, math.ceil(s / cell - 1e-9)) for s in r[1] - r[0])
    if nx * ny * yaw_bins * T.shape[0] > 2**31:
        raise ValueError(f"cell: {nx} x {ny} x {yaw_bins} bases x {T.shape[0]} tasks exceed 2**31 look-ups")
    xs, ys = r[0, 0] + (np.arange(nx) + 0.5) * cell, r[0, 1] + (np.arange(ny) + 0.5) * cell
    yaws = np.arange(yaw_bins) * (2 * np.pi / yaw_bins)

    # Per yaw and task: the orientation bin and z layer of the task in the base frame.
    n_bins, (mx, my, mz) = cap.orientation_bins, cap.shape
    n_dir, n_roll = split_bins(n_bins)
    dtype = jnp.result_type(float)
    turn = planar_poses(0.0, 0.0, -yaws, 0.0)[:, :3, :3]  # Rz(-yaw), (nyaw, 3, 3)
    R = turn[:, None] @ T[None, :, :3, :3]
    bins, halves = _task_bins(n_dir, n_roll, jnp.asarray(R.reshape(-1, 3, 3), dtype))
    bins, halves = np.asarray(bins, np.int64), np.asarray(halves).reshape(yaw_bins, -1, 3)
    z_base = T[:, 2, 3].astype(dtype) - np.asarray(base_height + cap.origin[2], dtype)  # the grid's z in the base
    scaled = z_base * dtype.type(1 / cap.voxel_size)
    z = np.floor(scaled)
    layer = np.where((z >= 0) & (z < mz), z, -1).astype(np.int64)
    keys = np.where(layer >= 0, bins.reshape(yaw_bins, -1) * mz + layer, -1)
    needed, slices = np.unique(keys, return_inverse=True)
    slices = slices.reshape(keys.shape) - (needed[0] < 0)  # -1: the task is outside the map's z range
    needed = needed[needed >= 0]
    # The code bits of each task's halves along z, u, v and the roll (axes 2-5, see cell_codes).
    upper_z = np.broadcast_to(scaled - z >= 0.5, (yaw_bins, T.shape[0]))
    edges = edge_bits((upper_z, *np.moveaxis(halves, -1, 0)), range(2, 6))
    # The map's (x, y) slices of those (bin, layer) pairs and of those around them: ranges of its cells.
    layers, xy, counts = cap.layers
    keys = needed
    if at_pose:
        keys = np.unique(np.concatenate([needed, slices_around(needed, n_dir, n_roll, mz).ravel()]))
        keys = keys[keys >= 0]
    first = np.searchsorted(layers, keys, "left")
    n_cells = np.searchsorted(layers, keys, "right") - first
    at = np.arange(n_cells.sum()) + np.repeat(first - (np.cumsum(n_cells) - n_cells), n_cells)  # ranges' cells
    cells = xy[at] + np.repeat(np.arange(keys.size) * (mx * my), n_cells)
    if min_count > 1:
        cells = cells[counts[at] >= min_count]
    held = np.zeros((keys.size, mx, my), bool)
    held.reshape(-1)[cells] = True
    if not needed.size:
        table = jnp.zeros((1, mx, my), jnp.uint16)
    else:  # bit 0 alone: the cell is held, no edge
        table = slice_codes(held, keys, needed, n_dir, n_roll, mz) if at_pose else jnp.asarray(held, jnp.uint16)
    # The tasks' and the bases' xy in each base frame's orientation.
    c = np.einsum("yij,nj->yni", turn[:, :2, :2], T[:, :2, 3])
    bx, by = np.meshgrid(xs, ys, indexing="ij")
    d = np.einsum("yij,abj->yabi", turn[:, :2, :2], np.stack([bx, by], axis=-1))
    blocked_bases = blocked_tasks = None
    if robot_frame is not None:
        ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(yaw_bins), indexing="ij")
        bases = planar_poses(xs[ii], ys[jj], yaws[kk], base_height).reshape(-1, 4, 4)
        blocked_bases, blocked_tasks = blocked(*robot_frame, avoid, bases, T)
        blocked_bases = blocked_bases.reshape(nx, ny, yaw_bins)
        slices = np.where(blocked_tasks[None], -1, slices)  # reached from no base
    n_groups, group_size = _task_groups(T.shape[0], nx * ny)
    pad = n_groups * group_size - T.shape[0]  # tasks of slice -1: reached from no base

    def grouped(a, fill=0):
        a = np.pad(a, [(0, 0), (0, pad)] + [(0, 0)] * (a.ndim - 2), constant_values=fill)
        return a.reshape(yaw_bins, n_groups, group_size, *a.shape[2:])

    score = _scores(
        table,
        jnp.asarray(grouped(slices, -1), jnp.int32),
        jnp.asarray(grouped(edges)),
        jnp.asarray(grouped(c), dtype),
        jnp.asarray(d, dtype),
        jnp.asarray(cap.origin[:2], dtype),
        jnp.asarray(1 / cap.voxel_size, dtype),
        n_tasks=T.shape[0],
    )
    score = np.asarray(score, np.float64)
    if blocked_bases is not None:
        score = np.where(blocked_bases, 0.0, score)
    return Placement(score, xs, ys, yaws, base_height, T, blocked_bases, blocked_tasks)
