"""Workspace analysis: reachability, manipulability and dexterity maps over millions of samples.

Configurations are drawn uniformly within the joint limits, chunk by chunk; each chunk is run
through forward kinematics, its end-effector positions are binned on a voxel grid and reduced
into per-voxel sample counts, best manipulability and the set of orientation bins reached.
Memory is ``O(chunk + grid)`` whatever the number of samples. Chunks are spread over devices
with a :class:`jax.sharding.Mesh` and ``shard_map``; every device keeps a partial map and the
partial maps are reduced at the end with integer sums, float maxima and logical ors, which
do not depend on the order of reduction, so the map is identical for any number of devices.
For that, each sample's bins must not depend on how its device's program is compiled: the
per-device program receives its chunk index as data (it is the same program for any number of
devices), and the binning uses no division (XLA's CPU division rounds differently in different
compilations); see ``_flat_index`` and ``_orientation_bin``.

Orientation bins are a fixed partition of SO(3) into ``orientation_bins = 6 * n_roll`` cells
of equal measure: the tool z axis picks a face of the cube (its largest component and that
component's sign), and the rotation about the tool z axis picks one of ``n_roll`` sectors of
the roll angle ``atan2(-R[u, 1], R[u, 0])``, where ``u = (a + 1) % 3`` for the face axis
``a``: the angle of the tool x axis from the projection of the base axis ``u`` on the plane
orthogonal to the tool z axis (never degenerate, since that axis is at most 54.8 degrees from
``a``). For a planar arm (rotation about the base z axis by ``phi``) the bin is the sector of
``phi``, so different planar angles land in different bins.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import os
import sys
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from diffkin import _rigid as rg
from diffkin._checks import instance, positive_int
from diffkin._npz import read_npz
from diffkin._static import ModelKey, partition
from diffkin._trig import atan2, sincos
from diffkin._xla import opaque_index
from diffkin.models import forward
from diffkin.models.dh import DHChain
from diffkin.models.forward import Pass
from diffkin.models.poe import PoEChain, to_poe
from diffkin.models.robot import Robot

_AXIS = "devices"
MAX_GRID_BYTES = 2 * 1024**3
"""Largest memory of the maps of :func:`reachability` (an estimate: every device's counts, manipulability
and orientation flags per voxel, their reduction and the host's copies); a finer grid is a ValueError
naming ``voxel_size``. Raise it (``diffkin.workspace.MAX_GRID_BYTES = ...``) to allow more."""
_INT32_MAX = 2**31 - 1
_QUANTITIES = ("count", "manipulability", "dexterity")
_AXES = ("x", "y", "z")


@dataclasses.dataclass(frozen=True, eq=False)
class ReachabilityMap:
    """Per-voxel statistics of the end-effector positions of sampled configurations.

    Voxel ``(i, j, k)`` is the box ``origin + voxel_size * ([i, i+1) x [j, j+1) x [k, k+1))`` in
    the chain's base frame; a sample whose end-effector position ``p`` (metres, base frame) has
    ``floor((p - origin) / voxel_size) == (i, j, k)`` counts in that voxel (computed as
    ``(p - origin) * (1 / voxel_size)`` in the computation's dtype, so a point within rounding of a
    face may count on either side of it, the same side on any number of devices). Samples outside
    the grid count in no voxel: ``counts.sum() + n_outside == n_samples``.

    Attributes:
        counts: ``(nx, ny, nz)`` int64, number of samples per voxel.
        manipulability: ``(nx, ny, nz)`` float, best Yoshikawa manipulability of the samples in
            the voxel (as :func:`diffkin.manipulability`), 0 where there are none.
        dexterity: ``(nx, ny, nz)`` int32, number of distinct orientation bins (of
            ``orientation_bins``, see the module docstring) reached in the voxel.
        origin: ``(3,)`` float64, corner of voxel ``(0, 0, 0)``, metres, base frame.
        voxel_size: edge of the cubic voxels, metres.
        n_samples: number of sampled configurations.
        n_outside: number of samples whose end effector fell outside the grid.
        orientation_bins: number of cells of the SO(3) partition.
        chain_name: name of the chain (informational).
    """

    counts: np.ndarray
    manipulability: np.ndarray
    dexterity: np.ndarray
    origin: np.ndarray
    voxel_size: float
    n_samples: int
    n_outside: int
    orientation_bins: int
    chain_name: str = ""

    def save(self, path) -> None:
        """Write the map to ``path`` as a ``.npz`` archive (numpy appends ``.npz`` if missing)."""
        fields = {f.name: np.asarray(getattr(self, f.name)) for f in dataclasses.fields(self)}
        np.savez_compressed(path, **fields)  # type: ignore[arg-type]  # numpy's stub reads **fields as allow_pickle

    @classmethod
    def load(cls, path) -> ReachabilityMap:
        """Read a map written by :meth:`save` (``load("map")`` reads the ``map.npz`` that ``save("map")`` wrote).

        Raises:
            ValueError: a file that is empty, truncated, not a ``.npz`` archive, or lacks a field
                of the map (the message names the file and the field).
            FileNotFoundError: no such file.
        """
        path = os.fspath(path)
        if not os.path.exists(path) and not path.endswith(".npz") and os.path.exists(path + ".npz"):
            path += ".npz"  # as np.savez named it
        fields = read_npz(path, "written by ReachabilityMap.save")
        missing = [f.name for f in dataclasses.fields(cls) if f.name not in fields]
        if missing:
            raise ValueError(f"{path}: not a complete reachability map, missing field(s) {', '.join(missing)}")
        if fields["counts"].ndim != 3:
            raise ValueError(f"{path}: field counts: expected a 3-d grid, got shape {fields['counts'].shape}")
        return cls(
            counts=fields["counts"],
            manipulability=fields["manipulability"],
            dexterity=fields["dexterity"],
            origin=fields["origin"],
            voxel_size=float(fields["voxel_size"]),
            n_samples=int(fields["n_samples"]),
            n_outside=int(fields["n_outside"]),
            orientation_bins=int(fields["orientation_bins"]),
            chain_name=str(fields["chain_name"]),
        )


def _as_chain(chain):
    """A chain as given, or the chain of a ``(robot, frame_name)`` pair (:meth:`Robot.chain` from the root)."""
    if isinstance(chain, tuple) and len(chain) == 2 and isinstance(chain[0], Robot):
        robot, frame = chain
        return robot.chain(frame)
    instance(chain, (DHChain, PoEChain), "chain", "a DHChain, PoEChain or (Robot, frame_name)")
    return chain


def _collision_check(pair, avoid) -> _Collision:
    """The static collision check of a map of ``pair = (robot, frame_name)`` with ``avoid``, checked on the host."""
    from diffkin.collision._robot import check_geometry
    from diffkin.ik import Avoid

    if not (isinstance(pair, tuple) and len(pair) == 2 and isinstance(pair[0], Robot)):
        raise ValueError("avoid: needs a (robot, frame_name) pair as chain (collision geometry is a robot's)")
    instance(avoid, Avoid, "avoid", "a dk.ik.Avoid(geom, world, margin)")
    robot, frame = pair
    check_geometry(robot, avoid.geom)
    chain = robot.chain(frame)
    lo, hi = np.asarray(robot.lower, np.float64), np.asarray(robot.upper, np.float64)
    middle = np.where(np.isfinite(lo) & np.isfinite(hi), (lo + hi) / 2, np.where(np.isfinite(lo), lo, 0.0))
    middle = np.where(np.isfinite(hi) & ~np.isfinite(lo), hi, middle)
    columns = tuple(robot.joint_names.index(name) for name in chain.joint_names)
    return _Collision(partition(robot)[0], columns, tuple(float(x) for x in middle))


def _joint_ranges(chain) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` sampling ranges: the limits, one turn ``[-pi, pi)`` for unlimited revolute joints."""
    forward.check(chain)
    lo, hi = np.asarray(chain.lower, np.float64), np.asarray(chain.upper, np.float64)
    for i, kind in enumerate(chain.actuated_types if isinstance(chain, Robot) else chain.joint_types):
        if kind == "P" and not (np.isfinite(lo[i]) and np.isfinite(hi[i])):
            raise ValueError(
                f"chain.lower/upper[{i}]: expected finite limits for prismatic joint {i}, got [{lo[i]}, {hi[i]}]"
            )
    return np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)


