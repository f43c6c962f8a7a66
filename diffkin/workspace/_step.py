"""The compiled, sharded step of a map: a chunk of samples per device through forward kinematics (and
the collision check), binned into per-device partial maps, and their order-independent reduction."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from diffkin._static import ModelKey, partition
from diffkin._xla import opaque_index
from diffkin.models.ranges import sampling_ranges, uniform
from diffkin.models.robot import Robot
from diffkin.workspace._bins import _flat_index, _manipulability, _orientation_bin

_AXIS = "devices"  # the mesh axis the samples are sharded over


class _Collision(NamedTuple):
    """How a map's samples are checked for collision (static): the robot, where the chain's joints sit
    in its ``q``, the values of its other joints."""

    robot: ModelKey
    columns: tuple[int, ...]
    others: tuple[float, ...]


def _collision_check(pair, avoid) -> _Collision:
    """The static collision check of a map of ``pair = (robot, frame_name)`` with ``avoid``, checked on the host."""
    from diffkin.ik.interface import check_avoid

    if not (isinstance(pair, tuple) and len(pair) == 2 and isinstance(pair[0], Robot)):
        raise ValueError("avoid: needs a (robot, frame_name) pair as chain (collision geometry is a robot's)")
    robot, frame = pair
    check_avoid(robot, avoid)
    chain = robot.chain(frame)
    lo, hi = np.asarray(robot.lower, np.float64), np.asarray(robot.upper, np.float64)
    middle = np.where(np.isfinite(lo) & np.isfinite(hi), (lo + hi) / 2, np.where(np.isfinite(lo), lo, 0.0))
    middle = np.where(np.isfinite(hi) & ~np.isfinite(lo), hi, middle)
    columns = tuple(robot.joint_names.index(name) for name in chain.joint_names)
    return _Collision(partition(robot)[0], columns, tuple(float(x) for x in middle))


@functools.lru_cache(maxsize=16)
def _compiled(
    chain_key: ModelKey,
    shape: tuple[int, int, int],
    n_bins: int,
    chunk: int,
    dtype,
    mesh: Mesh,
    collision: _Collision | None = None,
    n_dir: int = 1,
    cells: bool = False,
):
    """Jitted ``(zeros, step, reduce)`` of one map: compiled once per chain, grid shape, chunk, mesh,
    collision check (the step's last argument: the :class:`~diffkin.ik.Avoid`, or ``None``) and
    orientation binning (``n_bins = 6 n_dir^2 n_roll``, see :func:`_orientation_bin`).

    The state is, per device, ``counts (nvox,)`` int32, ``best (nvox,)`` manipulability and
    ``seen (nvox * n_bins,)`` uint8 flags of the orientation bins reached, stacked on a leading
    device axis sharded over the mesh. Step ``s`` runs chunk ``s * n_devices + d`` on device ``d``.
    With ``cells`` (a capability map: too many cells for dense flags) ``seen`` is a placeholder
    ``(n_devices, 1)`` and the step also returns every sample's cell ``voxel * n_bins + bin``
    (``(n_devices * chunk,)`` int32, ``n_slots`` for a sample not counted), for the caller to count.
    """
    chain = chain_key.model
    lo, hi = sampling_ranges(chain)
    n_dev, nvox = mesh.devices.size, math.prod(shape)
    sharded, replicated = NamedSharding(mesh, P(_AXIS)), NamedSharding(mesh, P())

    def zeros():
        return (
            jnp.zeros((n_dev, nvox), jnp.int32),
            jnp.zeros((n_dev, nvox), dtype),
            jnp.zeros((n_dev, 1 if cells else nvox * n_bins), jnp.uint8),
        )

    def local_step(counts, best, seen, key, chunk_index, n_full, n_last, origin, inv_voxel, n_slots, avoid):
        c = chunk_index[0]  # this device's chunk: no axis_index, so one per-device program for any device count
        n_valid = jnp.where(c < n_full, chunk, jnp.where(c == n_full, n_last, 0))
        q = uniform(jax.random.fold_in(key, c), lo, hi, chunk, dtype)
        counted = jnp.arange(chunk) < n_valid
        if collision is not None:  # only the samples clear of the obstacles (and of the robot itself) count
            robot = collision.robot.model
            q_robot = jnp.broadcast_to(jnp.asarray(collision.others, dtype)[:, None], (robot.dof, chunk))
            q_robot = q_robot.at[np.asarray(collision.columns)].set(q)
            counted = counted & (avoid.clearance(robot, q_robot.T) >= avoid.margin)
        kin = chain.forward(list(q))
        ee = kin.pose()
        p = tuple(jnp.broadcast_to(jnp.asarray(x, dtype), (chunk,)) for x in ee.p)
        R = tuple(tuple(jnp.broadcast_to(jnp.asarray(x, dtype), (chunk,)) for x in row) for row in ee.R)
        flat, inside = _flat_index(p, origin, inv_voxel, shape)
        slot = jnp.where(
            inside & counted, flat * n_bins + _orientation_bin(R, n_bins // (6 * n_dir**2), n_dir), n_slots
        )  # out of range: dropped by the scatters
        slot = opaque_index(slot, n_slots + 1)  # one forward pass for the three scatters, not one per scatter
        m = _manipulability(kin, chain.dof).astype(dtype)
        counts = counts.reshape(-1).at[slot // n_bins].add(1, mode="drop").reshape(counts.shape)
        best = best.reshape(-1).at[slot // n_bins].max(m, mode="drop").reshape(best.shape)
        if cells:
            return counts, best, seen, jnp.sum(n_valid), slot
        seen = seen.reshape(-1).at[slot].set(1, mode="drop").reshape(seen.shape)
        return counts, best, seen, jnp.sum(n_valid)

    step = jax.jit(
        jax.shard_map(
            local_step,
            mesh=mesh,
            in_specs=(P(_AXIS),) * 3 + (P(), P(_AXIS)) + (P(),) * 6,
            out_specs=(P(_AXIS),) * 3 + (P(),) + ((P(_AXIS),) if cells else ()),
            check_vma=False,
        ),
        donate_argnums=(0, 1, 2),
    )

    def reduce(counts, best, seen):
        if cells:  # the caller counts them
            return counts.sum(axis=0), best.max(axis=0), jnp.zeros(nvox, jnp.int32)
        dexterity = jnp.max(seen, axis=0).reshape(nvox, n_bins).sum(axis=1, dtype=jnp.int32)
        return counts.sum(axis=0), best.max(axis=0), dexterity

    return (jax.jit(zeros, out_shardings=(sharded,) * 3), step, jax.jit(reduce, out_shardings=(replicated,) * 3))