def _uniform(key, lo: np.ndarray, hi: np.ndarray, n: int, dtype) -> jax.Array:
    """``(dof, n)`` uniform joint values, one row per joint (the layout the kernel consumes)."""
    u = jax.random.uniform(key, (lo.size, n), dtype)
    return jnp.asarray(lo[:, None], dtype) + u * jnp.asarray((hi - lo)[:, None], dtype)


def sample_configs(chain, n: int, key, *, dtype=None) -> jax.Array:
    """Configurations uniform within the joint limits.

    Unlimited revolute joints are sampled over one turn ``[-pi, pi)``; a prismatic joint needs
    finite limits. Chunk ``c`` of :func:`reachability` is ``sample_configs(chain, chunk,
    jax.random.fold_in(key, c))``.

    Args:
        chain: a :class:`DHChain`, :class:`PoEChain` or :class:`Robot` (its actuated joints).
        n: number of configurations.
        key: a JAX PRNG key.
        dtype: float dtype; default the default float (float32, or float64 with x64).

    Returns:
        ``(n, dof)`` joint values, radians (revolute) or metres (prismatic).
    """
    lo, hi = _joint_ranges(chain)
    n = positive_int(n, "n")
    return _uniform(key, lo, hi, n, jnp.dtype(dtype or jnp.result_type(float))).T


def _reach(chain) -> float:
    """Upper bound on ``|p_ee|`` over all configurations, metres.

    A revolute joint keeps the distances from its axis to everything after it, so
    ``|p| <= |c_1| + sum |c_{i+1} - c_i| + |p_home - c_n|`` for any points ``c_i`` on the revolute
    axes at ``q = 0`` (each taken as the projection of the previous one, which keeps the bound
    tight); each prismatic joint adds its largest travel.
    """
    poe = to_poe(chain) if isinstance(chain, DHChain) else chain
    screws, home = np.asarray(poe.screws, np.float64), np.asarray(poe.home, np.float64)
    lo, hi = _joint_ranges(chain)
    points, reach = [np.zeros(3)], 0.0
    for i, kind in enumerate(chain.joint_types):
        v, w = screws[i, :3], screws[i, 3:]
        if kind == "R":
            c = np.cross(w, v)  # a point on the axis
            points.append(c + np.dot(points[-1] - c, w) * w)
        else:
            reach += max(abs(lo[i]), abs(hi[i]))
    points.append(home[:3, 3])
    return reach + float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def _grid(chain, voxel_size, bounds) -> tuple[np.ndarray, float, tuple[int, ...]]:
    """``(origin (3,), voxel_size, shape)`` of the voxel grid, validated."""
    if isinstance(voxel_size, bool) or not isinstance(voxel_size, (int, float, np.integer, np.floating)):
        raise TypeError(f"voxel_size: expected a positive number of metres, got {type(voxel_size).__name__}")
    voxel_size = float(voxel_size)
    if not (math.isfinite(voxel_size) and voxel_size > 0):
        raise ValueError(f"voxel_size: expected a positive number of metres, got {voxel_size}")
    shape: tuple[int, ...]
    if bounds is None:
        m = math.ceil(_reach(chain) / voxel_size)
        origin, shape = np.full(3, -(m + 0.5) * voxel_size), (2 * m + 1,) * 3
    else:
        try:
            b = np.asarray(bounds, dtype=np.float64)
        except (TypeError, ValueError):
            b = np.full(0, np.nan)
        if b.shape != (2, 3) or not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
            raise ValueError(
                f"bounds: expected [[xmin, ymin, zmin], [xmax, ymax, zmax]] (metres) with min < max, got {bounds!r}"
            )
        origin, shape = b[0], tuple(int(max(1, math.ceil(s))) for s in (b[1] - b[0]) / voxel_size)
    return origin, voxel_size, shape


def _orientation_bin(R: rg.Mat3, n_roll: int) -> jax.Array:
    """Orientation bin in ``[0, 6 n_roll)`` of rotations given by entries (see the module docstring)."""
    z = [jnp.abs(R[i][2]) for i in range(3)]
    a = jnp.where((z[0] >= z[1]) & (z[0] >= z[2]), 0, jnp.where(z[1] >= z[2], 1, 2))
    z_a = jnp.where(a == 0, R[0][2], jnp.where(a == 1, R[1][2], R[2][2]))
    x_u = jnp.where(a == 0, R[1][0], jnp.where(a == 1, R[2][0], R[0][0]))
    y_u = jnp.where(a == 0, R[1][1], jnp.where(a == 1, R[2][1], R[0][1]))
    roll = atan2(-y_u, x_u)  # [-pi, pi]
    sector = jnp.clip(jnp.floor((roll + jnp.pi) * (n_roll / (2 * jnp.pi))), 0, n_roll - 1).astype(jnp.int32)
    if n_roll > 1:
        # Settled by the side of the sector's edges that (x_u, -y_u) is on: products and sums, which
        # round the same however XLA compiles them (atan2's division may not: see _flat_index).
        width = 2 * np.pi / n_roll
        start = sector.astype(x_u.dtype) * width - np.pi
        (s0, c0), (s1, c1) = sincos(start), sincos(start + width)
        sector = sector - ((c0 * -y_u - s0 * x_u) < 0) + ((c1 * -y_u - s1 * x_u) >= 0)
        sector = jnp.clip(sector, 0, n_roll - 1)
    return (2 * a + (z_a < 0)) * n_roll + sector


def _manipulability(kin: Pass, dof: int) -> jax.Array:
    """Yoshikawa's measure from one forward pass, by the Cauchy-Binet formula.

    ``det(J J^T)`` (or ``det(J^T J)`` for fewer than 6 joints) is the sum of the squares of the
    maximal minors of the ``(6, dof)`` world Jacobian ``J``. The minors are built row by row by
    Laplace expansion, with products and sums only: no division or pivoting, exactly 0 at a
    singularity, and a single fused XLA kernel (a division with several users would make XLA
    materialise it and recompute the forward kinematics in a kernel of its own).
    """
    columns = rg.world_from_space(kin.columns(), kin.pose().p)
    J = [[columns[i][r // 3][r % 3] for i in range(dof)] for r in range(6)]  # J[row][column]
    rows = J if dof >= 6 else [[J[r][i] for r in range(6)] for i in range(dof)]  # short side first
    minors: dict[tuple[int, ...], rg.Entry] = {(): 1.0}  # column subset -> minor over the first len(subset) rows
    for k, row in enumerate(rows):
        minors = {
            subset: rg.add(
                *(
                    rg.mul((-1.0) ** (k + j), rg.mul(row[c], minors[subset[:j] + subset[j + 1 :]]))
                    for j, c in enumerate(subset)
                )
            )
            for subset in itertools.combinations(range(len(row)), k + 1)
        }
    det = rg.add(*(rg.mul(m, m) for m in minors.values()))
    return jnp.sqrt(det)


def _flat_index(p: rg.Vec3, origin, inv_voxel, shape) -> tuple[jax.Array | int, jax.Array | bool]:
    """Flat voxel index of positions given by entries, and whether they are inside the grid.

    The cell is ``floor((p - origin) * inv_voxel)``: a subtraction and a product, which round the
    same however XLA compiles them. (XLA's CPU backend computes a division by a reciprocal
    estimate in some compilations and exactly in others: with ``/ voxel_size`` a sample on a
    voxel face changed voxels with the number of devices.)
    """
    flat: jax.Array | int = 0
    inside: jax.Array | bool = True
    for i, n in enumerate(shape):
        cell = jnp.floor((p[i] - origin[i]) * inv_voxel)
        inside = inside & (cell >= 0) & (cell < n)
        flat = flat * n + jnp.where(inside, cell, 0).astype(jnp.int32)
    return flat, inside


class _Collision(NamedTuple):
    """How a map's samples are checked for collision (static): the robot, where the chain's joints sit
    in its ``q``, the values of its other joints."""

    robot: ModelKey
    columns: tuple[int, ...]
    others: tuple[float, ...]


@functools.lru_cache(maxsize=16)
def _compiled(
    chain_key: ModelKey,
    shape: tuple[int, int, int],
    n_bins: int,
    chunk: int,
    dtype,
    mesh: Mesh,
    collision: _Collision | None = None,
):
    """Jitted ``(zeros, step, reduce)`` of one map: compiled once per chain, grid shape, chunk, mesh and
    collision check (the step's last argument: the :class:`~diffkin.ik.Avoid`, or ``None``).

    The state is, per device, ``counts (nvox,)`` int32, ``best (nvox,)`` manipulability and
    ``seen (nvox * n_bins,)`` uint8 flags of the orientation bins reached, stacked on a leading
    device axis sharded over the mesh. Step ``s`` runs chunk ``s * n_devices + d`` on device ``d``.
    """
    chain = chain_key.model
    lo, hi = _joint_ranges(chain)
    n_dev, nvox = mesh.devices.size, math.prod(shape)
    sharded, replicated = NamedSharding(mesh, P(_AXIS)), NamedSharding(mesh, P())

    def zeros():
        return (
            jnp.zeros((n_dev, nvox), jnp.int32),
            jnp.zeros((n_dev, nvox), dtype),
            jnp.zeros((n_dev, nvox * n_bins), jnp.uint8),
        )

    def local_step(counts, best, seen, key, chunk_index, n_full, n_last, origin, inv_voxel, n_slots, avoid):
        c = chunk_index[0]  # this device's chunk: no axis_index, so one per-device program for any device count
        n_valid = jnp.where(c < n_full, chunk, jnp.where(c == n_full, n_last, 0))
        q = _uniform(jax.random.fold_in(key, c), lo, hi, chunk, dtype)
        counted = jnp.arange(chunk) < n_valid
        if collision is not None:  # only the samples clear of the obstacles (and of the robot itself) count
            robot = collision.robot.model
            q_robot = jnp.broadcast_to(jnp.asarray(collision.others, dtype)[:, None], (robot.dof, chunk))
            q_robot = q_robot.at[np.asarray(collision.columns)].set(q)
            counted = counted & (avoid.clearance(robot, q_robot.T) >= avoid.margin)
        kin = chain.forward(list(q))
        ee = kin.pose()
        p = [jnp.broadcast_to(jnp.asarray(x, dtype), (chunk,)) for x in ee.p]
        R = tuple(tuple(jnp.broadcast_to(jnp.asarray(x, dtype), (chunk,)) for x in row) for row in ee.R)
        flat, inside = _flat_index(p, origin, inv_voxel, shape)
        slot = jnp.where(
            inside & counted, flat * n_bins + _orientation_bin(R, n_bins // 6), n_slots
        )  # out of range: dropped by the scatters
        slot = opaque_index(slot, n_slots + 1)  # one forward pass for the three scatters, not one per scatter
        m = _manipulability(kin, chain.dof).astype(dtype)
        counts = counts.reshape(-1).at[slot // n_bins].add(1, mode="drop").reshape(counts.shape)
        best = best.reshape(-1).at[slot // n_bins].max(m, mode="drop").reshape(best.shape)
        seen = seen.reshape(-1).at[slot].set(1, mode="drop").reshape(seen.shape)
        return counts, best, seen, jnp.sum(n_valid)

    step = jax.jit(
        jax.shard_map(
            local_step,
            mesh=mesh,
            in_specs=(P(_AXIS),) * 3 + (P(), P(_AXIS)) + (P(),) * 6,
            out_specs=(P(_AXIS),) * 3 + (P(),),
            check_vma=False,
        ),
        donate_argnums=(0, 1, 2),
    )

    def reduce(counts, best, seen):
        dexterity = jnp.max(seen, axis=0).reshape(nvox, n_bins).sum(axis=1, dtype=jnp.int32)
        return counts.sum(axis=0), best.max(axis=0), dexterity

    return (jax.jit(zeros, out_shardings=(sharded,) * 3), step, jax.jit(reduce, out_shardings=(replicated,) * 3))


def _host(x: jax.Array) -> np.ndarray:
    """A replicated array as numpy (one local copy; works on every process of a multi-host run)."""
    return np.asarray(x.addressable_data(0))


def _progress(total: int, show: bool | None):
    """A tqdm bar over chunks, or ``None``: ``show=None`` shows it on a terminal on process 0."""
    if show is False or jax.process_index() != 0:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    if show is None and not sys.stderr.isatty():
        return None
    return tqdm(total=total, unit="sample", unit_scale=True, desc="reachability")


def reachability(
    chain,
    n_samples: int,
    *,
    key,
    voxel_size: float = 0.05,
    bounds=None,
    chunk: int = 1 << 16,
    devices: Sequence[jax.Device] | None = None,
    orientation_bins: int = 48,
    dtype=None,
    progress: bool | None = None,
    avoid=None,
) -> ReachabilityMap:
    """Reachability, best manipulability and dexterity of ``chain`` on a voxel grid.

    ``n_samples`` configurations uniform within the joint limits (see :func:`sample_configs`)
    are drawn in ``ceil(n_samples / chunk)`` chunks, chunk ``c`` from
    ``jax.random.fold_in(key, c)`` (the last one masked to the remaining samples), and reduced
    chunk by chunk, so memory is ``O(chunk + grid)`` per device. Chunks are spread over
    ``devices``; the map is identical for any number of devices. Each step is one jitted call,
    compiled once per chain, grid shape, chunk, orientation bins, dtype and device set.

    Args:
        chain: a :class:`DHChain` or :class:`PoEChain` with concrete (not traced) numbers, or a
            ``(robot, frame_name)`` pair: the map of that frame of a :class:`Robot`, in its root
            frame (the path's joints only; see :meth:`Robot.chain`).
        n_samples: number of configurations.
        key: a JAX PRNG key.
        voxel_size: voxel edge, metres (default 0.05, as the ``diffkin workspace`` command).
        bounds: ``(2, 3)`` ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` box in the base frame,
            metres; the grid starts at the min corner and has ``ceil((max - min) / voxel_size)``
            voxels per axis. Default: a cube centred on the base origin (at a voxel centre) that
            holds every reachable point, from an upper bound on the reach (the sum of the
            distances between consecutive joint axes, plus prismatic travel).
        chunk: samples per device per step (at most ``n_samples``: a larger value is capped).
        devices: devices to use (all processes' devices in a multi-host run); default
            ``jax.devices()``.
        orientation_bins: cells of the SO(3) partition, a multiple of 6 (6 cube faces of the
            tool z axis times ``orientation_bins / 6`` roll sectors).
        dtype: float dtype of the computation; default the default float (float32, or float64
            with x64).
        progress: show a tqdm progress bar; ``None`` (default): only on a terminal.
        avoid: for a ``(robot, frame_name)`` pair, a :class:`~diffkin.ik.Avoid` (the robot's collision
            geometry, obstacles, margin): only samples whose clearance is at least the margin count
            (in every map; ``n_outside`` then also counts the colliding samples). The robot's joints
            off the frame's path are held at the middle of their limits (a one-sided limit's bound, 0
            where unlimited).

    Returns:
        The :class:`ReachabilityMap`.

    Raises:
        ValueError, TypeError: bad arguments (named in the message).
    """
    collision = None if avoid is None else _collision_check(chain, avoid)
    chain = _as_chain(chain)
    n_samples = positive_int(n_samples, "n_samples")
    chunk = positive_int(chunk, "chunk")
    orientation_bins = positive_int(orientation_bins, "orientation_bins")
    if orientation_bins % 6:
        raise ValueError(
            f"orientation_bins: expected a multiple of 6 (6 cube faces x roll sectors), got {orientation_bins}"
        )
    origin, voxel_size, shape = _grid(chain, voxel_size, bounds)
    n_chunks = -(-n_samples // chunk)
    if n_chunks > _INT32_MAX:
        raise ValueError(f"n_samples: expected at most {_INT32_MAX} chunks of {chunk} samples, got {n_samples} samples")
    chunk = min(chunk, n_samples)  # a larger chunk would only compute masked samples
    n_slots = math.prod(shape) * orientation_bins
    if n_slots >= _INT32_MAX:
        raise ValueError(
            f"voxel_size: grid of {shape} voxels x {orientation_bins} orientation bins exceeds 2**31 "
            f"cells; expected a coarser voxel_size, smaller bounds or fewer orientation_bins"
        )
    devices = list(jax.devices() if devices is None else devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise TypeError(f"devices: expected a non-empty sequence of jax.Device, got {devices!r}")
    dtype = jnp.dtype(dtype or jnp.result_type(float))
    # Per voxel: every device's counts, best manipulability and orientation flags; the reduction's
    # maximum of the flags and its three maps; the host's int64 counts and copies of the maps.
    item = dtype.itemsize
    grid_bytes = math.prod(shape) * (
        len(devices) * (4 + item + orientation_bins) + orientation_bins + 2 * (8 + item) + 8
    )
    if grid_bytes > MAX_GRID_BYTES:
        raise ValueError(
            f"voxel_size: {voxel_size} m gives a grid of {shape} voxels x {orientation_bins} orientation "
            f"bins on {len(devices)} device(s), about {grid_bytes / 2**30:.1f} GiB of maps (limit "
            f"diffkin.workspace.MAX_GRID_BYTES = {MAX_GRID_BYTES / 2**30:.1f} GiB); expected a coarser "
            f"voxel_size, smaller bounds or fewer orientation_bins"
        )
    mesh = Mesh(np.array(devices), (_AXIS,))
    zeros, step, reduce = _compiled(partition(chain)[0], shape, orientation_bins, chunk, dtype, mesh, collision)

    n_full, n_last = divmod(n_samples, chunk)
    n_steps = -(-(n_full + (n_last > 0)) // len(devices))
    steps_per_flush = max(1, _INT32_MAX // (chunk * len(devices)))  # int32 device counts cannot overflow
    args = (
        jnp.asarray(n_full, jnp.int32),
        jnp.asarray(n_last, jnp.int32),
        jnp.asarray(origin, dtype),
        jnp.asarray(1.0 / voxel_size, dtype),
        jnp.asarray(n_slots, jnp.int32),
        jnp.zeros((), dtype) if avoid is None else avoid.cast(dtype),
    )
    sharded = NamedSharding(mesh, P(_AXIS))
    state, counts, bar = zeros(), np.zeros(shape, np.int64), _progress(n_samples, progress)
    done: jax.Array | None = None  # the valid samples of the step in flight
    for s in range(n_steps):
        indices = np.arange(s * len(devices), (s + 1) * len(devices), dtype=np.int32)
        chunks = jax.make_array_from_callback(indices.shape, sharded, indices.__getitem__)
        *state, n_step = step(*state, key, chunks, *args)
        if bar is not None:
            if done is not None:
                bar.update(int(done))  # waits for the previous step only: one step stays in flight
            done = n_step
        if (s + 1) % steps_per_flush == 0 or s + 1 == n_steps:
            counts_s, best, dexterity = reduce(*state)
            counts += _host(counts_s).reshape(shape)
            if s + 1 < n_steps:
                state = [zeros()[0], *state[1:]]
    if bar is not None and done is not None:
        bar.update(int(done))
    if bar is not None:
        bar.close()
    return ReachabilityMap(
        counts=counts,
        manipulability=_host(best).reshape(shape),
        dexterity=_host(dexterity).reshape(shape),
        origin=origin,
        voxel_size=voxel_size,
        n_samples=n_samples,
        n_outside=n_samples - int(counts.sum()),
        orientation_bins=orientation_bins,
        chain_name=chain.name,
    )


def plot_slice(
    reach_map: ReachabilityMap, axis: str = "y", value: float = 0.0, quantity: str = "count", *, path=None, ax=None
):
    """Heatmap of one quantity on the voxel layer that contains the plane ``axis = value``.

    The layer is a slab one voxel thick; the title and colour bar say what is plotted: samples
    per voxel (of ``n_samples`` configurations uniform in joint space), the best Yoshikawa
    manipulability per voxel (of the end effector's ``(6, dof)`` world Jacobian), or the number
    of orientation bins reached per voxel (out of ``orientation_bins``, the colour bar's maximum).
    Needs matplotlib (the ``plot`` extra), imported here only.

    Args:
        reach_map: the :class:`ReachabilityMap`.
        axis: ``"x"``, ``"y"`` or ``"z"``, the normal of the slicing plane (base frame).
        value: position of the plane along ``axis``, metres; it must cross the grid.
        quantity: ``"count"``, ``"manipulability"`` or ``"dexterity"``.
        path: if given, the figure is written there as a PNG.
        ax: a matplotlib axes to draw into; default a new figure.

    Returns:
        The matplotlib axes.
    """
    m = reach_map
    if axis not in _AXES:
        raise ValueError(f"axis: expected one of {_AXES}, got {axis!r}")
    if quantity not in _QUANTITIES:
        raise ValueError(f"quantity: expected one of {_QUANTITIES}, got {quantity!r}")
    a = _AXES.index(axis)
    layer = math.floor((float(value) - m.origin[a]) / m.voxel_size)
    if not 0 <= layer < m.counts.shape[a]:
        lo, hi = m.origin[a], m.origin[a] + m.voxel_size * m.counts.shape[a]
        raise ValueError(f"value: expected {axis} in [{lo:.4g}, {hi:.4g}) (the grid), got {value}")
    if ax is None:
        from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

        ax = Figure(figsize=(7, 5.5), layout="constrained").add_subplot()
    data = {"count": m.counts, "manipulability": m.manipulability, "dexterity": m.dexterity}[quantity]
    plane = np.take(data, layer, axis=a).astype(np.float64)
    plane[np.take(m.counts, layer, axis=a) == 0] = np.nan  # unreached voxels blank
    u, v = (i for i in range(3) if i != a)
    extent = [
        m.origin[u],
        m.origin[u] + m.voxel_size * data.shape[u],
        m.origin[v],
        m.origin[v] + m.voxel_size * data.shape[v],
    ]
    slab = (m.origin[a] + layer * m.voxel_size, m.origin[a] + (layer + 1) * m.voxel_size)
    limits = {"vmin": 0, "vmax": m.orientation_bins} if quantity == "dexterity" else {}
    image = ax.imshow(plane.T, origin="lower", extent=extent, interpolation="nearest", **limits)
    label = {
        "count": "samples per voxel",
        "manipulability": "best Yoshikawa manipulability sqrt(det(J J^T)) in the voxel",
        "dexterity": f"orientation bins reached (of {m.orientation_bins})",
    }[quantity]
    ax.figure.colorbar(image, ax=ax, label=label)
    what = {
        "count": "reachability: samples per voxel",
        "manipulability": "best manipulability per voxel (J: world Jacobian of the end effector)",
        "dexterity": f"dexterity: orientation bins of {m.orientation_bins} reached per voxel",
    }[quantity]
    ax.set(
        xlabel=f"{_AXES[u]} (m)",
        ylabel=f"{_AXES[v]} (m)",
        aspect="equal",
        title=f"{m.chain_name} {what}\nslab {axis} in [{slab[0]:.3g}, {slab[1]:.3g}) m ({m.voxel_size:g} m "
        f"voxels)\n{m.n_samples:,} samples uniform in joint space; blank: none reached",
    )
    ax.title.set_fontsize("medium")
    if path is not None:
        ax.figure.savefig(path, dpi=120)
    return ax


__all__ = ["ReachabilityMap", "plot_slice", "reachability", "sample_configs"]
